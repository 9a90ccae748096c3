"""Markers on a prop: where to stick them, and the files and pictures of the placement."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from starforge.io import staged_output

__all__ = ["place_markers", "write_placement"]


def place_markers(
    prop: str = "hammer",
    *,
    spec: str = "default",
    seed: int = 0,
    units: str = "m",
    avoid: Sequence[str | Path] = (),
    grip: str | None = None,
    progress=None,
    **overrides,
):
    """Where to stick markers on a prop: a built-in name or a mesh file, optimized by
    reversible-jump MCMC so that a tracker keeps it while a hand holds it and cameras drop out.

    Parameters
    ----------
    prop : str
        Built-in prop (``hammer``, ``sword``, ...) or a mesh path (STL, OBJ, PLY, GLB...).
    spec : str
        Place template name or TOML file (``starforge templates place``).
    units : str
        Units of a mesh file: ``m``, ``cm`` or ``mm``.
    avoid : sequence of path
        Bodies already in the room (placements, families, tracker files).
    **overrides
        Template keys (``markers``, ``sites``, ``resolution``, ``orientations``, ``marker_mm``...).

    Returns
    -------
    PlacementResult

    Examples
    --------
    >>> res = place_markers("box", sites=150, resolution=1, orientations=6, seed=1)
    >>> len(res.marker_points) >= 4 and res.marker_points.shape[1] == 3
    True
    """
    from starforge.props.placement import run_placement

    faces = None
    if avoid:
        from starforge.tracking.avoid import faces_to_avoid

        faces = faces_to_avoid([Path(a) for a in avoid])[0] / 1000.0  # mm -> m
    return run_placement(prop, spec, seed=seed, units=units, grip=grip, avoid=faces, progress=progress, **overrides)


def write_placement(result, out: str | Path, *, pictures: bool = True, force: bool = False) -> Path:
    """Write a placement's files (``placement.json``, ``markers.csv``, the prop with its markers,
    and with ``pictures`` the layout, convergence and rigging-guide pictures); returns the folder."""
    from starforge.props.files import write_outputs

    renderer = None
    if pictures:
        from starforge.render.props import BackgroundRenderer

        renderer = BackgroundRenderer(enabled=False)
    folder = Path(out)
    with staged_output(folder, force) as stage:
        write_outputs(result, stage, render=pictures, renderer=renderer)
    return folder
