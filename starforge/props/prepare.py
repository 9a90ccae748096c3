"""What every placement starts from: the sites that seat a marker (constrained areas and the hand
removed), the rig, the poses and the visibility table; and the refusals and warnings that come
before that work (a prop in other units, sites no layout can track, a table past the limits)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.builtin import BUILTIN
from starforge.props.grips import (
    GRIP_SEED_OFFSET,
    HELD_SHARE,
    Grip,
    HeldPart,
    assign_grips,
    grip_arrays,
    grip_distribution,
    pinned_grip,
    under_hand,
)
from starforge.props.hand import GRIPS, Capsule
from starforge.props.mesh import units_hint
from starforge.props.result import tick
from starforge.props.rig import Poses, Rig, load_rig, make_poses
from starforge.props.seat import Seat, SeatReport, seat_report
from starforge.props.sites import Sites, forbidden_sites, sample_sites
from starforge.props.spacing import line_reach, spaced_triple, spacing_m
from starforge.props.spec import PlaceSpec
from starforge.props.tracked import TRIANGLE_SPREAD
from starforge.props.visibility import VisibilityTable, compute_table
from starforge.runtime.budget import require_memory, require_time
from starforge.runtime.stored import content_key, stored


@dataclass(frozen=True)
class Prepared:
    """The optimizer's input: seated sites, the rig, the poses and the visibility table."""

    sites: Sites
    removed: dict  # sampled sites removed, by reason
    rig: Rig
    poses: Poses
    table: VisibilityTable
    seat: Seat
    seat_report: SeatReport
    capsules: tuple[Capsule, ...]  # every grip's capsules together (what the pictures outline)
    grips: tuple[Grip, ...] = ()  # the distribution the layout is scored under
    pose_grip: np.ndarray = field(default=None, repr=False)  # (poses,) the grip of each pose
    part: HeldPart | None = None
    notes: tuple[str, ...] = ()  # warnings about the preparation
    key: str = ""  # the content key it is kept under (:func:`prepare`); "" when it is not kept


def hand_grips(prop, spec: PlaceSpec, grip=None) -> tuple:
    """``(held part, grips)``: the grips of :func:`starforge.props.grips.grip_distribution`, or
    only ``grip`` when given (a :class:`~starforge.props.grips.Grip`, a Capsule, or ``--grip``
    text: ``N`` or ``x0,y0,z0,x1,y1,z1[,r]``); ``(None, ())`` when the spec has no hand."""
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
    """Sites that seat the marker (constrained areas and the hand removed), rig, poses, table.

    A pure function of the mesh, the spec, the grip, the seed and the generator's state (which it
    advances): kept in the cache folder (:func:`starforge.runtime.stored.stored`) with the
    generator's state after it, and read back by a later run with the same inputs, unless the
    spec's constrained areas name files (whose content the key does not hold)."""
    timings = {} if timings is None else timings
    t = time.perf_counter()
    rig = load_rig(spec.rig)
    if spec.constraints.mesh or spec.constraints.mask:
        return _prepare(prop, spec, rig, rng, progress, timings, grip, seed)
    key = content_key(
        "prepared", prop.vertices, prop.faces, prop.name, prop.source, spec, spec.marker_seat(), rig,
        grip, seed,
        rng.bit_generator.state, libraries=("numpy", "trimesh", "embreex", "numba"),
    )  # fmt: skip

    def work():
        prep = _prepare(prop, spec, rig, rng, progress, timings, grip, seed)
        return replace(prep, key=key), rng.bit_generator.state

    (prep, state), kept = stored("prepared", key, work)
    if kept:
        check_cost(prop, spec, rig, len(prep.sites), spec.resolution**3 * spec.orientations)
        rng.bit_generator.state = state
        if progress is not None:
            progress(0, None)
            progress(1, 1)
        t = tick(timings, "sample_s", t)
        tick(timings, "visibility_s", t)
    return prep


