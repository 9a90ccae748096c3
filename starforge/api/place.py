"""Markers on a prop: where to stick them, and the files and pictures of the placement.

``starforge place`` is :func:`run_place` (the files written) and :func:`describe_placement` (its
summary); ``starforge place score`` is :func:`score_markers` and :func:`describe_score`.  A
notebook calls :func:`plan_placement`, :func:`place_markers` and :func:`write_placement`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from starforge.errors import StarforgeError
from starforge.io import check_input_file, check_writable, staged_output
from starforge.runtime import progress as runtime_progress
from starforge.spec import in_range

if TYPE_CHECKING:  # the props' modules load with their first call, not with the API
    from starforge.props.costs import CostBreakdown
    from starforge.props.mesh import PropMesh
    from starforge.props.result import PlacementResult
    from starforge.props.spec import PlaceSpec

__all__ = [
    "NOISE_MM",
    "PlacePlan",
    "PlaceRun",
    "ScoreResult",
    "describe_placement",
    "describe_score",
    "distinct_tolerance_mm",
    "distinct_tolerances_mm",
    "place_markers",
    "placement_files",
    "plan_placement",
    "run_place",
    "score_markers",
    "write_placement",
]

#: the marker noise (sigma per axis, mm) the layouts' triangles are designed for by default
NOISE_MM = 0.2


def distinct_tolerances_mm(spec: PlaceSpec, preset: str | None, noise_mm: float) -> tuple[float, ...]:
    """How far (mm, every sorted side) a layout of ``n`` markers keeps its triangles from each
    other and from other bodies', entry ``n`` for ``n`` in 0 .. the spec's ``max_markers``: twice
    the tracker's window at ``noise_mm`` for bodies of ``n`` markers
    (:func:`starforge.tracking.presets.design_tolerance_mm`; the window widens with the count, as
    more distances must stay within it), or the spec's ``avoid_tolerance_mm`` when larger.  A
    layout grown past its target (``track.grow_markers``) is designed with the entry of the
    count it tries.

    >>> from starforge.props.spec import load_spec
    >>> table = distinct_tolerances_mm(load_spec("default"), None, 0.2)
    >>> round(table[7], 3), round(table[11], 3)  # the spec's 2.6 mm floor; 11 markers need more
    (2.6, 2.7)
    """
    from starforge.tracking.presets import design_tolerance_mm

    in_range("noise", noise_mm, 0.0, 100.0)
    top = max(spec.track.max_markers, spec.costs.max_markers)
    return tuple(
        max(spec.track.avoid_tolerance_mm, design_tolerance_mm(preset, noise_mm, n_markers=max(n, 2)))
        for n in range(top + 1)
    )


def distinct_tolerance_mm(spec: PlaceSpec, preset: str | None, noise_mm: float) -> float:
    """:func:`distinct_tolerances_mm`'s entry for the spec's target marker count, mm."""
    n = spec.track.target_markers if spec.objective == "tracked" else spec.costs.target_markers
    return distinct_tolerances_mm(spec, preset, noise_mm)[n]


@dataclass(frozen=True)
class PlacePlan:
    """What :func:`place_markers` places: the loaded prop, the validated spec, the hand and the
    bodies to keep clear of.

    Attributes
    ----------
    prop : PropMesh
        The prop's mesh (m), repaired, with its name and source.
    spec : PlaceSpec
        The template with the options applied, the triangle tolerance designed for the tracker.
    grip : str or None
        ``--grip`` text pinning one grip (``N`` or ``x0,y0,z0,x1,y1,z1[,r]``); None: every grip of
        the distribution (or no hand when ``spec.hand`` is false).
    avoid_m : (k, 3) float, m, or None
        Sorted side lengths of the marker triangles of the bodies to keep clear of.
    tolerances_mm : tuple of float or None
        The triangle tolerance for each marker count (:func:`distinct_tolerances_mm`), mm, that a
        layout grown past its target is designed with; None: the spec's for every count (a
        ``distinct_mm`` given).
    """

    prop: PropMesh
    spec: PlaceSpec
    grip: str | None = None
    avoid_m: np.ndarray | None = field(default=None, repr=False)
    tolerances_mm: tuple[float, ...] | None = None


def _prop_and_spec(prop: str, spec: str | PlaceSpec, units: str, forbid_mesh, mask, smooth: bool = True, **overrides):
    """The prop and the spec with ``overrides`` (:func:`starforge.props.spec.with_overrides`
    keywords) and the constrained areas applied; the files are checked before the prop loads."""
    from starforge.props.mesh import load_prop
    from starforge.props.spec import as_spec, with_overrides

    s = as_spec(spec)
    cons = None
    if forbid_mesh or mask:
        cons = s.constraints
        if forbid_mesh:
            check_input_file(forbid_mesh, "--forbid-mesh file", "mesh")  # before the long work
            cons = replace(cons, mesh=str(forbid_mesh))
        if mask:
            check_input_file(mask, "--mask file", "mask")
            cons = replace(cons, mask=str(mask))
    s = with_overrides(s, constraints=cons, **overrides)
    return load_prop(prop, units, smooth=smooth), s


def plan_placement(
    prop: str = "hammer",
    *,
    spec: str | PlaceSpec = "default",
    units: str = "m",
    grip: str | None = None,
    hand: bool | None = None,
    avoid: Sequence[str | Path] = (),
    preset: str | None = None,
    noise_mm: float = NOISE_MM,
    forbid_mesh: str | Path | None = None,
    mask: str | Path | None = None,
    smooth: bool = True,
    **overrides,
) -> PlacePlan:
    """The prop, the spec and the bodies to avoid of a placement, from a template and options.

    Parameters
    ----------
    prop : str
        Built-in prop (``hammer``, ``sword``, ...; ``builtin:NAME`` when a path has that name) or
        a mesh path (STL, OBJ, PLY, GLB, OFF).
    spec : str or PlaceSpec
        Place template name or TOML file (``starforge templates place``), or a spec.
    units : str
        Units of a mesh file: ``m``, ``cm`` or ``mm``.
    grip : str, optional
        ``N`` (grip N of the distribution), ``x0,y0,z0,x1,y1,z1[,r]`` (a fist around that
        segment, prop frame, m) or ``none`` (no hand); default: every grip of the distribution.
    hand : bool, optional
        False: no hand holds the prop (``grip`` is then ignored); default: the spec's.
    avoid : sequence of path
        Bodies already in the room (placements, families, tracker files).
    preset, noise_mm : str or None, float
        The tracker the layout is designed for and its marker noise (sigma per axis, mm): every
        marker triangle keeps :func:`distinct_tolerance_mm` from the others, from itself
        relabelled and from ``avoid``'s (unless ``distinct_mm`` is given).
    forbid_mesh, mask : path, optional
        A mesh of a constrained area, and a per-face mask file (1: no markers on that face).
    smooth : bool
        Smooth a scanned mesh's noise where it tilts the faces (:mod:`starforge.props.scan`);
        False keeps the mesh as it is.
    **overrides
        :func:`starforge.props.spec.with_overrides` keywords (``markers``, ``sites``, ``rig``,
        ``resolution``, ``orientations``, ``marker_mm``, ``base_mm``, ``standoff_mm``, ``cameras_lost``...);
        None means not given.

    Examples
    --------
    >>> plan = plan_placement("box", markers=5, grip="none")
    >>> plan.prop.name, plan.spec.track.target_markers, plan.spec.hand, plan.grip
    ('box', 5, False, None)
    """
    from starforge.props.spec import with_overrides

    if grip is not None and str(grip).strip().lower() == "none":
        hand, grip = False, None
    if hand is False:
        grip = None
    loaded, s = _prop_and_spec(prop, spec, units, forbid_mesh, mask, smooth, hand=hand, **overrides)
    table = None
    if overrides.get("distinct_mm") is None:
        table = distinct_tolerances_mm(s, preset, noise_mm)
        s = with_overrides(s, distinct_mm=distinct_tolerance_mm(s, preset, noise_mm))
    faces = None
    if avoid:
        from starforge.tracking.avoid import faces_to_avoid

        faces = faces_to_avoid([Path(a) for a in avoid])[0] / 1000.0  # mm -> m
    return PlacePlan(loaded, s, None if grip is None else str(grip), faces, table)


def place_markers(
    prop: str | PlacePlan = "hammer",
    *,
    seed: int = 0,
    progress: Callable[[str, int, int | None], None] | None = None,
    on_layout: Callable[[PlacementResult], None] | None = None,
    **options,
) -> PlacementResult:
    """Where to stick markers on a prop: a built-in name or a mesh file, optimized by
    reversible-jump MCMC so that a tracker keeps it while a hand holds it and cameras drop out.

    Parameters
    ----------
    prop : str or PlacePlan
        A prop (see :func:`plan_placement`) or a plan.
    seed : int
        Seeds every random choice; same seed, same result.
    progress : callable, optional
        ``progress(stage, done, total)``.
    on_layout : callable, optional
        ``on_layout(result)`` as soon as the layout is chosen, before its check on fresh poses.
    **options
        :func:`plan_placement`'s keywords (``spec``, ``units``, ``avoid``, ``grip``, ``preset``,
        ``noise_mm``, ``markers``, ``sites``, ``resolution``, ``orientations``, ``marker_mm``...).

    Returns
    -------
    PlacementResult

    Examples
    --------
    >>> res = place_markers("box", sites=150, resolution=1, orientations=6, seed=1)
    >>> len(res.marker_points) >= 4 and res.marker_points.shape[1] == 3
    True
    """
    from starforge.props.placement import place

    plan = prop if isinstance(prop, PlacePlan) else plan_placement(prop, **options)
    return place(
        plan.prop, plan.spec, seed=seed, progress=progress, avoid=plan.avoid_m, grip=plan.grip, on_layout=on_layout,
        tolerances_mm=plan.tolerances_mm,
    )  # fmt: skip


def placement_files(spec: PlaceSpec, *, bases_stl: bool = False) -> list[str]:
    """The files :func:`run_place` may write for ``spec`` (``standoff.stl`` with a stand-off, and
    ``clamps.stl`` when a post stands on a rod; ``prop_bases.stl`` with ``bases_stl``)."""
    names = ["placement.json", "markers.csv", f"prop_markers.{spec.mesh_format}"]
    names += ["convergence.png", "layout.png", "guide.png", "guide.pdf"]
    names += ["standoff.stl", "clamps.stl"] if spec.standoff_mm > 0 else []
    return names + (["prop_bases.stl"] if bases_stl else [])


def write_placement(result: PlacementResult, out: str | Path, *, pictures: bool = True, force: bool = False) -> Path:
    """Write a placement's files (``placement.json``, ``markers.csv``, the prop with its markers,
    and with ``pictures`` the layout, convergence and rigging-guide pictures); returns the folder."""
    from starforge.props.files import write_outputs

    renderer = None
    if pictures:
        from starforge.render.props import BackgroundRenderer

        renderer = BackgroundRenderer(enabled=False)
    folder = Path(out)
    with staged_output(folder, force) as stage:
        written = write_outputs(result, stage, render=pictures, renderer=renderer)
    _drop_stale(folder, written, force)
    return folder


def _drop_stale(folder: Path, written: list[str], force: bool) -> None:
    """Remove the ``clamps.stl`` an earlier run left in ``folder`` (replaced with ``force``) when
    this layout has no clamp: it would not fit these markers."""
    if force and "clamps.stl" not in written:
        (folder / "clamps.stl").unlink(missing_ok=True)


@dataclass(frozen=True)
class PlaceRun:
    """What :func:`run_place` placed and wrote.

    Attributes
    ----------
    result : PlacementResult
        The placement.
    folder : Path
        Where its files are.
    files : tuple of str
        The files written there (:func:`placement_files`).
    """

    result: PlacementResult
    folder: Path
    files: tuple[str, ...]


def run_place(
    prop: str = "hammer",
    *,
    out: str | Path = "out/place",
    seed: int = 0,
    force: bool = False,
    bases_stl: bool = False,
    on_layout: Callable[[PlacementResult], None] | None = None,
    **options,
) -> PlaceRun:
    """``starforge place`` as one call: plan the placement (:func:`plan_placement`), refuse before
    any work what cannot be read or written, place the markers and write every file and picture
    (the pictures drawn in a process of their own while the layout is checked on fresh poses).

    Parameters
    ----------
    prop : str
        Built-in prop or mesh path (see :func:`plan_placement`).
    out : path
        Output folder; existing files are replaced only with ``force``.
    bases_stl : bool
        Also write ``prop_bases.stl``: the prop with a flat pad under every marker.
    on_layout : callable, optional
        ``on_layout(result)`` once the layout is chosen, while the pictures are drawn.
    **options
        :func:`plan_placement`'s keywords; None means not given.

    Examples
    --------
    >>> import tempfile
    >>> run = run_place("box", out=Path(tempfile.mkdtemp()) / "box", sites=150, resolution=1, orientations=6)
    >>> sorted(run.files) == sorted(p.name for p in run.folder.iterdir())
    True
    """
    from starforge.render.props import BackgroundRenderer

    if not isinstance(seed, int) or seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if options.get("avoid"):  # the files to avoid exist and are readable before any work starts
        from starforge.tracking.bodies import check_body_files

        check_body_files([Path(a) for a in options["avoid"]], "--avoid file")
    folder = Path(out)
    # the picture-drawing process forks first, so that its matplotlib import overlaps the work
    with BackgroundRenderer() as renderer:
        from starforge.props.files import write_outputs

        plan = plan_placement(prop, **options)
        names = placement_files(plan.spec, bases_stl=bases_stl)
        check_writable(folder, names, force)  # fail before the work, not after
        with staged_output(folder, force) as stage:

            def chosen(res):  # the pictures are drawn while the layouts are evaluated on fresh poses
                renderer.submit(res, stage)
                if on_layout is not None:
                    on_layout(res)

            res = place_markers(plan, seed=seed, on_layout=chosen)
            with runtime_progress.stage("render", unit="pictures"):
                written = write_outputs(res, stage, renderer=renderer, bases_stl=bases_stl)
    _drop_stale(folder, written, force)
    return PlaceRun(res, folder, tuple(n for n in names if n in written))


def describe_placement(result: PlacementResult) -> list[str]:
    """The lines ``starforge place`` prints: the prop, sites, poses, grips, the layout's scores
    and what each stage took (its warnings are ``result.warnings``)."""
    from starforge.props.files import summary_lines

    t = result.timings
    load = t.get("load_s", 0.0) + t.get("repair_s", 0.0)
    return [
        *summary_lines(result),
        f"time: load {load:.2f} s, sites {t.get('sample_s', 0):.2f} s, visibility {t['visibility_s']:.2f} s, "
        f"optimization {t['optimize_s']:.2f} s, evaluation {t.get('evaluate_s', 0):.2f} s",
    ]


@dataclass(frozen=True)
class ScoreResult:
    """A given layout scored on a prop (:func:`score_markers`).

    Attributes
    ----------
    prop : str
        The prop's name.
    cost : CostBreakdown
        The spec's objective's cost and its terms.
    visibility : (m,) float
        Each marker's visibility over the scenarios, in [0, 1].
    extra : dict
        Each marker's seat (``seated``, ``contact``, ``edge_mm``, ``seat_margin_mm``) and, for the
        tracked objective, ``tracked_fraction``, the self-margins (mm) and the fresh-pose
        ``evaluation``.
    """

    prop: str
    cost: CostBreakdown
    visibility: np.ndarray = field(repr=False)
    extra: dict = field(repr=False)

    def to_json(self) -> dict:
        """What ``starforge place score --json`` prints."""
        return {
            **self.cost.to_json(),
            "marker_visibility": [round(float(v), 9) for v in self.visibility],
            **self.extra,
        }


def score_markers(
    prop: str,
    markers: str | Path | np.ndarray,
    *,
    spec: str | PlaceSpec = "default",
    units: str = "m",
    seed: int = 0,
    **overrides,
) -> ScoreResult:
    """Score a given marker layout on a prop under a spec (the paper's expert comparison).

    Parameters
    ----------
    prop : str
        Built-in prop or mesh path (see :func:`plan_placement`).
    markers : path or (m, 3) float, m
        A markers CSV (``id,x_m,y_m,z_m[,nx,ny,nz]``, prop frame) or the points; each on the
        prop's surface (see :func:`starforge.props.score.score_layout`).
    spec : str or PlaceSpec
        Place template name or TOML file, or a spec.
    seed : int
        Seeds the poses' orientations and the camera losses.
    **overrides
        :func:`starforge.props.spec.with_overrides` keywords (``rig``, ``resolution``,
        ``orientations``...); None means not given.

    Examples
    --------
    >>> import numpy as np
    >>> plan = plan_placement("box")
    >>> on_box = plan.prop.mesh.nearest.on_surface(plan.prop.mesh.vertices[:5])[0]
    >>> score = score_markers("box", on_box, resolution=1, orientations=6)
    >>> score.cost.markers, len(score.visibility)
    (5, 5)
    """
    from starforge.props.files import read_markers_csv
    from starforge.props.score import score_layout

    loaded, s = _prop_and_spec(prop, spec, units, None, None, **overrides)
    if isinstance(markers, str | Path):
        pts, nrm = read_markers_csv(markers)
    else:
        pts, nrm = np.asarray(markers, dtype=float), None
    cost, vis, extra = score_layout(loaded, pts, nrm, s, seed=seed)
    return ScoreResult(loaded.name, cost, vis, extra)


def describe_score(score: ScoreResult) -> list[str]:
    """The lines ``starforge place score`` prints."""
    cost, extra = score.cost, score.extra
    seated = extra.get("seated", [])
    lines = [
        f"{score.prop}: {cost.markers} markers, cost {cost.total:.4f}",
        f"  seated: {sum(seated)} of {len(seated)} markers (their base rests on the surface, clear of sharp edges)",
    ]
    if "tracked_fraction" in extra:
        lines.append(
            f"  tracked in {100 * extra['tracked_fraction']:.1f} % of the scenarios, mean visibility {cost.mean_visibility:.3f}"
        )
        m3, m4 = (extra[k] for k in ("self_margin_mm", "self_margin_4_mm"))
        if m3 is not None:
            lines.append(
                f"  self-margin {m3:.2f} mm from any 3 markers"
                + (f", {m4:.2f} mm from any 4" if m4 is not None else "")
                + " (under a tracker's window, those markers flip)"
            )
        ev = extra.get("evaluation")
        if ev:
            lines.append(
                f"  on fresh poses with cameras lost and the hand: tracked {100 * ev['tracked']:.1f} %, "
                f"markers reconstructed {ev['markers_reconstructed']:.3f}"
            )
        return lines
    lines.append(
        f"  visibility {cost.visibility:.4f} (mean {cost.mean_visibility:.3f}), count {cost.count:.4f}, "
        f"overlap {cost.overlap:.4f} ({cost.overlapping_pairs} pairs), symmetry {cost.symmetry:.0f}"
    )
    if not math.isinf(cost.margin_m):
        lines.append(f"  near-symmetry margin {cost.margin_m * 1000:.1f} mm")
    return lines
