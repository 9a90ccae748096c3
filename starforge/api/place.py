"""Markers on a prop: where to stick them, and the files and pictures of the placement."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from starforge.io import staged_output

__all__ = ["distinct_tolerance_mm", "place_markers", "write_placement"]


def distinct_tolerance_mm(spec, preset: str | None, noise_mm: float) -> float:
    """How far (mm, every sorted side) the layout's triangles keep from each other and from
    other bodies': twice the tracker's window at ``noise_mm``
    (:func:`starforge.tracking.presets.design_tolerance_mm` for bodies of the spec's marker
    count), or the spec's ``avoid_tolerance_mm`` when larger."""
    from starforge.spec import in_range
    from starforge.tracking.presets import design_tolerance_mm

    in_range("noise", noise_mm, 0.0, 100.0)
    n = spec.track.target_markers if spec.objective == "tracked" else spec.costs.target_markers
    return max(spec.track.avoid_tolerance_mm, design_tolerance_mm(preset, noise_mm, n_markers=n))


def place_markers(
    prop: str = "hammer",
    *,
    spec: str = "default",
    seed: int = 0,
    units: str = "m",
    avoid: Sequence[str | Path] = (),
    grip: str | None = None,
    preset: str | None = None,
    noise_mm: float = 0.2,
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
    preset, noise_mm : str or None, float
        The tracker the layout is designed for and its marker noise (sigma per axis, mm): every
        marker triangle keeps :func:`distinct_tolerance_mm` from the others, from itself
        relabelled and from ``avoid``'s.
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
    from starforge.props.spec import load_spec, with_overrides

    if "distinct_mm" not in overrides:
        designed = with_overrides(load_spec(spec), **{k: v for k, v in overrides.items() if k != "hand"})
        overrides["distinct_mm"] = distinct_tolerance_mm(designed, preset, noise_mm)
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
