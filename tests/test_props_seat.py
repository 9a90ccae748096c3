"""Seated markers, the hand, the fresh-pose evaluation, the rigging guide and the prop-name fixes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.props.seat import (
    Seat,
    SeatRules,
    disc_offsets,
    seat_for,
    seat_report,
    sharp_edge_points,
    tilt_distance,
)


def _box(ext=(0.1, 0.06, 0.04)):
    import trimesh

    return trimesh.creation.box(extents=ext)


def test_seat_from_the_catalogue_and_from_a_diameter():
    s = seat_for("9.5mm-m3")
    assert (s.ball_mm, s.base_mm, s.centre_height_mm) == (9.5, 7.0, 5.2)
    assert seat_for(9.5) == s  # a plain diameter takes the catalogue entry of that size
    odd = seat_for(8.0)  # none in the catalogue: 0.75 / 0.55 diameters
    assert odd.base_mm == pytest.approx(6.0) and odd.centre_height_mm == pytest.approx(4.4)
    pad = seat_for("14mm-m4", base_mm=20)
    assert pad.base_mm == 20 and pad.ball_mm == 14.0
    with pytest.raises(StarforgeError, match="marker must be a catalogue marker"):
        seat_for("nope")


def test_disc_samples_are_area_uniform():
    off = disc_offsets()
    r = np.linalg.norm(off, axis=1)
    assert r.max() == pytest.approx(1.0) and r.min() == 0.0
    # area-uniform: the fraction inside radius 1/sqrt(2) is about half
    assert abs((r <= 1 / math.sqrt(2)).mean() - 0.5) < 0.06


def test_sharp_edges_of_a_box_and_the_distance_to_them():
    box = _box()
    pts = sharp_edge_points(box, 30.0)
    # every sample lies on one of the 12 edges: two coordinates at their extremes
    half = np.array([0.05, 0.03, 0.02])
    on_extreme = np.isclose(np.abs(pts), half, atol=1e-9).sum(axis=1)
    assert (on_extreme >= 2).all()
    # the steps cover the edges' total length
    assert len(pts) >= 4 * (0.1 + 0.06 + 0.04) / 2.5e-4
    # a cylinder's facet edges (11.25 deg) are not sharp at 30 deg, its rims are
    import trimesh

    cyl = trimesh.creation.cylinder(radius=0.02, height=0.1, sections=32)
    p = sharp_edge_points(cyl, 30.0)
    assert np.allclose(np.abs(p[:, 2]), 0.05)


def test_seat_report_on_a_box_against_brute_force():
    box = _box()
    seat = seat_for("9.5mm-m3")  # 7 mm base, radius 3.5 mm
    rules = SeatRules()
    # sites on the +z face at growing distances from the x = 0.05 edge
    d = np.array([0.001, 0.003, 0.0036, 0.01, 0.02])
    pts = np.column_stack([0.05 - d, np.zeros(5), np.full(5, 0.02)])
    nrm = np.tile([0.0, 0, 1], (5, 1))
    rep = seat_report(box, pts, nrm, seat, rules)
    assert np.allclose(rep.edge_m, d, atol=1.3e-4)  # sampled edges: within half a step
    # a base radius plus the 2 mm placement error from the edge; without the error, a base radius
    assert rep.ok.tolist() == [False, False, False, True, True]
    assert seat_report(box, pts, nrm, seat, SeatRules(placement_error_mm=0.0)).ok.tolist() == [False, False, True, True, True]
    # the margin: the room beyond the base radius to the edge (or the tilted side face), capped,
    # never more than the true room (the edge samples err upward by at most half a step)
    true = np.minimum(d, 0.0035 + rules.margin_cap_mm / 1000) - 0.0035
    assert (rep.margin_m <= true + 1.3e-4).all()
    assert np.allclose(rep.margin_m, true, atol=1e-3)
    # contact: the part of the disc over the face, brute force on a fine grid
    g = np.linspace(-1, 1, 801)
    X, Y = np.meshgrid(g, g)
    inside = X**2 + Y**2 <= 1
    for di, c in zip(d, rep.contact, strict=True):
        exact = ((X[inside] * 0.0035) <= di).mean()
        assert abs(c - exact) < 0.08
    assert np.allclose(rep.clearance_m, 0.0052)


@pytest.mark.parametrize("seed", range(3))
def test_tilt_distance_on_a_box_against_the_exact_distance_to_its_sides(seed):
    """Sites on a box's top face: the nearest surface tilted past 30 degrees is a side face, whose
    nearest point is on the top's rim (the bottom, turned away and below, does not count), so
    the distance is the site's distance to the rim, capped at the reach; every site is looked up,
    those far inside get the reach."""
    box = _box()
    rng = np.random.default_rng(seed)
    reach = 0.012
    pts = np.column_stack([rng.uniform(-0.05, 0.05, 400), rng.uniform(-0.03, 0.03, 400), np.full(400, 0.02)])
    nrm = np.tile([0.0, 0.0, 1.0], (400, 1))
    got = tilt_distance(box, pts, nrm, 30.0, reach)
    rim = np.min(np.column_stack([0.05 - np.abs(pts[:, 0]), 0.03 - np.abs(pts[:, 1])]), axis=1)
    assert np.allclose(got, np.minimum(rim, reach), atol=1e-12)
    assert (got == reach).any() and (got < reach).any()


def test_seat_rejects_a_tight_curve_and_accepts_a_gentle_one():
    import trimesh

    seat = seat_for("9.5mm-m3")
    rules = SeatRules(min_contact=1.0)
    for radius, ok in ((0.008, False), (0.06, True)):
        cyl = trimesh.creation.cylinder(radius=radius, height=0.1, sections=256)
        pts = np.array([[radius * math.cos(0.01), radius * math.sin(0.01), 0.0]])
        nrm = pts / np.linalg.norm(pts)
        rep = seat_report(cyl, pts, nrm, seat, rules)
        # the flat base's sag over a cylinder: a^2 / 2R against 0.3 mm
        sag = 0.0035**2 / (2 * radius)
        assert (sag <= 0.0003) == ok
        assert bool(rep.ok[0]) == ok


def test_a_ball_that_would_cut_in_is_refused():
    """A ball in the inside corner of an L: centre 2 mm off the floor, 1 mm from the wall."""
    import trimesh

    from starforge.props.solids import union_solids

    floor = trimesh.creation.box(extents=(0.1, 0.1, 0.01))
    wall = trimesh.creation.box(extents=(0.01, 0.1, 0.05), transform=trimesh.transformations.translation_matrix([0.045, 0, 0.03]))
    L = union_solids([floor, wall])
    seat = Seat("4 mm ball", 4.0, 0.0, 2.0)
    rules = SeatRules(base=False)
    pts = np.array([[0.039, 0.0, 0.005], [0.0, 0.0, 0.005]])
    rep = seat_report(L, pts, np.tile([0.0, 0, 1], (2, 1)), seat, rules)
    assert rep.ok.tolist() == [False, True]
    assert rep.clearance_m[0] == pytest.approx(0.001, abs=1e-6)


def test_paper_spec_puts_one_marker_per_site_and_no_ball_cuts_in():
    from starforge.props.placement import run_placement

    res = run_placement("box", "paper", markers=10, sites=300, resolution=2)
    sites = list(res.marker_sites)
    assert len(set(sites)) == len(sites)
    c = res.centres()
    d = np.linalg.norm(c[:, None] - c[None], axis=2)[np.triu_indices(len(c), 1)]
    assert d.min() > 0
    assert (res.prop.mesh.nearest.on_surface(c)[1] >= 0.002 - 5e-5).all()


def test_hand_grip_parsing_and_default():
    from starforge.props.builtin import builtin_mesh
    from starforge.props.grips import grip_distribution, held_part, under_hand
    from starforge.props.hand import FINGERS_M, parse_grip

    cap = parse_grip("0,0,0.02,0,0,0.11,0.015")
    assert cap.radius == pytest.approx(0.015 + FINGERS_M)
    with pytest.raises(StarforgeError, match="--grip"):
        parse_grip("1,2,3")
    _, grips = grip_distribution(builtin_mesh("hammer"))
    pts = np.array([[0, 0, 0.05], [0.05, 0, 0.31]])  # on the handle, on the head
    assert under_hand(pts, pts, grips).tolist() == [True, False]
    # a mesh without a grip of its own: the thinner end of its longest axis
    import trimesh

    bat = trimesh.util.concatenate([
        trimesh.creation.cylinder(radius=0.015, height=0.2, transform=trimesh.transformations.translation_matrix([0, 0, 0.1])),
        trimesh.creation.cylinder(radius=0.04, height=0.3, transform=trimesh.transformations.translation_matrix([0, 0, 0.35])),
    ])  # fmt: skip
    g = held_part(bat)  # the 30 mm handle, not the 80 mm barrel
    assert g.found and max(g.a[2], g.b[2]) < 0.21 and g.radius_m == pytest.approx(0.015, abs=2e-3)


def test_a_small_prop_is_pinched_by_the_fingertips_and_a_large_one_held_in_a_fist():
    import trimesh

    from starforge.props.grips import grip_distribution
    from starforge.props.hand import FINGERTIP_M, PINCH_BELOW_M, PINCH_M, inside_capsules

    small = trimesh.creation.box(extents=(0.09, 0.02, 0.01))  # a bottle opener's size
    (pinched,) = grip_distribution(small)[1]
    tips, rest = pinched.capsules
    fine = small
    for _ in range(6):
        fine = fine.subdivide()
    surf = np.asarray(fine.vertices)  # points on the surface, about 1.5 mm apart
    # the rest of the hand lies beyond the prop's end: it covers no surface point
    assert not inside_capsules(surf, (rest,)).any()
    # the fingertips cover the end's surface over about PINCH_M, not a fist's 90 mm
    covered = surf[inside_capsules(surf, (tips,))]
    assert len(covered)
    span = np.ptp(covered[:, 0])
    assert span <= PINCH_M + 2 * (tips.radius) + 1e-9 and span < 0.045
    assert tips.radius <= 0.012 + FINGERTIP_M  # the section's half-diagonal plus a fingertip
    # the hand sits at the same end as the fingertips
    assert np.sign(rest.a[0]) == np.sign(np.mean(covered[:, 0])) != 0
    # a prop a fist closes round: fists, each with a wrist beside it
    big = trimesh.creation.box(extents=(PINCH_BELOW_M + 0.1, 0.03, 0.03))
    assert all(len(g.capsules) == 2 and g.hand in ("left", "right") for g in grip_distribution(big)[1])


def test_the_hand_hides_what_lies_behind_it():
    """Compiled capsule test against a numpy brute force over points along each sight line."""
    from starforge.props.hand import Capsule, capsule_arrays
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.visibility import compute_table

    box = _box((0.2, 0.2, 0.02))
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-0.09, 0.09, 40), rng.uniform(-0.09, 0.09, 40), np.full(40, 0.01)])
    nrm = np.tile([0.0, 0, 1], (40, 1))
    cap = Capsule((-0.1, 0.0, 0.06), (0.1, 0.0, 0.06), 0.03)
    rig = load_rig("default")
    poses = make_poses(rig.volume, 1, 6, np.zeros(3), rng)
    with_hand = compute_table(box, pts, nrm, rig, poses, 180.0, radius_m=0.002, occluders=capsule_arrays((cap,)))
    without = compute_table(box, pts, nrm, rig, poses, 180.0, radius_m=0.002)
    assert (with_hand.masks & ~without.masks).sum() == 0  # the hand only removes
    cams = np.array([c.position for c in rig.cameras])
    a, b = np.array(cap.a), np.array(cap.b)
    t = np.linspace(0, 1, 6000)[:, None]
    for k in range(len(poses)):
        R, T = poses.rotations[k], poses.translations[k]
        q = (cams - T) @ R  # cameras in the prop frame (pivot 0)
        for i in range(0, 40, 5):
            c = pts[i] + 0.002 * nrm[i]
            for j in range(len(cams)):
                seg = c + t * (q[j] - c)
                s = np.clip((seg - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
                hidden = (np.linalg.norm(seg - (a + s[:, None] * (b - a)), axis=1) <= cap.radius).any()
                bit_w = bool((int(with_hand.masks[i, k]) >> j) & 1)
                bit_o = bool((int(without.masks[i, k]) >> j) & 1)
                if bin(int(without.masks[i, k])).count("1") >= 2 and bin(int(with_hand.masks[i, k])).count("1") >= 2:
                    assert bit_w == (bit_o and not hidden)


def test_loss_scenarios_count_two_surviving_cameras():
    from starforge.props.scenarios import alive_masks, loss_scenarios

    rng = np.random.default_rng(0)
    alive = alive_masks(8, 0.5, 500, rng)
    assert (np.bitwise_count(alive) == 4).all() and (alive < 256).all()
    masks = rng.integers(0, 256, size=(30, 50)).astype(np.uint64)
    seen, alive = loss_scenarios(masks, 8, 0.5, 3, np.random.default_rng(1))
    assert seen.shape == (30, 150)
    for s in range(30):
        for col in range(150):
            p = col // 3
            live = [c for c in range(8) if (int(alive[col]) >> c) & 1]
            n = sum((int(masks[s, p]) >> c) & 1 for c in live)
            assert seen[s, col] == (n >= 2)


def test_evaluation_spread_rule_matches_svd():
    from starforge.props.evaluate import tracked_poses

    rng = np.random.default_rng(5)
    centres = rng.normal(size=(6, 3)) * 0.03
    hits = rng.random((200, 6, 8)) < 0.5
    alive = np.full(200, np.uint64(255))
    got = tracked_poses(hits, alive, centres, 15.0)
    for k in range(200):
        rec = hits[k].sum(axis=1) >= 2
        P = centres[rec]
        if len(P) < 3:
            assert not got[k]
            continue
        sv = np.linalg.svd(P - P.mean(0), compute_uv=False)
        spread = math.sqrt((sv[1] ** 2 + sv[2] ** 2) / len(P))
        assert got[k] == (spread >= math.sqrt(2) / 3 * 0.015)


def test_paired_comparison_counts_discordant_poses_and_its_exact_p_value():
    from scipy.stats import binomtest

    from starforge.props.evaluate import mcnemar_exact, paired

    rng = np.random.default_rng(11)
    a = rng.random(1000) < 0.995
    b = rng.random(1000) < 0.997
    got = paired(a, b)
    assert got["poses_only_it_tracks"] == sum(bool(y and not x) for x, y in zip(a, b, strict=True))
    assert got["poses_only_default_tracks"] == sum(bool(x and not y) for x, y in zip(a, b, strict=True))
    # the tracked fractions differ by exactly the discordant poses
    assert (b.sum() - a.sum()) == got["poses_only_it_tracks"] - got["poses_only_default_tracks"]
    for k, n in ((0, 0), (0, 1), (1, 3), (0, 3), (2, 9), (5, 5), (0, 20), (40, 70)):
        want = 1.0 if k + n == 0 else binomtest(k, k + n, 0.5).pvalue  # independent: scipy's exact test
        assert mcnemar_exact(k, n) == pytest.approx(want, rel=1e-9)
        assert mcnemar_exact(k, n) == mcnemar_exact(n, k)
    assert mcnemar_exact(0, 3) == 0.25 and mcnemar_exact(0, 6) < 0.05


def test_landmarks_from_the_bounding_box():
    from starforge.props.guide import caliper_pairs, landmarks, mesh_guide, mesh_landmarks, tilt

    box = _box()  # 100 x 60 x 40 mm about the origin
    p = np.array([[0.04, -0.02, 0.02]])
    face = box.nearest.on_surface(p)[2]
    feats = mesh_landmarks(box)
    # the middles of its six faces (its flat ends along each axis) and its eight corners, none twice
    pts = np.array([f["point"] for f in feats])
    half = np.array([0.05, 0.03, 0.02])
    middles = np.array([s * half[k] * np.eye(3)[k] for k in range(3) for s in (1, -1)])
    corners = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.03, 0.03) for z in (-0.02, 0.02)])
    want = np.vstack([middles, corners])
    assert len(pts) == 14 and np.allclose(np.linalg.norm(pts[:, None] - want[None], axis=2).min(1), 0, atol=1e-9)
    assert np.allclose(np.linalg.norm(want[:, None] - pts[None], axis=2).min(1), 0, atol=1e-9)
    assert [f["kind"] for f in feats] == ["tip"] * 6 + ["corner"] * 8
    m = landmarks(mesh_guide(box), p, np.array([[0.0, 0, 1]]), face)[0]
    assert m["from"] == {"x": "max", "y": "min", "z": "max"}
    assert m["distance_mm"] == [10.0, 10.0, 0.0]
    assert m["face"]["kind"] == "flat" and m["face"]["facing"] == "+z" and m["face"]["area_mm2"] == 6000
    # three corners, nearest first, each at the distance the guide prints (brute force)
    named = {f["name"]: np.array(f["point"]) for f in feats}
    got = [x["distance_mm"] for x in m["measure_from"]]
    assert len(got) == 3 and got == sorted(got)
    for x in m["measure_from"]:
        assert x["distance_mm"] == pytest.approx(np.linalg.norm(named[x["name"]] - p[0]) * 1000, abs=0.05)
    # on a flat face, first order holds: the error is the ellipse's reach, sqrt(5.99 / lambda_min)
    lp = np.array([named[x["name"]] for x in m["measure_from"]])
    g = (p[0] - lp) / np.linalg.norm(p[0] - lp, axis=1)[:, None]
    sig = 0.5 + 0.005 * np.linalg.norm(p[0] - lp, axis=1) * 1000
    info = (g[:, :2] / sig[:, None]).T @ (g[:, :2] / sig[:, None])
    assert m["locating_error_mm"] == pytest.approx(np.sqrt(-2 * np.log(0.05) / np.linalg.eigvalsh(info)[0]), abs=0.01)
    assert m["tilt_deg"] == 0 and tilt([1.0, 0, 1.0]) == (pytest.approx(45.0), "+x")
    # caliper pairs: every pair once, the centre distance by brute force, outside = + a diameter
    c = np.random.default_rng(2).random((5, 3)) * 0.1
    pairs = caliper_pairs(c, 9.5, 2.0)
    assert len(pairs) == 10
    for q in pairs:
        d = np.linalg.norm(c[q["a"] - 1] - c[q["b"] - 1]) * 1000
        assert q["centre_mm"] == pytest.approx(d, abs=0.05) and q["outside_mm"] == pytest.approx(d + 9.5, abs=0.1)
        assert q["tolerance_mm"] == 4.0


def test_bases_mesh_adds_a_pad_per_marker():
    from starforge.props.guide import bases_mesh

    box = _box()
    pts = np.array([[0.0, 0, 0.02], [0.03, 0, 0.02]])
    out = bases_mesh(box, pts, np.tile([0.0, 0, 1], (2, 1)), base_mm=7.0, height_mm=1.0)
    assert out.is_watertight
    # each pad adds its part above the surface: pi r^2 h (32-gon, within 1 %)
    added = out.volume - box.volume
    assert added == pytest.approx(2 * math.pi * 0.0035**2 * 0.001, rel=0.01)


def test_builtin_prefix_and_a_folder_of_that_name(tmp_path, monkeypatch):
    from starforge.props.mesh import load_prop
    from starforge.props.prepare import prop_name_warnings

    monkeypatch.chdir(tmp_path)
    (tmp_path / "hammer").mkdir()
    p = load_prop("hammer")
    assert p.source == "builtin"
    assert "built-in hammer was used" in prop_name_warnings(p)[0]
    assert load_prop("builtin:hammer").source == "builtin"
    with pytest.raises(StarforgeError, match="unknown built-in"):
        load_prop("builtin:anvil")


def test_turned_extent_warning():
    from starforge.props.mesh import PropMesh
    from starforge.props.prepare import check_scale
    from starforge.props.rig import load_rig

    rig = load_rig("default")  # 2 x 2 x 2 m
    long = _box((0.1, 0.1, 1.9))  # fits upright; turned it sweeps a 1.91 m ball: fits
    thin = _box((1.5, 1.5, 0.1))  # fits upright; turned it sweeps 2.12 m: does not
    mk = lambda m: PropMesh.of(m, "p", "x.stl", "m", np.arange(len(m.faces)), (), len(m.faces))  # noqa: E731
    assert check_scale(mk(long), rig, 0.0095) == []
    w = check_scale(mk(thin), rig, 0.0095)
    assert len(w) == 1 and "not when turned" in w[0] and "2.12" in w[0]


def test_the_evaluation_agrees_with_the_compiled_table():
    """Two implementations of what a camera sees (the evaluation's numpy geometry and the
    compiled table) agree on random poses of the hammer held in its hand."""
    from starforge.props.builtin import builtin_mesh
    from starforge.props.evaluate import camera_hits, random_poses
    from starforge.props.hand import GRIPS, capsule_arrays, fist
    from starforge.props.rig import load_rig
    from starforge.props.sites import sample_sites
    from starforge.props.visibility import compute_table

    mesh = builtin_mesh("hammer")
    rig = load_rig("default")
    rng = np.random.default_rng(11)
    sites = sample_sites(mesh, 40, rng)
    caps = (fist(*GRIPS["hammer"]),)
    poses = random_poses(rig.volume, 60, mesh.bounds.mean(axis=0), rng)
    table = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, radius_m=0.00475, centre_m=0.0052,
                          occluders=capsule_arrays(caps))  # fmt: skip
    hits = camera_hits(mesh, sites.points + 0.0052 * sites.normals, sites.normals, rig, poses, caps, 180.0)
    C = len(rig.cameras)
    bits = ((table.masks.T[..., None] >> np.arange(C, dtype=np.uint64)) & np.uint64(1)).astype(bool)  # (P, s, C)
    both = (bits.sum(axis=2) >= 2) & (hits.sum(axis=2) >= 2)
    assert both.mean() > 0.3
    agree = (bits == hits).all(axis=2)[both].mean()
    assert agree >= 0.99  # sight lines that graze an edge may go either way in float32 embree
    # a marker the table counts as seen by two cameras, the evaluation does too, and back
    assert ((bits.sum(axis=2) >= 2) == (hits.sum(axis=2) >= 2)).mean() >= 0.99


def test_a_mesh_is_held_by_its_handle_not_by_a_blade():
    """The sword's mesh (no grip of its own as a file) is held at its hilt, not its thin tip; a
    blade alone (4 mm thick) has no handle; a turned box's sections measure its true widths."""
    import trimesh

    from starforge.props.builtin import builtin_mesh
    from starforge.props.grips import held_part
    from starforge.props.hand import section_widths

    sword = builtin_mesh("sword")
    g = held_part(sword)
    assert g.found and max(g.a[2], g.b[2]) < 0.2 < 0.9 * float(sword.bounds[1][2])
    assert not held_part(trimesh.creation.box(extents=(0.04, 0.004, 0.3))).found
    box = trimesh.creation.box(extents=(0.05, 0.02, 0.3))
    box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30), [0, 0, 1]))
    w = section_widths(box, 2, np.linspace(-0.14, 0.14, 8))
    assert np.allclose(w[:, 0], 0.05) and np.allclose(w[:, 1], 0.02)


