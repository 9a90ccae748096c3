"""Marker placement end to end: prop -> seated sites -> visibility table -> optimizer -> result.

:func:`run_placement` runs one placement from plain arguments (a prop name or path, a spec
name, a seed) and returns the :class:`PlacementResult`; :func:`place` does the same from a
loaded prop and spec.  The files are written by :mod:`starforge.props.files`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.costs import CostBreakdown, evaluate
from starforge.props.optimizer import AnnealResult, anneal
from starforge.props.sites import Sites
from starforge.props.spec import PlaceSpec
from starforge.runtime.progress import note as progress_note
from starforge.runtime.progress import report as progress_report
from starforge.spec import require
from starforge.stars.avoid import body_triangles


@dataclass(frozen=True)
class PlacementResult:
    """One optimized placement with everything needed to re-check it."""

    prop: object  # PropMesh
    spec: PlaceSpec
    seed: int
    rig: object  # Rig
    poses: object  # Poses
    sites: Sites
    forbidden: int
    site_visibility: np.ndarray = field(repr=False)
    marker_sites: tuple[int, ...] = ()
    cost: CostBreakdown | None = None
    anneal: AnnealResult | None = None
    marker_pose_seen: np.ndarray = field(default=None, repr=False)  # (m, scenarios) seen
    timings: dict = field(default_factory=dict)
    rays: int = 0
    tracked: object = None  # starforge.props.tracked.Optimized for the tracked objective
    warnings: tuple[str, ...] = ()
    spacing_m: float = 0.0
    seat: object = None  # starforge.props.seat.Seat
    seat_report: object = None  # starforge.props.seat.SeatReport over ``sites``
    capsules: tuple = ()  # the hand (starforge.props.hand.Capsule)
    removed: dict = field(default_factory=dict)  # sampled sites removed, by reason
    evaluation: dict = field(default_factory=dict)  # starforge.props.evaluate on fresh poses
    marker_masks: np.ndarray = field(default=None, repr=False)  # (m, poses) uint64 camera bits
    shortfall: dict = field(default_factory=dict)  # below track.target_tracked on the held-out sample: why
    grips: tuple = ()  # starforge.props.grips.Grip: the hand's distribution the layout was scored under
    part: object = None  # starforge.props.grips.HeldPart: where they hold it

    @property
    def marker_points(self) -> np.ndarray:
        return self.sites.points[list(self.marker_sites)]

    @property
    def marker_normals(self) -> np.ndarray:
        return self.sites.normals[list(self.marker_sites)]

    @property
    def marker_visibility(self) -> np.ndarray:
        return self.site_visibility[list(self.marker_sites)]

    def centres(self, sites=None) -> np.ndarray:
        """(m, 3) ball centres of ``sites`` (default: the markers), m: on the seat's axis."""
        idx = list(self.marker_sites if sites is None else sites)
        return self.sites.points[idx] + self.seat.centre_height_m * self.sites.normals[idx]


