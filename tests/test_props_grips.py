"""Grips from the prop's shape: the held part, the distribution, the per-pose hand in the table."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from starforge.errors import StarforgeError
from starforge.props.grips import (
    WRAPS,
    assign_grips,
    grip_arrays,
    grip_distribution,
    held_part,
    pinned_grip,
    principal_axes,
    under_hand,
)
from starforge.props.hand import inside_capsules


def _torch(tilt_deg: float = 0.0):
    """A 200 mm body 35 mm across under a 70 mm box head, optionally turned off the axes."""
    body = trimesh.creation.cylinder(radius=0.0175, height=0.2, sections=48)
    body.apply_translation([0, 0, 0.1])
    head = trimesh.creation.box(extents=(0.07, 0.07, 0.05))
    head.apply_translation([0, 0, 0.225])
    mesh = trimesh.util.concatenate([body, head])
    if tilt_deg:
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(tilt_deg), [1, 1, 0]))
    return mesh


def test_principal_axes_are_orthonormal_and_longest_first():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(500, 3)) * [0.1, 0.03, 0.01]
    c, ax = principal_axes(v)
    assert np.allclose(ax @ ax.T, np.eye(3), atol=1e-9)
    spread = ((v - c) @ ax.T).var(axis=0)
    assert spread[0] >= spread[1] >= spread[2]


@pytest.mark.parametrize("tilt", [0.0, 37.0])
def test_the_torch_is_held_by_its_body_whatever_its_orientation(tilt):
    mesh = _torch(tilt)
    part = held_part(mesh)
    assert part.found
    assert part.radius_m == pytest.approx(0.0175, abs=1.5e-3)
    # the run covers most of the body and none of the head: its ends' distance from the axis
    # of the body through the origin, recomputed in the torch's own frame
    R = trimesh.transformations.rotation_matrix(np.radians(tilt), [1, 1, 0])[:3, :3]
    ends = np.array([part.a, part.b]) @ R  # back to the upright torch
    assert np.allclose(ends[:, :2], 0.0, atol=2e-3)
    assert ends[:, 2].min() < 0.01 and 0.18 < ends[:, 2].max() <= 0.2 + 0.004


def test_the_distribution_spans_hands_positions_and_wraps():
    part, grips = grip_distribution(_torch())
    assert len(grips) == 3 * 2 * len(WRAPS)
    assert {g.hand for g in grips} == {"left", "right"}
    assert sorted({round(g.along, 3) for g in grips}) == pytest.approx([0.225, 0.5, 0.775], abs=0.01)
    # the fists of the grips cover the whole body and never the top of the head
    z = np.linspace(0.005, 0.195, 39)
    body = np.column_stack([np.full_like(z, 0.0175), np.zeros_like(z), z])
    assert under_hand(body, body, grips).all()
    top = np.array([[0.0, 0.0, 0.25], [0.02, 0.02, 0.25]])
    assert not under_hand(top, top, grips).any()
    # a left hand's wrist is the mirror image of the right's across the plane of the wrap
    right, left = grips[0].capsules[1], grips[len(WRAPS)].capsules[1]
    assert right.a == pytest.approx(left.a)
    assert np.linalg.norm(np.subtract(right.b, left.b)) > 0.05


def test_the_table_holds_each_pose_in_its_own_grip():
    """The compiled table with a grip per pose equals, pose by pose, tables built with that
    grip's capsules alone (brute force over the grips)."""
    from starforge.props.evaluate import random_poses
    from starforge.props.hand import capsule_arrays
    from starforge.props.rig import load_rig
    from starforge.props.sites import sample_sites
    from starforge.props.visibility import compute_table

    mesh = _torch()
    _, grips = grip_distribution(mesh)
    rig = load_rig("default")
    rng = np.random.default_rng(5)
    sites = sample_sites(mesh, 60, rng)
    poses = random_poses(rig.volume, 36, mesh.bounds.mean(axis=0), rng)
    pose_grip = assign_grips(len(poses), len(grips), np.random.default_rng(1))
    assert np.bincount(pose_grip).tolist() == [2] * len(grips)
    occ, starts = grip_arrays(grips)
    table = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, radius_m=0.005,
                          occluders=occ, occluder_starts=starts, pose_grip=pose_grip).masks  # fmt: skip
    for g, grip in enumerate(grips):
        alone = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, radius_m=0.005,
                              occluders=capsule_arrays(grip.capsules)).masks  # fmt: skip
        k = pose_grip == g
        assert (table[:, k] == alone[:, k]).all()
    bare = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, radius_m=0.005).masks
    assert (np.bitwise_count(table) <= np.bitwise_count(bare)).all() and (table != bare).any()
    with pytest.raises(StarforgeError, match="pose_grip"):
        compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, occluders=occ, occluder_starts=starts,
                      pose_grip=np.full(len(poses), len(grips)))  # fmt: skip