def _prepare(prop, spec, rig, rng, progress, timings, grip, seed) -> Prepared:
    """:func:`prepare`'s work."""
    t = time.perf_counter()
    notes: list[str] = []
    sites = sample_sites(prop.mesh, spec.sites, rng)
    if spec.constraints.empty:
        bad = np.zeros(len(sites), dtype=bool)
    else:
        bad = forbidden_sites(sites, spec.constraints, prop.face_origin, prop.source_faces)
    seat = spec.marker_seat()
    part, grips = hand_grips(prop, spec, grip)
    caps = tuple(c for g in grips for c in g.capsules)
    centres = sites.points + seat.centre_height_m * sites.normals
    hand = under_hand(sites.points, centres, grips, share=HELD_SHARE if len(grips) > 1 else 0.0) & ~bad
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
    t = tick(timings, "sample_s", t)
    pivot = prop.bounds_m.mean(axis=0)
    check_cost(prop, spec, rig, len(kept), spec.resolution**3 * spec.orientations)  # before building them
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    if progress is not None:
        progress(0, None)  # the rays' stage starts with its work
    pose_grip = assign_grips(len(poses), grips, np.random.default_rng(seed + GRIP_SEED_OFFSET))
    occ, starts = grip_arrays(grips)
    table = compute_table(
        prop,
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
        post_m=seat.standoff_m,
    )
    tick(timings, "visibility_s", t)
    return Prepared(kept, removed, rig, poses, table, seat, report, caps, grips, pose_grip, part, tuple(notes))


def check_trackable(centres: np.ndarray, spec: PlaceSpec, rig, seat, removed: dict) -> None:
    """Refuse, before the visibility table, seated sites on which no layout can ever be tracked:
    no three of them lie the marker spacing apart (closer markers merge in the images), or every
    ball centre lies so near one line that no markers on them span the tracker's triangle
    (:func:`starforge.props.spacing.line_reach`, an upper bound: never a false alarm).  Both are
    proofs about every layout, not a search that failed."""
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
    ext = float(np.max(prop.extents_m))
    vol = float(np.max(rig.volume.size))
    if ext > 2 * vol or ext < 4 * marker_m:

        hint = "; " + units_hint(ext, prop.units, 4 * marker_m, vol)
        size = " x ".join(f"{e:.4g}" for e in prop.extents_m)
        raise StarforgeError(
            f"prop {prop.name} is {size} m read as {prop.units}: "
            + (f"larger than twice the capture volume ({vol:g} m)" if ext > 2 * vol
               else f"smaller than four markers ({4 * marker_m * 1000:g} mm)")
            + hint
        )
    size = np.asarray(rig.volume.size, float)
    vol_text = " x ".join(f"{e:g}" for e in size)
    if np.any(prop.extents_m > size):
        return [
            f"the prop ({' x '.join(f'{e:.3g}' for e in prop.extents_m)} m) does not fit inside the capture volume ({vol_text} m)"
        ]
    pivot = prop.bounds_m.mean(axis=0)
    span = 2.0 * float(np.linalg.norm(prop.vertices - pivot, axis=1).max())
    if span > size.min():
        return [
            f"the prop fits the capture volume ({vol_text} m) upright but not when turned: turned about its "
            f"centre it sweeps {span:.3g} m, more than the volume's smallest side {size.min():g} m"
        ]
    return []


def prop_name_warnings(prop) -> list[str]:
    """Say which prop was used when a built-in name is also a path here."""
    if prop.source == "builtin" and Path(prop.name).exists():
        return [f"a path named {prop.name!r} exists here; the built-in {prop.name} was used (./{prop.name} names the path)"]
    if prop.source != "builtin" and Path(prop.source).name in BUILTIN and Path(prop.source).stem == prop.source.removeprefix("./"):
        name = Path(prop.source).name
        return [f"the file {prop.source!r} was used, not the built-in {name} (builtin:{name} names it)"]
    return []