def test_the_ends_named_are_points_a_person_finds():
    import trimesh

    from starforge.props.guide import mesh_landmarks

    # a cylinder: the middles of its two flat caps; along its sides the end is a line, no point
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.2, sections=64)
    tips = np.array([f["point"] for f in mesh_landmarks(cyl) if f["kind"] == "tip"])
    assert len(tips) == 2 and np.allclose(np.sort(tips[:, 2]), [-0.1, 0.1]) and np.allclose(tips[:, :2], 0, atol=1e-9)
    # a cone: its apex (a point), and the middle of its base
    cone = trimesh.creation.cone(radius=0.03, height=0.1, sections=64)
    feats = [f for f in mesh_landmarks(cone) if f["kind"] == "tip"]
    got = {f["what"].split(" (")[0]: np.array(f["point"]) for f in feats}
    assert len(feats) == 2
    assert np.allclose(got["the end towards +z"], [0, 0, 0.1]) and np.allclose(got["the middle of the flat end towards -z"], 0)
    # a disc 12 mm thick: the facets of its rim are slivers, not faces to measure across
    slab = trimesh.creation.cylinder(radius=0.05, height=0.012, sections=64)
    assert len([f for f in mesh_landmarks(slab) if f["kind"] == "tip"]) == 2  # the two faces only


