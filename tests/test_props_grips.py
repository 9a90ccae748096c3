"""Grips from the prop's shape: the held part, the distribution, the per-pose hand in the table."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from starforge.errors import StarforgeError
from starforge.props.grips import (
    POSITIONS,
    SLICE_M,
    STEP,
    WRAPS,
    Grip,
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
    places = len({g.along for g in grips})
    assert len(grips) == places * 2 and places % len(WRAPS) == 0
    assert {g.hand for g in grips} == {"left", "right"}
    # both hands at every place; every wrap at as many places, spread along the whole reach
    for hand in ("left", "right"):
        assert sorted(g.along for g in grips if g.hand == hand) == sorted({g.along for g in grips})
    for w in WRAPS:
        at = sorted(g.along for g in grips if g.wrap_deg == w and g.hand == "right")
        assert len(at) == places // len(WRAPS) and at[0] <= min(g.along for g in grips) + 0.1 and at[-1] >= max(g.along for g in grips) - 0.1
    # the reach: the body continued over the 70 mm head (a hand spans it), 250 mm in all
    a, b = part.reach
    assert np.allclose([a[:2], b[:2]], 0.0, atol=2e-3)
    assert min(a[2], b[2]) < 0.005 and max(a[2], b[2]) > 0.245
    # palms from one end of the reach to the other, neighbours at most STEP palms apart
    palm = 0.09
    centres = sorted({round(g.along * 0.25, 4) for g in grips})
    assert centres[0] == pytest.approx(palm / 2, abs=0.005) and centres[-1] == pytest.approx(0.25 - palm / 2, abs=0.005)
    assert np.diff(centres).max() <= STEP * palm + 1e-9 and places <= POSITIONS * len(WRAPS)
    # the fists of the grips cover the whole body and the head: a hand may hold it anywhere
    z = np.linspace(0.005, 0.245, 49)
    side = np.column_stack([np.where(z < 0.2, 0.0175, 0.035), np.zeros_like(z), z])
    assert under_hand(side, side, grips).all()
    # ... but no body point is held by most of them
    assert not under_hand(side[z < 0.2], side[z < 0.2], grips, share=0.5).all()
    # the fist on the head is as thick as the head, those on the body as the body
    fists = {round(g.along, 3): g.capsules[0].radius for g in grips}
    assert fists[max(fists)] >= 0.035 + 0.02 and fists[min(fists)] == pytest.approx(0.0175 + 0.025, abs=2e-3)
    # a left hand's wrist is the mirror image of the right's across the plane of the wrap
    w = len(WRAPS)
    right, left = grips[0].capsules[1], grips[w].capsules[1]
    assert (grips[0].hand, grips[w].hand, grips[0].along, grips[0].wrap_deg) == ("right", "left", grips[w].along, grips[w].wrap_deg)
    assert right.a == pytest.approx(left.a)
    assert np.linalg.norm(np.subtract(right.b, left.b)) > 0.05


def _screwdriver():
    """A 100 mm handle 32 mm across, a 130 mm shaft 7 mm across."""
    handle = trimesh.creation.cylinder(radius=0.016, height=0.1, sections=48)
    handle.apply_translation([0, 0, 0.05])
    shaft = trimesh.creation.cylinder(radius=0.0035, height=0.13, sections=24)
    shaft.apply_translation([0, 0, 0.1 + 0.065])
    return trimesh.util.concatenate([handle, shaft])


def test_the_reach_runs_past_the_handle_over_what_a_hand_spans():
    """A screwdriver's handle is the held part; the reach goes on over the thin shaft to its tip.
    A handle under a plate wider than a hand stops at the plate."""
    part = held_part(_screwdriver())
    assert part.found and part.radius_m == pytest.approx(0.016, abs=1.5e-3)
    assert min(part.a[2], part.b[2]) < 0.005 and 0.095 < max(part.a[2], part.b[2]) < 0.105
    a, b = part.reach
    assert min(a[2], b[2]) < 0.005 and max(a[2], b[2]) > 0.225
    # the sections' half widths along the reach: the handle's, then the shaft's
    r = np.asarray(part.reach_radii)
    t = np.linspace(min(a[2], b[2]), max(a[2], b[2]), len(r))
    assert np.allclose(r[(t > 0.01) & (t < 0.09)], 0.016, atol=1.5e-3)
    assert np.allclose(r[(t > 0.11) & (t < 0.22)], 0.0035, atol=1e-3)
    handle = trimesh.creation.cylinder(radius=0.016, height=0.12, sections=48)
    handle.apply_translation([0, 0, 0.06])
    plate = trimesh.creation.box(extents=(0.15, 0.15, 0.01))
    plate.apply_translation([0, 0, 0.125])
    capped = held_part(trimesh.util.concatenate([handle, plate]))
    a, b = capped.reach
    assert max(a[2], b[2]) <= 0.12 + 0.005


def _drill():
    """A 100 mm handle 40 mm across under a 210 x 50 x 60 mm body, on a 80 x 70 x 40 mm battery."""
    handle = trimesh.creation.cylinder(radius=0.02, height=0.12, sections=48)
    handle.apply_translation([0, 0, 0.1])
    body = trimesh.creation.box(extents=(0.21, 0.05, 0.06))
    body.apply_translation([0.045, 0, 0.17])
    battery = trimesh.creation.box(extents=(0.08, 0.07, 0.04))
    battery.apply_translation([0, 0, 0.02])
    return trimesh.util.concatenate([handle, body, battery])


def test_a_body_beside_the_handle_gets_grips_of_its_own():
    """The drill's handle is the held part; the stretch of its body clear of the handle (cut
    across x, every section the 50 x 60 mm box) is another, with fists as thick as the body; the
    torch, as thick as a hand across, has none."""
    part, grips = grip_distribution(_drill())
    assert part.found and part.radius_m == pytest.approx(0.02, abs=1.5e-3)
    assert len(part.others) == 1
    (body,) = part.others
    ends = np.array([body.a, body.b])
    # along x through the body's middle (a principal axis, a few degrees off x)
    assert np.allclose(ends[:, 1:], [0.0, 0.17], atol=6e-3)
    # the battery under the handle (x within 40 mm) makes the sections 200 mm tall: the stretch
    # starts past it and runs to the body's front
    assert ends[:, 0].min() >= 0.04 - 5e-3 and ends[:, 0].max() == pytest.approx(0.15, abs=5e-3)
    half_diag = np.hypot(0.025, 0.03)
    assert 0.03 - 1e-3 <= body.radius_m <= half_diag + 1e-3
    on_body = [g for g in grips if "stretch 2" in g.label]
    assert on_body and len(on_body) < len(grips)
    pts = np.array([[0.09, 0.025, 0.17], [0.09, 0.0, 0.2]])  # on the body's side and top
    assert under_hand(pts, pts, on_body).all()
    assert held_part(_torch()).others == ()


def test_a_grip_on_the_shaft_closes_round_the_shaft():
    """Each fist is the widest section under its palm plus the fingers (recomputed from the
    mesh's own dimensions), and the fists together cover handle and shaft."""
    from starforge.props.hand import FINGERS_M

    _, grips = grip_distribution(_screwdriver())
    for g in grips:
        fist = g.capsules[0]
        lo = min(fist.a[2], fist.b[2])
        if abs(lo - 0.1) <= SLICE_M:  # the palm ends at the step, within one section of it
            continue
        on_handle = lo < 0.1  # the palm reaches over the handle
        want = (0.016 if on_handle else 0.0035) + FINGERS_M
        assert fist.radius == pytest.approx(want, abs=1.5e-3)
    z = np.linspace(0.003, 0.227, 60)
    shaft = np.column_stack([np.where(z < 0.1, 0.016, 0.0035), np.zeros_like(z), z])
    assert under_hand(shaft, shaft, grips).all()


def held_scene(mesh, sites: int, seed: int):
    """``(grips, rig, sites, poses, pose_grip)``: ``mesh``'s grip distribution, the default rig,
    ``sites`` sites and two random poses per grip, each held in its own grip."""
    from starforge.props.evaluate import random_poses
    from starforge.props.rig import load_rig
    from starforge.props.sites import sample_sites

    _, grips = grip_distribution(mesh)
    rig = load_rig("default")
    rng = np.random.default_rng(seed)
    samples = sample_sites(mesh, sites, rng)
    poses = random_poses(rig.volume, 2 * len(grips), mesh.bounds.mean(axis=0), rng)
    return grips, rig, samples, poses, assign_grips(len(poses), len(grips), np.random.default_rng(1))


@pytest.mark.slow
def test_the_table_holds_each_pose_in_its_own_grip():
    """The compiled table with a grip per pose equals, pose by pose, tables built with that
    grip's capsules alone (brute force over the grips)."""
    from starforge.props.hand import capsule_arrays
    from starforge.props.visibility import compute_table

    mesh = _torch()
    grips, rig, sites, poses, pose_grip = held_scene(mesh, 60, 5)
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
    # fewer poses than twice the grips: which grips hold two is drawn, so over seeds every grip does
    twice = np.array([np.bincount(assign_grips(10, 7, np.random.default_rng(s)), minlength=7) == 2 for s in range(200)])
    assert twice.sum(axis=1).tolist() == [3] * 200 and twice.any(axis=0).all()


def test_weighted_grips_share_the_poses_by_largest_remainder_with_drawn_ties():
    # a heavy grip and four light ones of equal weight: 10 poses leave 2 spare, for 2 of the 4 tied light grips
    w = np.array([3.0, 1.0, 1.0, 1.0, 1.0])
    grips = [Grip(f"g{i}", "", 0.5, 0.0, (), weight=float(x)) for i, x in enumerate(w)]
    exact = 10 * w / w.sum()
    spare = []
    for seed in range(200):
        counts = np.bincount(assign_grips(10, grips, np.random.default_rng(seed)), minlength=len(w))
        assert counts.sum() == 10 and (np.abs(counts - exact) < 1).all()
        frac = exact - np.floor(exact)
        up = counts > np.floor(exact)
        assert frac[up].min(initial=1.0) >= frac[~up].max(initial=0.0)  # largest remainders first
        spare.append(np.flatnonzero(up & (w == 1.0)))
    # the light grips tie: over seeds each of them gets a spare pose, not always the lowest-numbered
    assert len({tuple(s) for s in spare}) > 1 and set(np.concatenate(spare)) == {1, 2, 3, 4}
    # equal weights are the unweighted case, draw for draw
    same = [Grip(f"g{i}", "", 0.5, 0.0, (), weight=0.3) for i in range(7)]
    assert np.array_equal(assign_grips(31, same, np.random.default_rng(5)), assign_grips(31, 7, np.random.default_rng(5)))


def test_a_pinned_grip_by_number_or_by_segment():
    _, grips = grip_distribution(_torch())
    assert pinned_grip("4", grips) is grips[3]
    seg = pinned_grip("0,0,0.02,0,0,0.11,0.015", grips)
    assert inside_capsules(np.array([[0.0175, 0, 0.06]]), seg.capsules).all()
    with pytest.raises(StarforgeError, match=f"numbered 1 to {len(grips)}"):
        pinned_grip(str(len(grips) + 1), grips)
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
    """A plain 40 mm rod: the grips cover it all together, so only the sites more than half of
    the grips' fists cover are left out (recomputed here from the bands, brute force); the
    markers lie where some grips hold it, and there they are lost in those grips' poses."""
    from starforge.props.placement import run_placement

    rod = trimesh.creation.cylinder(radius=0.02, height=0.25, sections=48)
    path = tmp_path / "rod.stl"
    rod.export(path)
    res = run_placement(str(path), sites=200, resolution=1, orientations=6)
    pts, centres = res.marker_points, res.centres()
    covered = np.zeros((len(pts), len(res.grips)), bool)
    for j, g in enumerate(res.grips):
        f = g.capsules[0]
        covered[:, j] = enclosed_by(pts, f.a, f.b, f.radius, f.flat) | enclosed_by(centres, f.a, f.b, f.radius, f.flat)
    assert (covered.mean(axis=1) <= 0.5).all()
    assert covered.any()  # some under a fist of some grip


def enclosed_by(points, a, b, radius, flat) -> np.ndarray:
    """Brute force, for the tests: each point within ``radius`` of the segment ``a``-``b`` (a
    capsule) or, when ``flat``, of its line with the point's foot between ``a`` and ``b`` (a band)."""
    p = np.atleast_2d(np.asarray(points, float))
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    s = (p - a) @ ab / (ab @ ab)
    foot = a + (s if flat else np.clip(s, 0, 1))[:, None] * ab
    near = np.linalg.norm(p - foot, axis=1) <= radius
    return near & (s >= 0) & (s <= 1) if flat else near


def test_a_marker_in_a_fist_is_lost_whenever_that_grip_holds_the_prop():
    """Ball centres inside a grip's fist or forearm (distances to their segments, brute force) are
    seen by no camera at any pose held in that grip, in the optimizer's table and in the
    independent evaluation alike; held in another grip, some of them are seen."""
    from starforge.props.evaluate import camera_hits, random_poses
    from starforge.props.rig import load_rig
    from starforge.props.sites import sample_sites
    from starforge.props.visibility import compute_table

    mesh = _torch()
    _, grips = grip_distribution(mesh)
    rig = load_rig("default")
    rng = np.random.default_rng(11)
    sites = sample_sites(mesh, 150, rng)
    centres = sites.points + 0.005 * sites.normals
    poses = random_poses(rig.volume, 72, mesh.bounds.mean(axis=0), rng)
    pose_grip = assign_grips(len(poses), len(grips), np.random.default_rng(2))
    occ, starts = grip_arrays(grips)
    masks = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, radius_m=0.005,
                          occluders=occ, occluder_starts=starts, pose_grip=pose_grip).masks  # fmt: skip
    hits = camera_hits(mesh, centres, sites.normals, rig, poses, [g.capsules for g in grips], 180.0, pose_grip)
    inside = np.array([[any(enclosed_by(centres[i], c.a, c.b, c.radius, c.flat)[0] for c in g.capsules) for g in grips]
                       for i in range(len(centres))])  # fmt: skip
    held = inside[:, pose_grip]  # (sites, poses): the site is inside the pose's hand
    assert held.any() and (~held).any()
    assert (masks[held] == 0).all()
    assert not hits.transpose(1, 0, 2)[held].any()
    # the same sites at poses where another grip holds the prop: seen at some
    some = np.flatnonzero(held.any(axis=1))
    assert (masks[some][~held[some]] != 0).any()