def test_grips_are_assigned_evenly_and_reproducibly():
    a = assign_grips(100, 7, np.random.default_rng(4))
    assert (a == assign_grips(100, 7, np.random.default_rng(4))).all()
    assert np.ptp(np.bincount(a, minlength=7)) <= 1
    assert not (a == np.arange(100) % 7).all()  # shuffled
    assert (assign_grips(10, 0, np.random.default_rng(0)) == 0).all()


def test_a_pinned_grip_by_number_or_by_segment():
    _, grips = grip_distribution(_torch())
    assert pinned_grip("4", grips) is grips[3]
    seg = pinned_grip("0,0,0.02,0,0,0.11,0.015", grips)
    assert inside_capsules(np.array([[0.0175, 0, 0.06]]), seg.capsules).all()
    with pytest.raises(StarforgeError, match="numbered 1 to 18"):
        pinned_grip("19", grips)
    with pytest.raises(StarforgeError, match="--grip"):
        pinned_grip("0,1", grips)


def test_the_seat_margin_is_rewarded_by_the_tracked_cost():
    """The margin term: the mean shortfall of the markers' margins below the target, weighted into
    the total (recomputed by hand), and in the screened additions too."""
    from starforge.props.tracked import Problem, TrackSettings

    rng = np.random.default_rng(8)
    pts = rng.random((30, 3)) * 0.2
    seen = rng.random((30, 50)) < 0.7
    margin = rng.random(30) * 0.006
    ts = TrackSettings(w_margin=0.7, w_near_symmetry=0.0)
    with_m = Problem(pts, seen, seen.mean(axis=1), ts, 0.02, 0.02, margin=margin, margin_target=0.005)
    without = Problem(pts, seen, seen.mean(axis=1), ts, 0.02, 0.02)
    lay = [0, 3, 7, 11, 19, 25]
    short = np.maximum(0.0, 1.0 - margin[lay] / 0.005).mean()
    t = with_m.terms(lay)
    assert t["margin_shortfall"] == pytest.approx(short)
    assert t["total"] == pytest.approx(without.terms(lay)["total"] + 0.7 * short)
    free = np.array([1, 2, 4])
    diff = with_m.screen_additions(lay, free) - without.screen_additions(lay, free)
    want = [0.7 * np.maximum(0.0, 1.0 - margin[[*lay, c]] / 0.005).mean() for c in free]
    assert diff == pytest.approx(want)


@pytest.mark.slow
def test_a_prop_held_anywhere_keeps_markers_off_where_most_grips_hold_it(tmp_path):
    """A plain 40 mm rod: every fist position together covers it all, so only the sites more than
    half of the grips cover are left out, and the run says so; none of its markers lies there."""
    from starforge.props.placement import run_placement

    rod = trimesh.creation.cylinder(radius=0.02, height=0.25, sections=48)
    path = tmp_path / "rod.stl"
    rod.export(path)
    res = run_placement(str(path), sites=200, resolution=1, orientations=6)
    assert any("held almost anywhere" in w for w in res.warnings)
    pts, centres = res.marker_points, res.centres()
    assert not under_hand(pts, centres, res.grips, share=0.5).any()
    assert under_hand(pts, centres, res.grips).any()  # some under a fist of some grip