@pytest.mark.parametrize(("sections", "sides_flat"), [(6, True), (8, True), (12, True), (16, False), (32, False), (64, False)])
def test_a_flat_face_has_edges_a_person_finds(sections, sides_flat):
    """A prism's sides bend 360 / sections degrees into each other: a hexagon's or a dodecagon's
    are faces to find, a 16-gon's or a tessellated cylinder's are the round body; the caps bend
    90 degrees into the sides and are faces either way."""
    import trimesh

    from starforge.props.guide import FLAT_EDGE_DEG, landmarks, mesh_guide

    prism = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=sections)
    # a side's outline: two long edges bending 360/sections degrees, two short rim edges bending
    # 90 (by length, the long ones are most of it)
    bend = 360.0 / sections
    assert (bend >= FLAT_EDGE_DEG) == sides_flat
    fn = np.asarray(prism.face_normals)
    side = int(np.flatnonzero(np.abs(fn[:, 2]) < 1e-9)[0])
    cap = int(np.flatnonzero(fn[:, 2] > 0.99)[0])
    p = np.asarray(prism.triangles_center)[[side, cap]]
    got = landmarks(mesh_guide(prism), p, fn[[side, cap]], np.array([side, cap]))
    assert got[0]["face"]["kind"] == ("flat" if sides_flat else "curved")
    assert got[1]["face"]["kind"] == "flat" and got[1]["face"]["facing"] == "+z"
    assert got[0]["text"].startswith("on flat face" if sides_flat else "on the curved surface")