def _fist_shares(mesh, points, monkeypatch, step=None, positions=POSITIONS):
    """The share of the distribution's grips whose fist covers each point (palm places at most
    ``step`` palms apart; the module's own when None)."""
    import starforge.props.grips as grips

    if step is not None:
        monkeypatch.setattr(grips, "STEP", step)
    _, dist = grip_distribution(mesh, positions=positions)
    monkeypatch.undo()
    return np.mean([inside_capsules(points, [g.capsules[0]]) for g in dist], axis=0)


@pytest.mark.parametrize("make", [_torch, pytest.param(_screwdriver, marks=pytest.mark.slow)], ids=["torch", "screwdriver"])
def test_the_grip_places_stand_for_a_hand_anywhere_along_the_reach(make, monkeypatch):
    """Each surface point is covered by about the share of grips that a palm placed anywhere
    along the reach covers it in (brute force: a palm every hundredth of a palm), and closer
    than with places half a palm apart."""
    mesh = make()
    pts = trimesh.sample.sample_surface(mesh, 2000, seed=1)[0]
    dense = _fist_shares(mesh, pts, monkeypatch, step=0.01, positions=400)
    ours = np.abs(_fist_shares(mesh, pts, monkeypatch) - dense)
    half = np.abs(_fist_shares(mesh, pts, monkeypatch, step=0.5, positions=7) - dense)
    assert ours.max() <= 0.05 and ours.mean() <= 0.015  # within a wrap's turn of the places
    assert ours.max() < half.max() and ours.mean() < half.mean()