def _tick(timings: dict, key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = round(now - t0, 4)
    return now


@dataclass(frozen=True)
class Prepared:
    """The optimizer's input: seated sites, the rig, the poses and the visibility table."""

    sites: Sites
    removed: dict
    rig: object
    poses: object
    table: object
    seat: object
    seat_report: object
    capsules: tuple  # every grip's capsules together (what the pictures outline)
    grips: tuple = ()  # starforge.props.grips.Grip: the distribution the layout is scored under
    pose_grip: np.ndarray = field(default=None, repr=False)  # (poses,) the grip of each pose
    part: object = None  # starforge.props.grips.HeldPart
    notes: tuple = ()  # warnings about the preparation


def hand_grips(prop, spec: PlaceSpec, grip=None) -> tuple:
    """``(held part, grips)``: the grips of :func:`starforge.props.grips.grip_distribution`, or
    only ``grip`` when given (a :class:`~starforge.props.grips.Grip`, a Capsule, or ``--grip``
    text: ``N`` or ``x0,y0,z0,x1,y1,z1[,r]``); ``(None, ())`` when the spec has no hand."""
    from starforge.props.grips import Grip, grip_distribution, pinned_grip
    from starforge.props.hand import GRIPS, Capsule

    if not spec.hand:
        return None, ()
    own = GRIPS.get(prop.name) if prop.source == "builtin" else None
    part, grips = grip_distribution(prop.mesh, fallback=own)
    if grip is None:
        return part, grips
    if isinstance(grip, Grip):
        return part, (grip,)
    if isinstance(grip, Capsule):
        return part, (Grip("pinned: a fist", "", 0.5, 0.0, (grip,)),)
    return part, (pinned_grip(str(grip), grips),)


def prepare(prop, spec: PlaceSpec, rng: np.random.Generator, progress=None, timings=None, grip=None, seed: int = 0) -> Prepared:
    """Sites that seat the marker (constrained areas and the hand removed), rig, poses, table."""
    from starforge.props.grips import (
        FEW_SITES,
        GRIP_SEED_OFFSET,
        assign_grips,
        grip_arrays,
        grips_summary,
        under_hand,
    )
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.seat import seat_report
    from starforge.props.sites import forbidden_sites, sample_sites
    from starforge.props.visibility import compute_table

    timings = {} if timings is None else timings
    t = time.perf_counter()
    notes: list[str] = []
    rig = load_rig(spec.rig)
    sites = sample_sites(prop.mesh, spec.sites, rng)
    if spec.constraints.empty:
        bad = np.zeros(len(sites), dtype=bool)
    else:
        bad = forbidden_sites(sites, spec.constraints, prop.face_origin, prop.source_faces)
    seat = spec.marker_seat()
    part, grips = hand_grips(prop, spec, grip)
    caps = tuple(c for g in grips for c in g.capsules)
    centres = sites.points + seat.centre_height_m * sites.normals
    hand = under_hand(sites.points, centres, grips) & ~bad
    wanted = spec.track.target_markers if spec.objective == "tracked" else spec.costs.target_markers
    if grips and int((~bad & ~hand).sum()) < FEW_SITES * wanted:  # held almost everywhere
        hand = under_hand(sites.points, centres, grips, share=0.5) & ~bad
        notes.append(
            f"the prop can be held almost anywhere ({grips_summary(part, grips)}): markers keep off only where more "
            "than half of the grips hold it (--grip N pins one grip)"
        )
    rest = ~bad & ~hand
    report = seat_report(prop.mesh, sites.points[rest], sites.normals[rest], seat, spec.seat)
    ok = np.zeros(len(sites), bool)
    ok[np.flatnonzero(rest)[report.ok]] = True
    removed = {"constrained": int(bad.sum()), "under_hand": int(hand.sum()), "unseated": int((rest & ~ok).sum())}
    kept = sites.subset(ok)
    report = report.subset(report.ok)
    need = spec.track.min_markers if spec.objective == "tracked" else spec.costs.min_markers
    if len(kept) < need:
        raise StarforgeError(
            f"only {len(kept)} of the {len(sites)} candidate sites seat a {seat.name} marker "
            f"(base {seat.base_mm:g} mm): {removed['constrained']} in constrained areas, "
            f"{removed['under_hand']} under the hand, {removed['unseated']} where the base does not rest "
            f"(curved, near an edge or the ball cuts in); fewer than the {need} markers needed: try a "
            "smaller --marker or --base-mm, or --no-hand"
        )
    if spec.objective == "tracked":
        check_trackable(kept.points + seat.centre_height_m * kept.normals, spec, rig, seat, removed)
    t = _tick(timings, "sample_s", t)
    pivot = np.asarray(prop.mesh.bounds, dtype=float).mean(axis=0)
    check_cost(prop, spec, rig, len(kept), spec.resolution**3 * spec.orientations)  # before building them
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    if progress is not None:
        progress(0, None)  # the rays' stage starts with its work
    pose_grip = assign_grips(len(poses), len(grips), np.random.default_rng(seed + GRIP_SEED_OFFSET))
    occ, starts = grip_arrays(grips)
    table = compute_table(
        prop.mesh,
        kept.points,
        kept.normals,
        rig,
        poses,
        spec.grazing_limit_deg,
        progress=progress,
        radius_m=seat.ball_radius_m,
        centre_m=seat.centre_height_m,
        occlusion=spec.occlusion,
        occluders=occ,
        occluder_starts=starts,
        pose_grip=pose_grip,
    )
    _tick(timings, "visibility_s", t)
    return Prepared(kept, removed, rig, poses, table, seat, report, caps, grips, pose_grip, part, tuple(notes))


def check_trackable(centres: np.ndarray, spec: PlaceSpec, rig, seat, removed: dict) -> None:
    """Refuse, before the visibility table, seated sites on which no layout can ever be tracked:
    no three of them lie the marker spacing apart (closer markers merge in the images), or every
    ball centre lies so near one line that no markers on them span the tracker's triangle
    (:func:`starforge.props.tracked.line_reach`, an upper bound: never a false alarm).  Both are
    proofs about every layout, not a search that failed."""
    from starforge.props.tracked import TRIANGLE_SPREAD, line_reach, spaced_triple, spacing_m

    ts = spec.track
    hand = f"; {removed['under_hand']} sites under the hand (another --grip or --no-hand frees them)" if removed["under_hand"] else ""
    advice = (
        "; try another --marker or --base-mm (a smaller base seats on more of the prop, a taller marker "
        "holds its ball farther from a thin prop's faces)" + hand
    )
    spacing = spacing_m(ts.marker_mm, rig, ts.gap_px)
    if not spaced_triple(centres, spacing):
        raise StarforgeError(
            f"no layout on this prop can be tracked: no three of its {len(centres)} usable sites lie "
            f"{spacing * 1000:.1f} mm apart (closer {ts.marker_mm:g} mm markers merge in the camera images), "
            f"and a tracker needs three{advice}"
        )
    need = TRIANGLE_SPREAD * ts.min_height_mm / 1000.0
    rho = line_reach(centres, refine_below=2.0 * need)  # past twice the spread the search is not run
    if rho < need:
        raise StarforgeError(
            f"no layout on this prop can be tracked: every ball centre on its {len(centres)} usable sites "
            f"({seat.name} markers, centres {seat.centre_height_m * 1000:g} mm off the surface) lies within "
            f"{rho * 1000:.2f} mm of one line, so no markers on them span the {ts.min_height_mm:g} mm triangle a "
            f"tracker needs (an RMS distance of {need * 1000:.2f} mm from their line; a thin part's two faces hold "
            f"their balls its thickness plus {2 * seat.centre_height_m * 1000:g} mm apart){advice}"
        )


def check_cost(prop, spec: PlaceSpec, rig, sites: int, poses: int) -> None:
    """Refuse, before the visibility table, work past the memory or time limit (one line)."""
    from starforge.runtime.budget import require_memory, require_time

    cams = len(rig.cameras)
    patterns = spec.track.loss_patterns if spec.objective == "tracked" else 1
    what = f"a visibility table of {sites:,} sites x {poses:,} poses x {cams} cameras"
    advice = "lower --resolution, --orientations or --sites"
    require_memory(sites * poses * (8 + 3 * patterns + len(rig.pairs)) + sites * poses * 16 + 50e6, what, advice)
    require_time(sites * poses * cams * 1e-7 + 1.0, what, advice)


def check_scale(prop, rig, marker_m: float) -> list[str]:
    """Refuse a prop whose size says it is in other units; warn when it does not fit the volume,
    upright or turned.

    A prop larger than twice the capture volume, or smaller than four markers, cannot be what was
    meant: the message names the ``--units`` that would make it a plausible size.  The poses turn
    the prop about its bounding-box centre, so it sweeps a ball as wide as twice its farthest
    point from that centre: a prop that fits upright but not that ball gets its own warning.
    """
    ext = float(np.max(prop.mesh.extents))
    vol = float(np.max(rig.volume.size))
    if ext > 2 * vol or ext < 4 * marker_m:
        from starforge.props.mesh import units_hint

        hint = "; " + units_hint(ext, prop.units, 4 * marker_m, vol)
        size = " x ".join(f"{e:.4g}" for e in prop.mesh.extents)
        raise StarforgeError(
            f"prop {prop.name} is {size} m read as {prop.units}: "
            + (f"larger than twice the capture volume ({vol:g} m)" if ext > 2 * vol
               else f"smaller than four markers ({4 * marker_m * 1000:g} mm)")
            + hint
        )
    size = np.asarray(rig.volume.size, float)
    vol_text = " x ".join(f"{e:g}" for e in size)
    if np.any(np.asarray(prop.mesh.extents) > size):
        return [
            f"the prop ({' x '.join(f'{e:.3g}' for e in prop.mesh.extents)} m) does not fit inside the capture volume ({vol_text} m)"
        ]
    pivot = np.asarray(prop.mesh.bounds, float).mean(axis=0)
    span = 2.0 * float(np.linalg.norm(np.asarray(prop.mesh.vertices) - pivot, axis=1).max())
    if span > size.min():
        return [
            f"the prop fits the capture volume ({vol_text} m) upright but not when turned: turned about its "
            f"centre it sweeps {span:.3g} m, more than the volume's smallest side {size.min():g} m"
        ]
    return []


def prop_name_warnings(prop) -> list[str]:
    """Say which prop was used when a built-in name is also a path here."""
    from starforge.props.builtin import BUILTIN

    if prop.source == "builtin" and Path(prop.name).exists():
        return [f"a path named {prop.name!r} exists here; the built-in {prop.name} was used (./{prop.name} names the path)"]
    if prop.source != "builtin" and Path(prop.source).name in BUILTIN and Path(prop.source).stem == prop.source.removeprefix("./"):
        name = Path(prop.source).name
        return [f"the file {prop.source!r} was used, not the built-in {name} (builtin:{name} names it)"]
    return []


def run_placement(
    prop: str = "hammer",
    spec: str | PlaceSpec = "default",
    seed: int = 0,
    units: str = "m",
    grip: str | None = None,
    avoid: np.ndarray | None = None,
    progress=None,
    **overrides,
) -> PlacementResult:
    """One placement from plain arguments (the library entry point, e.g. for a batch).

    Parameters
    ----------
    prop : str
        A built-in name (``hammer``, ``builtin:hammer``) or a mesh path.
    spec : str or PlaceSpec
        A place template name or TOML path, or a spec.
    seed : int
    units : str
        Units of a mesh file (m, cm, mm).
    grip : str, optional
        ``N`` (grip N of the printed distribution), ``x0,y0,z0,x1,y1,z1[,r]`` (a fist around that
        segment, prop frame, m), ``none`` for no hand; default: the distribution of grips.
    avoid : (k, 3) float, m, optional
        Sorted side lengths of the marker triangles of bodies already in the room
        (:func:`starforge.tracking.avoid.faces_to_avoid` reads them from files, in mm).
    **overrides
        :func:`starforge.props.spec.with_overrides` keywords (``markers``, ``marker_mm``, ...).
    """
    from starforge.props.mesh import load_prop
    from starforge.props.spec import load_spec, with_overrides

    s = spec if isinstance(spec, PlaceSpec) else load_spec(spec)
    cap = None
    if grip is not None and str(grip).strip().lower() == "none":
        overrides["hand"] = False
    elif grip is not None:
        cap = str(grip)
    s = with_overrides(s, **overrides)
    return place(load_prop(prop, units), s, seed=seed, progress=progress, avoid=avoid, grip=cap)


def _stages(progress):
    """``progress(stage, done, total)``: the caller's callback (if any) and the process's progress
    stages (:mod:`starforge.runtime.progress`)."""
    shown = progress_report()

    def both(name: str, done, total) -> None:
        shown(name, done, total)
        if progress is not None:
            progress(name, done, total)

    return both


def _prepared(prop, spec: PlaceSpec, seed: int, progress, grip):
    """What every placement starts from: ``(rng, timings, progress, warnings, prepared)``, the
    generator having drawn the sites and poses."""
    require(isinstance(seed, int) and seed >= 0, f"seed must be an integer >= 0, got {seed}")
    rng = np.random.default_rng(seed)
    timings: dict = dict(getattr(prop, "timings", {}) or {})
    progress = _stages(progress)
    from starforge.props.rig import load_rig

    warnings = prop_name_warnings(prop) + check_scale(prop, load_rig(spec.rig), spec.marker_diameter_m)
    seat = spec.marker_seat()
    if seat.name.endswith(" mm ball"):
        warnings.append(
            f"a {seat.ball_mm:g} mm marker is not in the catalogue: a generic ball on a {seat.base_mm:g} mm base with its "
            f"centre {seat.centre_height_mm:g} mm above it is assumed (--marker NAME for a catalogue marker, --base-mm for the base)"
        )
    from starforge.props.tracked import kernels_compiled
    from starforge.runtime.kernels import FIRST_RUN_NOTE

    if not kernels_compiled():
        progress_note(FIRST_RUN_NOTE)
    progress("sites", 0, None)
    prep = prepare(prop, spec, rng, lambda d, n: progress("rays", d, n), timings, grip, seed)
    return rng, timings, progress, warnings + list(prep.notes), prep


def place(
    prop, spec: PlaceSpec, seed: int = 0, progress=None, avoid=None, grip=None, on_layout=None
) -> PlacementResult:
    """Optimize a marker set on ``prop`` (a :class:`starforge.props.mesh.PropMesh`).

    Parameters
    ----------
    prop : PropMesh
    spec : PlaceSpec
    seed : int
        Seeds ``numpy.random.default_rng``; same seed, same result.
    progress : callable, optional
        ``progress(stage, done, total)`` for a progress bar.
    avoid : (k, 3) float or None
        Marker triangles (sorted sides, m) of props and stars already in the room (tracked
        objective): the layout's triangles keep ``avoid_tolerance_mm`` from them.
    grip : starforge.props.hand.Capsule, optional
        The hand (default: the prop's grip, when ``spec.hand``).
    on_layout : callable, optional
        ``on_layout(result)`` as soon as the layout is chosen, before the fresh-pose evaluation
        (the tracked objective): ``result`` then lacks only ``evaluation`` and that step's
        warnings (the CLI starts drawing the pictures, which need neither).
    """
    rng, timings, progress, warnings, prep = _prepared(prop, spec, seed, progress, grip)
    if spec.objective == "tracked":
        return _place_tracked(prop, spec, seed, rng, prep, timings, warnings, avoid, progress, on_layout)
    res = _place_paper(prop, spec, seed, rng, prep, timings, warnings, progress)
    if on_layout is not None:
        on_layout(res)
    return res


def place_copies(
    prop, spec: PlaceSpec, copies: int, seed: int = 0, progress=None, avoid=None, grip=None
) -> list[PlacementResult]:
    """``copies`` layouts on one prop (an airframe, a tool a lab owns several of) that a tracker
    tells apart: optimized one after the other on one visibility table, each avoiding the
    triangles of every layout before it and of ``avoid`` (sorted sides, m) by
    ``track.avoid_tolerance_mm``, as well as its own (:mod:`starforge.props.distinct`).  The
    first equals :func:`place` with the same seed; each later one continues its random stream,
    so the set is deterministic.  Every copy is scored on the same scenarios (the hand, camera
    loss) and checked on the same fresh poses.  Tracked objective only."""
    require(isinstance(copies, int) and copies >= 1, f"copies must be an integer >= 1, got {copies}")
    require(
        spec.objective == "tracked",
        f"copies need the tracked objective (the default spec); the spec's objective is {spec.objective!r}",
    )
    rng, timings, progress, warnings, prep = _prepared(prop, spec, seed, progress, grip)
    faces = np.zeros((0, 3)) if avoid is None else np.asarray(avoid, float).reshape(-1, 3)
    out = []
    for _ in range(copies):
        res = _place_tracked(prop, spec, seed, rng, prep, dict(timings), warnings, faces, progress)
        out.append(res)
        faces = np.concatenate([faces, body_triangles(res.centres())])
    return out


def _place_paper(prop, spec, seed, rng, prep, timings, warnings, progress) -> PlacementResult:
    """The paper's objective (eq. 1-5) and RJMCMC (eq. 6-9) on the prepared table."""
    table, sites = prep.table, prep.sites
    v = table.site_visibility
    t = time.perf_counter()
    run_cb = lambda d, n: progress("optimise", d, n)  # noqa: E731
    run_cb(0, spec.chain.restarts)
    pose_seen = table.seen.any(axis=2)  # (s, p): some pair sees the site at the pose
    result = anneal(sites.points, v, spec.costs, spec.chain, rng, on_run=run_cb, site_pose_seen=pose_seen)
    t = _tick(timings, "optimize_s", t)
    chosen = tuple(int(s) for s in result.best.sites)
    seen_any = pose_seen[list(chosen)]
    cost = evaluate(sites.points[list(chosen)], v[list(chosen)], spec.costs, marker_pose_seen=seen_any)
    _tick(timings, "score_s", t)
    return PlacementResult(
        prop, spec, seed, prep.rig, prep.poses, sites, prep.removed["constrained"], v, chosen, cost, result,
        seen_any, timings, table.rays, warnings=tuple(warnings), seat=prep.seat, seat_report=prep.seat_report,
        capsules=prep.capsules, removed=prep.removed, marker_masks=table.masks[list(chosen)], grips=prep.grips,
        part=prep.part,
    )  # fmt: skip


#: the held-out sample's generator is seeded with seed + this (the evaluation's differs again)
VALIDATION_SEED_OFFSET = 2_000_029
#: the camera losses of the searched scenarios come from seed + this (so that ``place score``
#: meets the same scenarios as the placement it re-scores)
LOSS_SEED_OFFSET = 3_000_017


#: the tuning sample that the held-out polish searches (never the ranking's or the evaluation's)
TUNING_SEED_OFFSET = 4_000_037


class _HeldOut:
    """A held-out sample: ``track.validation_poses`` fresh random poses (generator ``seed +
    offset``), each met ``track.loss_patterns`` times with its own random camera losses, drawn
    as :func:`starforge.props.tracked.loss_scenarios` draws them; tables are built on demand
    for the sites (and poses) asked.  A site's row of camera masks depends on that site alone,
    so the rows over every pose are kept (with and without the hand) and a later call computes
    only the sites it has not met: the ranking scores the polished layouts on the rows of the
    candidates they share sites with, and the tuning polish reuses its start's rows."""

    def __init__(self, prop, spec, seed: int, prep, offset: int):
        from starforge.props.evaluate import random_poses
        from starforge.props.grips import GRIP_SEED_OFFSET, assign_grips
        from starforge.props.tracked import alive_masks

        ts, rig = spec.track, prep.rig
        rng = np.random.default_rng(seed + offset)
        self.poses = random_poses(rig.volume, ts.validation_poses, prep.poses.pivot, rng)
        self.patterns = ts.loss_patterns if int(round(ts.cameras_lost * len(rig.cameras))) > 0 else 1
        self.alive = alive_masks(len(rig.cameras), ts.cameras_lost, len(self.poses) * self.patterns, rng)
        self.grip = assign_grips(len(self.poses), len(prep.grips), np.random.default_rng(seed + offset + GRIP_SEED_OFFSET))
        self.prop, self.spec, self.prep = prop, spec, prep
        self._rows: dict = {}  # (site, hand) -> (poses,) uint64 masks over every pose

    def _table(self, sites, k, hand: bool) -> np.ndarray:
        from starforge.props.grips import grip_arrays
        from starforge.props.rig import Poses
        from starforge.props.visibility import compute_table

        prep, spec = self.prep, self.spec
        sub = Poses(self.poses.rotations[k], self.poses.translations[k], self.poses.pivot)
        occ, starts = grip_arrays(prep.grips if hand else ())
        return compute_table(
            self.prop.mesh, prep.sites.points[sites], prep.sites.normals[sites], prep.rig, sub,
            spec.grazing_limit_deg, radius_m=prep.seat.ball_radius_m, centre_m=prep.seat.centre_height_m,
            occlusion=spec.occlusion, occluders=occ, occluder_starts=starts,
            pose_grip=self.grip[k] if hand and prep.grips else None,
        ).masks  # fmt: skip

    def seen(self, sites, poses=None, hand: bool = True):
        """(seen (len(sites), scenarios) bool, masks (len(sites), poses) uint64): the scenarios
        of ``poses`` (indices, default all), without the hand when ``hand`` is false."""
        sites = [int(x) for x in sites]
        every = np.arange(len(self.poses))
        k = every if poses is None else np.asarray(poses, dtype=np.int64)
        masks = np.zeros((len(sites), len(k)), dtype=np.uint64)
        kept = [i for i, s in enumerate(sites) if (s, hand) in self._rows]
        for i in kept:
            masks[i] = self._rows[(sites[i], hand)][k]
        new = [i for i, s in enumerate(sites) if (s, hand) not in self._rows]
        if new:
            idx = [sites[i] for i in new]
            if poses is None:  # rows over every pose: kept for later calls
                rows = self._table(idx, every, hand)
                for s, row in zip(idx, rows, strict=True):
                    self._rows[(s, hand)] = row
            else:
                rows = self._table(idx, k, hand)
            masks[new] = rows
        L = self.patterns
        scen = (k[:, None] * L + np.arange(L)[None]).ravel()  # scenario j of pose k: k * L + j
        seen = np.bitwise_count(masks[:, np.repeat(np.arange(len(k)), L)] & self.alive[scen][None]) >= 2
        return seen, masks


def _validator(sample: _HeldOut, spec, centres, prob):
    """``validate(layouts) -> [{"untracked", "cost"}]``: each layout's untracked fraction and cost
    on the ranking sample (``sample``, :data:`VALIDATION_SEED_OFFSET`)."""
    from starforge.props.tracked import Problem

    def validate(layouts):
        union = sorted({int(x) for lay in layouts for x in lay})
        seen, _ = sample.seen(union)
        held = Problem(
            centres[union], seen, seen.mean(axis=1), spec.track, prob.spacing, prob.spread_target, prob.avoid_faces,
            None if prob.margin is None else prob.margin[union], prob.margin_target,
        )  # fmt: skip
        at = {s: i for i, s in enumerate(union)}
        out = []
        for lay in layouts:
            t = held.terms([at[int(x)] for x in lay])
            out.append({"untracked": t["untracked"], "cost": t["total"]})
        return out

    return validate


#: at most this many sites take part in the held-out polish (the winner's, every candidate's,
#: then the winner's nearest neighbours)
POLISH_SITES = 120


def _polisher(prop, spec, seed, prep, centres, prob):
    """``polish(sites) -> sites``: :func:`starforge.props.tracked.held_out_polish` on the hard
    poses of a tuning sample of its own (:data:`TUNING_SEED_OFFSET`: neither the ranking sample
    nor the evaluation), the poses in which ``sites`` leave fewer than ``spare_markers`` seen in
    some scenario; the sites near the winner's and the other candidates' take part."""
    from starforge.props.tracked import Problem, held_out_polish

    ts = spec.track
    sample = _HeldOut(prop, spec, seed, prep, TUNING_SEED_OFFSET)  # one for every polish: rows shared

    def polish(sites, others=()):
        sites = [int(x) for x in sites]
        seen, _ = sample.seen(sites)
        L = sample.patterns
        few = (seen.sum(axis=0) < max(3, ts.spare_markers)).reshape(-1, L).any(axis=1)
        hard = np.flatnonzero(few)
        if not len(hard):
            return tuple(sites)
        pool = list(dict.fromkeys(sites + sorted({int(x) for o in others for x in o})))
        near = range(len(prob.points)) if len(prob.points) <= POLISH_SITES else prob.knn[sites].T.ravel().tolist()
        for i in near:  # nearest neighbours of every marker first, then the next nearest
            if len(pool) >= POLISH_SITES:
                break
            if int(i) not in pool:
                pool.append(int(i))
        hseen, _ = sample.seen(pool, hard)
        tuning = Problem(centres[pool], hseen, hseen.mean(axis=1), ts, prob.spacing, prob.spread_target, prob.avoid_faces)
        found = held_out_polish(tuning, prob, list(range(len(sites))), np.asarray(pool))
        return tuple(pool[i] for i in found)

    return polish


def _shortfall(sample: _HeldOut, spec, prep, prob, chosen, removed, fit) -> dict:
    """Why the chosen layout is tracked in fewer held-out scenarios than ``track.target_tracked``:
    the same scenarios re-scored with every camera and without the hand, the untracked ones split
    into too few markers seen and markers in a line, and the sites the layout had to work with."""
    from starforge.props.tracked import Problem

    ts, idx = spec.track, list(chosen)
    seen, masks = sample.seen(idx)  # the ranking sample
    held = Problem(prob.points[idx], seen, seen.mean(axis=1), ts, prob.spacing, prob.spread_target)
    everything = np.repeat(np.bitwise_count(masks) >= 2, seen.shape[1] // masks.shape[1], axis=1)
    seen_nh, _ = sample.seen(idx, hand=False) if prep.capsules else (seen, None)
    marks = list(range(len(idx)))
    tracked = 1.0 - held.terms(marks)["untracked"]
    few = float(((seen.sum(axis=0) < 3)).mean())
    out = {
        "target": ts.target_tracked,
        "validation_tracked": tracked,
        "scenarios": int(seen.shape[1]),
        "untracked_too_few_seen": few,
        "untracked_in_a_line": max(0.0, 1.0 - tracked - few),
        "tracked_with_every_camera": 1.0 - Problem(prob.points[idx], everything, everything.mean(axis=1), ts, prob.spacing, prob.spread_target).terms(marks)["untracked"],
        "tracked_without_the_hand": 1.0 - Problem(prob.points[idx], seen_nh, seen_nh.mean(axis=1), ts, prob.spacing, prob.spread_target).terms(marks)["untracked"],
        "markers": len(idx),
        "markers_asked": spec.track.target_markers,
        "markers_that_fit_at_the_spacing": fit,
        "usable_sites": len(prep.sites),
        "sites_under_the_hand": removed["under_hand"],
    }
    from starforge.props.ceiling import tracked_ceiling

    every = np.arange(len(prob.points))
    out["ceiling"] = tracked_ceiling(
        prob.points, lambda: sample.seen(every)[0], prob.spacing, held.min_spread2, ts.target_markers
    )
    return out


def shortfall_warning(sf: dict, spacing_m: float, hand: bool) -> str:
    """One line: how far below the target the layout is on the held-out scenarios, the cause the
    numbers point to, and what to change."""
    cause = []
    if sf["markers_that_fit_at_the_spacing"] < sf["markers_asked"]:
        cause.append(
            f"only {sf['markers_that_fit_at_the_spacing']} markers fit {spacing_m * 1000:.1f} mm apart on its "
            f"{sf['usable_sites']} usable sites" + (f" ({sf['sites_under_the_hand']} sites under the hand)" if hand else "")
        )
    share = sf["untracked_too_few_seen"] / max(1e-12, 1.0 - sf["validation_tracked"])
    cause.append(f"{100 * share:.0f} % of the untracked scenarios see fewer than 3 markers, the rest see them in a line")
    c = sf.get("ceiling")
    if c is not None:
        cause.append(
            f"no layout of markers {spacing_m * 1000:.1f} mm apart on these sites does better than "
            f"{100 * c['ceiling']:.2f} % of these scenarios (all {c['layouts']:,} such layouts scored)"
        )
    helps = [f"with every camera {100 * sf['tracked_with_every_camera']:.1f} %"]
    if hand:
        helps.append(f"without the hand {100 * sf['tracked_without_the_hand']:.1f} %")
    advice = "a smaller --marker or --base-mm (more markers fit, more sites seat)"
    if hand:
        advice += ", another --grip or --no-hand"
    return (
        f"the layout is tracked in {100 * sf['validation_tracked']:.1f} % of {sf['scenarios']} held-out scenarios, "
        f"below the {100 * sf['target']:g} % target ({', '.join(helps)}): {'; '.join(cause)}; try {advice}"
    )


def _place_tracked(prop, spec, seed, rng, prep, timings, warnings, avoid, progress, on_layout=None) -> PlacementResult:
    """The tracked objective (:mod:`starforge.props.tracked`) over camera-loss scenarios, then
    the chosen layout and both baselines checked on fresh poses (:mod:`starforge.props.evaluate`)."""
    from starforge.props.evaluate import evaluate_layouts
    from starforge.props.optimizer import ChainResult
    from starforge.props.tracked import (
        Problem,
        loss_scenarios,
        optimize,
        spaced_capacity,
        spacing_m,
    )

    t = time.perf_counter()
    ts, table, sites, rig = spec.track, prep.table, prep.sites, prep.rig
    centres = sites.points + prep.seat.centre_height_m * sites.normals
    seen, _ = loss_scenarios(table.masks, len(rig.cameras), ts.cameras_lost, ts.loss_patterns, np.random.default_rng(seed + LOSS_SEED_OFFSET))
    ext = np.sort(np.asarray(prop.mesh.extents))
    spacing = spacing_m(ts.marker_mm, rig, ts.gap_px)
    warnings = list(warnings)
    fit = spaced_capacity(centres, spacing, ts.target_markers)
    if fit < ts.target_markers:  # a small prop: markers closer than the spacing merge in the images
        n = max(ts.min_markers, fit)
        warnings.append(
            f"only {fit} markers fit {spacing * 1000:.1f} mm apart on the usable sites: {n} markers placed, "
            f"not {ts.target_markers}" + (" (some closer than the spacing)" if n > fit else "")
        )
        ts = replace(ts, target_markers=n)
    prob = Problem(
        centres,
        seen,
        seen.mean(axis=1),
        ts,
        spacing,
        max(ts.spread_fraction * float(ext[1]), 1e-4),
        None if avoid is None or not len(avoid) else np.asarray(avoid, float),
        margin=prep.seat_report.margin_m,
        margin_target=spec.seat.margin_cap_mm / 1000.0,
    )
    run_cb = lambda d, n: progress("optimise", d, n)  # noqa: E731
    run_cb(0, ts.restarts)
    validate = polish = ranking = None
    if ts.validation_poses:
        ranking = _HeldOut(prop, spec, seed, prep, VALIDATION_SEED_OFFSET)
        validate = _validator(ranking, spec, centres, prob)
        polish = _polisher(prop, spec, seed, prep, centres, prob)
    opt = optimize(prob, rng, run_cb, validate, polish)
    t = _tick(timings, "optimize_s", t)
    chosen, terms = opt.sites, opt.terms
    shortfall = {}
    won = opt.baselines["selection"]["candidates"][opt.baselines["selection"]["winner"]]
    if won["validation_tracked"] is not None and won["validation_tracked"] < ts.target_tracked:
        shortfall = _shortfall(ranking, spec, prep, prob, chosen, prep.removed, fit)
        warnings.append(shortfall_warning(shortfall, prob.spacing, bool(prep.capsules)))
        t = _tick(timings, "shortfall_s", t)
    runs = tuple(
        ChainResult(c.sites, c.cost, c.iterations, c.history, c.history, np.full(len(c.history), len(c.sites), np.int16), {}, {"all": c.accepted})
        for c in opt.runs
    ) or (
        ChainResult(chosen, terms["total"], 0, np.array([terms["total"]]), np.array([terms["total"]]), np.array([len(chosen)], np.int16)),
    )  # fmt: skip
    ann = AnnealResult(min(runs, key=lambda c: c.cost), runs)
    cost = CostBreakdown(
        total=terms["total"],
        visibility=1.0 - terms["mean_visibility"],
        count=0.0,
        overlap=float(terms["close_pairs"]),
        symmetry=0.0,
        near_symmetry=0.0,
        mean_visibility=terms["mean_visibility"],
        overlapping_pairs=terms["close_pairs"],
        symmetric=terms["near_symmetry_margin_m"] == 0.0,
        margin_m=terms["near_symmetry_margin_m"],
        markers=terms["markers"],
        coverage=terms["untracked"],
    )
    res = PlacementResult(
        prop, spec, seed, rig, prep.poses, sites, prep.removed["constrained"], prob.visibility, chosen, cost, ann,
        seen[list(chosen)], timings, table.rays, opt, (), prob.spacing, seat=prep.seat,
        seat_report=prep.seat_report, capsules=prep.capsules, removed=prep.removed,
        marker_masks=table.masks[list(chosen)], shortfall=shortfall, grips=prep.grips, part=prep.part,
    )  # fmt: skip
    if on_layout is not None:
        on_layout(res)
    progress("evaluate", 0, None)  # the layouts on fresh poses
    layouts = {"default": chosen, "greedy_local_search": opt.baselines["greedy_local_search"]["sites"]}
    if opt.baselines["best_of_random"]["sites"] is not None:
        layouts["best_of_random"] = opt.baselines["best_of_random"]["sites"]
    ev = evaluate_layouts(
        prop.mesh,
        {k: (centres[list(v)], sites.normals[list(v)]) for k, v in layouts.items()},
        rig,
        prep.poses.pivot,
        spec.evaluation,
        seed,
        ts.min_height_mm,
        prep.grips,
        spec.grazing_limit_deg,
    )
    t = _tick(timings, "evaluate_s", t)
    lost = int(round(ts.cameras_lost * len(rig.cameras)))
    if terms["untracked"] > 0:
        warnings.append(
            f"{100 * terms['untracked']:.1f} % of the scenarios ({round(terms['untracked'] * seen.shape[1])} of "
            f"{seen.shape[1]}: {len(prep.poses)} poses, {lost} of {len(rig.cameras)} cameras lost at random) "
            "are not tracked (fewer than 3 markers seen, or in a line)"
        )
    if terms["close_pairs"]:
        warnings.append(f"{terms['close_pairs']} marker pair(s) closer than the spacing {prob.spacing * 1000:.1f} mm")
    if terms["avoid_conflicts"]:
        warnings.append(
            f"{terms['avoid_conflicts']} marker triangle(s) within {ts.avoid_tolerance_mm:g} mm of another prop's"
        )
    if terms.get("own_conflicts"):
        warnings.append(
            f"{terms['own_conflicts']} of the layout's own triangles lie within {ts.avoid_tolerance_mm:g} mm of another "
            f"of them or of themselves relabelled (self-margin {terms['self_margin_m'] * 1000:.2f} mm): a tracker that "
            "sees only those three markers may report a wrong pose; try more --sites or fewer --markers"
        )
    ahead = [
        f"{k.replace('_', ' ')} ({v['poses_only_it_tracks']} poses only it tracks, {v['poses_only_default_tracks']} "
        f"only the chosen one; paired exact test p = {v['paired_p_value']:.2g}"
        + ("" if v["paired_p_value"] < 0.05 else ": within the evaluation's noise") + ")"
        for k, v in ev.items()
        if not k.startswith("_") and k != "default" and ev.get("default") and v["tracked"] > ev["default"]["tracked"]
    ]
    if ahead:
        warnings.append(
            f"on the {ev['_poses']} fresh evaluation poses a baseline layout tracked more poses than the chosen one: "
            + "; ".join(ahead)
        )
    return replace(res, warnings=tuple(warnings), evaluation=ev)


#: a scored marker may lie this far from the prop's surface (m), or 1 % of the prop's size if more
OFF_SURFACE_M = 0.002


def score_layout(prop, points: np.ndarray, normals: np.ndarray | None, spec: PlaceSpec, seed: int = 0, grip=None):
    """Score a given layout (the paper's expert comparison): ``(CostBreakdown, per-marker
    visibility, extra)`` where ``extra`` holds the tracked objective's terms for that objective.

    Markers are surface points (as markers.csv writes them); one farther from the surface than
    :data:`OFF_SURFACE_M` (or 1 % of the prop's size) is refused.  Normals missing or zero are
    taken from the nearest surface point.
    """
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.visibility import compute_table

    pts = np.asarray(points, dtype=float)
    require(len(pts) >= 1, "the layout has no markers")
    closest, dist, tri = prop.mesh.nearest.on_surface(pts)
    limit = max(OFF_SURFACE_M, 0.01 * float(np.linalg.norm(prop.mesh.extents)))
    far = np.flatnonzero(dist > limit)
    if len(far):
        k = int(far[np.argmax(dist[far])])
        raise StarforgeError(
            f"marker {k} lies {dist[k] * 1000:.1f} mm from the prop's surface (at most {limit * 1000:.1f} mm): "
            f"{len(far)} of {len(pts)} markers are off the prop (wrong --units, or another prop's file?)"
        )
    nrm = np.zeros_like(pts) if normals is None else np.asarray(normals, dtype=float)
    length = np.linalg.norm(nrm, axis=1)
    missing = length < 1e-12
    if missing.any():
        nrm[missing] = prop.mesh.face_normals[tri[missing]]
        length = np.linalg.norm(nrm, axis=1)
    nrm = nrm / length[:, None]
    rng = np.random.default_rng(seed)
    rig = load_rig(spec.rig)
    pivot = np.asarray(prop.mesh.bounds, dtype=float).mean(axis=0)
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    check_cost(prop, spec, rig, len(pts), len(poses))
    from starforge.props.grips import GRIP_SEED_OFFSET, assign_grips, grip_arrays
    from starforge.props.seat import seat_report

    seat = spec.marker_seat()
    _, grips = hand_grips(prop, spec, grip)
    occ, starts = grip_arrays(grips)
    pose_grip = assign_grips(len(poses), len(grips), np.random.default_rng(seed + GRIP_SEED_OFFSET))
    table = compute_table(
        prop.mesh,
        pts,
        nrm,
        rig,
        poses,
        spec.grazing_limit_deg,
        radius_m=seat.ball_radius_m,
        centre_m=seat.centre_height_m,
        occlusion=spec.occlusion,
        occluders=occ,
        occluder_starts=starts,
        pose_grip=pose_grip if grips else None,
    )
    v = table.site_visibility
    rep = seat_report(prop.mesh, pts, nrm, seat, spec.seat)
    seated = {
        "contact": [round(float(x), 4) for x in rep.contact],
        "edge_mm": [None if not math.isfinite(x) else round(float(x) * 1000, 2) for x in rep.edge_m],
        "seat_margin_mm": [round(float(x) * 1000, 3) for x in rep.margin_m],
        "seated": [bool(x) for x in rep.ok],
    }
    if spec.objective == "tracked":
        from starforge.props.evaluate import evaluate_layouts
        from starforge.props.tracked import Problem, loss_scenarios, spacing_m

        ts = spec.track
        centres = pts + seat.centre_height_m * nrm
        seen, _ = loss_scenarios(table.masks, len(rig.cameras), ts.cameras_lost, ts.loss_patterns, np.random.default_rng(seed + LOSS_SEED_OFFSET))
        v = seen.mean(axis=1)
        prob = Problem(
            centres,
            seen,
            v,
            ts,
            spacing_m(ts.marker_mm, rig, ts.gap_px),
            max(ts.spread_fraction * float(np.sort(prop.mesh.extents)[1]), 1e-4),
            margin=rep.margin_m,
            margin_target=spec.seat.margin_cap_mm / 1000.0,
        )
        t = prob.terms(list(range(len(pts))))
        cost = CostBreakdown(
            t["total"],
            1 - t["mean_visibility"],
            0.0,
            float(t["close_pairs"]),
            0.0,
            0.0,
            t["mean_visibility"],
            t["close_pairs"],
            False,
            t["near_symmetry_margin_m"],
            len(pts),
            t["untracked"],
        )
        ev = evaluate_layouts(
            prop.mesh, {"layout": (centres, nrm)}, rig, pivot, spec.evaluation, seed, ts.min_height_mm, grips,
            spec.grazing_limit_deg,
        )  # fmt: skip
        from starforge.props.distinct import subset_margin

        m3, m4 = (subset_margin(centres * 1000.0, k) for k in (3, 4))
        extra = {
            "objective": "tracked",
            "tracked_fraction": 1 - t["untracked"],
            "self_margin_mm": None if math.isinf(m3) else m3,  # from any 3 markers (flip-proof above the window)
            "self_margin_4_mm": None if math.isinf(m4) else m4,
            "spacing_m": prob.spacing,
            "evaluation": ev["layout"],
            **seated,
        }
        return cost, v, extra
    extra = {"objective": "paper", **seated}
    return evaluate(pts, v, spec.costs, marker_pose_seen=table.seen.any(axis=2)), v, extra


