"""Scoring a given marker layout on a prop (the paper's expert comparison; ``place score``)."""

from __future__ import annotations

import math

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.costs import CostBreakdown, evaluate
from starforge.props.distinct import subset_margin
from starforge.props.evaluate import evaluate_layouts
from starforge.props.grips import GRIP_SEED_OFFSET, assign_grips, grip_arrays
from starforge.props.prepare import check_cost, hand_grips
from starforge.props.rig import load_rig, make_poses
from starforge.props.scenarios import LOSS_SEED_OFFSET, loss_scenarios
from starforge.props.seat import seat_report
from starforge.props.spacing import spacing_m
from starforge.props.spec import PlaceSpec
from starforge.props.tracked import Problem
from starforge.props.visibility import compute_table
from starforge.spec import require

#: a scored marker may lie this far from the prop's surface (m), or 1 % of the prop's size if more
OFF_SURFACE_M = 0.002


def score_layout(prop, points: np.ndarray, normals: np.ndarray | None, spec: PlaceSpec, seed: int = 0, grip=None):
    """Score a given layout (the paper's expert comparison): ``(CostBreakdown, per-marker
    visibility, extra)`` where ``extra`` holds the tracked objective's terms for that objective.

    Markers are surface points (as markers.csv writes them); one farther from the surface than
    :data:`OFF_SURFACE_M` (or 1 % of the prop's size) is refused.  Normals missing or zero are
    taken from the nearest surface point.
    """
    pts, nrm = _on_surface(prop, points, normals)
    rng = np.random.default_rng(seed)
    rig = load_rig(spec.rig)
    pivot = prop.bounds_m.mean(axis=0)
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    check_cost(prop, spec, rig, len(pts), len(poses))
    seat = spec.marker_seat()
    _, grips = hand_grips(prop, spec, grip)
    occ, starts = grip_arrays(grips)
    pose_grip = assign_grips(len(poses), grips, np.random.default_rng(seed + GRIP_SEED_OFFSET))
    table = compute_table(
        prop,
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
        post_m=seat.standoff_m,
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
        return _score_tracked(prop, spec, seed, pts, nrm, table, rig, grips, rep, seated)
    extra = {"objective": "paper", **seated}
    return evaluate(pts, v, spec.costs, marker_pose_seen=table.seen.any(axis=2)), v, extra


def _on_surface(prop, points, normals) -> tuple[np.ndarray, np.ndarray]:
    """``(points (m, 3) m, unit normals (m, 3))`` of a given layout: a marker off the surface is
    refused, a missing or zero normal is the nearest face's."""
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
    return pts, nrm


def _score_tracked(prop, spec: PlaceSpec, seed: int, pts, nrm, table, rig, grips, rep, seated: dict):
    """The tracked objective's score of the markers ``pts`` (m) on the scenarios ``place`` searched
    with this seed, their self-margins and their check on fresh poses."""
    seat = spec.marker_seat()
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
        max(ts.spread_fraction * float(np.sort(prop.extents_m)[1]), 1e-4),
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
    pivot = prop.bounds_m.mean(axis=0)
    ev = evaluate_layouts(
        prop, {"layout": (centres, nrm)}, rig, pivot, spec.evaluation, seed, ts.min_height_mm, grips,
        spec.grazing_limit_deg,
    )  # fmt: skip
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
