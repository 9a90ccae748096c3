"""Markers on printed stand-off posts (``place --standoff``): the seat they sit on, the hand that
cannot hold a post, the post's clearance from the prop and the printed part itself, each checked
against its own geometry (a polygon's area, a dense sampling, a segment's distance)."""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from starforge.errors import StarforgeError
from starforge.geometry.distance import segment_segment_distance
from starforge.markers import POST_MIN_WIDTH_MM, load_marker, marker_names, post_top
from starforge.props.hand import Capsule, capsule_arrays, posts_in_hands
from starforge.props.seat import SeatRules, post_clear, seat_for, seat_report, with_standoff
from starforge.props.standoff import POST_SEGMENTS, standoff_solid
from tests.conftest import run_cli


@pytest.mark.parametrize("name", marker_names())
def test_a_standoff_lifts_the_ball_and_seats_on_its_foot(name):
    seat = seat_for(name)
    up = with_standoff(seat, 20.0)
    top = post_top(load_marker(name), seat.base_mm)
    assert up.centre_height_mm == pytest.approx(seat.centre_height_mm + 20.0)
    assert up.standoff_mm == 20.0 and up.ball_mm == seat.ball_mm
    assert up.base_mm == top.width_mm >= max(seat.base_mm, POST_MIN_WIDTH_MM)
    if top.hole_mm:  # the wall round a threaded hole
        assert up.base_mm >= top.hole_mm + 2.0
    assert with_standoff(seat, 0.0) is seat


def test_a_post_too_short_for_its_marker_is_refused_naming_the_option():
    with pytest.raises(StarforgeError, match=r"--standoff 7\.2 or more"):
        with_standoff(seat_for("12.7mm-m3"), 5.0)
    with pytest.raises(StarforgeError, match="standoff"):
        with_standoff(seat_for("9.5mm-m3"), 61.0)


def _polygon_area(r: float, n: int = POST_SEGMENTS) -> float:
    return 0.5 * n * r * r * math.sin(2 * math.pi / n)


@pytest.mark.parametrize("name", marker_names())
def test_the_printed_post_is_one_closed_solid_of_the_designed_volume(name):
    seat = with_standoff(seat_for(name), 18.0)
    top = post_top(seat.marker, seat_for(name).base_mm)
    solid = standoff_solid(seat)
    mesh = trimesh.Trimesh(np.asarray(solid.to_mesh().vert_properties)[:, :3], solid.to_mesh().tri_verts)
    assert mesh.is_watertight and mesh.body_count == 1 and mesh.is_winding_consistent
    want = _polygon_area(seat.base_mm / 2) * 18.0
    want -= _polygon_area(top.hole_mm / 2) * top.hole_depth_mm
    want += _polygon_area(top.pin_mm / 2) * top.pin_length_mm
    assert mesh.volume == pytest.approx(want, rel=1e-6)
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(0.0) and hi[2] == pytest.approx(18.0 + top.pin_length_mm)
    if top.hole_mm:  # a ray down the axis enters the post at the hole's floor
        hit = mesh.ray.intersects_location([[0, 0, 30.0]], [[0, 0, -1.0]])[0]
        assert hit[:, 2].max() == pytest.approx(18.0 - top.hole_depth_mm)


def _dense_hits(a, b, cap: Capsule, samples: int = 4001) -> bool:
    t = np.linspace(0.0, 1.0, samples)
    return bool(cap.contains(a + t[:, None] * (b - a)).any())


def test_a_post_is_held_exactly_when_it_passes_through_the_hand():
    """For round capsules, against the exact distance between the post and the capsule's axis;
    for the fist's band, against a dense sampling of each post (4,001 points), a denser one
    (200,001) settling the grazes between them."""
    rng = np.random.default_rng(5)
    caps = [
        Capsule((0.0, 0.0, 0.0), (0.0, 0.0, 0.09), 0.04, True),  # a fist's band
        Capsule((0.05, 0.0, 0.04), (0.25, 0.0, 0.04), 0.03, False),  # a forearm
        Capsule((-0.05, 0.02, 0.0), (-0.05, 0.02, 0.05), 0.02, False),
    ]
    bases = rng.uniform(-0.08, 0.12, (400, 3))
    d = rng.normal(size=(400, 3))
    tops = bases + 0.03 * d / np.linalg.norm(d, axis=1, keepdims=True)
    starts = np.array([0, 1, 3])
    held = posts_in_hands(bases, tops, capsule_arrays(caps), starts)
    for i in range(len(bases)):
        exact = any(segment_segment_distance(bases[i], tops[i], np.array(c.a), np.array(c.b)) <= c.radius for c in caps[1:])
        assert held[i, 1] == exact
        if held[i, 0] != _dense_hits(bases[i], tops[i], caps[0]):
            assert held[i, 0] and _dense_hits(bases[i], tops[i], caps[0], 200_001)  # a graze the samples missed
    assert 0 < held[:, 0].sum() < len(bases) and 0 < held[:, 1].sum() < len(bases)
    # a post of no length is the point it stands on
    assert np.array_equal(posts_in_hands(bases, bases, capsule_arrays(caps), starts)[:, 0], caps[0].contains(bases))


def _slabs():
    floor = trimesh.creation.box([0.1, 0.1, 0.01])
    floor.apply_translation([0, 0, -0.005])
    shelf = trimesh.creation.box([0.1, 0.1, 0.002])
    shelf.apply_translation([0, 0, 0.015])
    return trimesh.util.concatenate([floor, shelf])


def test_a_post_that_would_run_into_the_prop_is_refused():
    mesh = _slabs()
    p, n = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    assert post_clear(mesh, p, n, 0.0035, 0.010, 5e-5).all()  # stops 3.5 mm under the shelf
    assert not post_clear(mesh, p, n, 0.0035, 0.025, 5e-5).any()  # through it
    # the ball alone would clear (its centre 31 mm up, the shelf's top at 16 mm) but the post does not
    seat = with_standoff(seat_for("9.5mm-m3"), 25.0)
    rep = seat_report(mesh, p, n, seat, SeatRules(base=False))
    assert rep.clearance_m[0] > seat.ball_radius_m and not rep.ok[0]


@pytest.mark.slow
def test_place_writes_the_post_and_the_markers_stand_on_it(tmp_path):
    import json

    out = tmp_path / "p"
    args = ["place", "run", "box", "--sites", "150", "--resolution", "1", "--orientations", "6", "--no-hand"]
    assert run_cli([*args, "--standoff", "12", "--out", out, "-q"]) == 0
    doc = json.loads((out / "placement.json").read_text())
    assert doc["seat"]["standoff_mm"] == 12.0 and doc["settings"]["standoff_mm"] == 12.0
    stl = trimesh.load(out / "standoff.stl")
    assert stl.is_watertight and stl.bounds[1][2] == pytest.approx(12.0)
    from starforge.props.builtin import builtin_mesh

    pts = np.array([m["position"] for m in doc["markers"]], float)  # where a technician marks: the surface
    assert trimesh.proximity.closest_point(builtin_mesh("box"), pts)[1].max() < 1e-6
    assert run_cli([*args, "--standoff", "12", "--out", out, "-q"]) == 2  # no overwrite without --force
    from benchmarks._pdftext import glyph_boxes, off_page, overlapping_glyphs

    pages = glyph_boxes(out / "guide.pdf")  # the guide names the post, and its text stays apart
    assert "standoff.stl" in "".join(c for c, _ in pages[0][1])
    for page in pages:
        assert overlapping_glyphs([b for _, b in page[1]]) == [] and off_page(page) == []


def test_the_table_hides_a_marker_at_the_poses_whose_grip_holds_its_post():
    """Pose by pose against the table without posts: a marker is cleared exactly where the
    pose's grip has a capsule that a dense sample of the post (site to ball centre) enters."""
    from starforge.props.grips import grip_arrays
    from starforge.props.visibility import compute_table
    from tests.test_props_grips import held_scene

    mesh = trimesh.creation.cylinder(radius=0.016, height=0.12, sections=48)
    mesh.apply_translation([0, 0, 0.06])
    grips, rig, sites, poses, pose_grip = held_scene(mesh, 50, 3)
    occ, starts = grip_arrays(grips)
    h = 0.03
    kw = dict(radius_m=0.005, centre_m=h, occluders=occ, occluder_starts=starts, pose_grip=pose_grip)
    plain = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, **kw).masks
    posts = compute_table(mesh, sites.points, sites.normals, rig, poses, 180.0, post_m=h - 0.005, **kw).masks
    tops = sites.points + h * sites.normals
    held = np.array([[any(_dense_hits(a, b, c) for c in g.capsules) for g in grips] for a, b in zip(sites.points, tops, strict=True)])
    want = np.where(held[:, pose_grip], 0, plain)
    assert (posts == want).all()
    assert (plain != posts).any() and (posts != 0).any()


def sliced_layers(folder, name: str, stl: bytes) -> list[float]:
    """The layer heights (mm) PrusaSlicer prints the STL bytes at, 0.2 mm layers; it must slice
    them without an error."""
    (folder / f"{name}.stl").write_bytes(stl)
    g = folder / f"{name}.gcode"
    res = subprocess.run(
        ["prusa-slicer", "--export-gcode", str(folder / f"{name}.stl"), "--layer-height", "0.2",
         "--first-layer-height", "0.2", "--output", str(g)],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert res.returncode == 0 and g.exists(), res.stdout[-2000:] + res.stderr[-2000:]
    return [float(z) for z in re.findall(r"^;Z:([0-9.]+)", g.read_text(), flags=re.M)]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("prusa-slicer") is None, reason="PrusaSlicer is not installed here")
@pytest.mark.parametrize("name", ["9.5mm-m3", "6.4mm-post"])
def test_prusaslicer_slices_the_post_standing_on_its_foot(tmp_path, name):
    """The slicer that must print it: no error, the first layer on the bed, the last at the post's
    top (the pin's, for a post marker), within a layer."""
    from starforge.props.standoff import standoff_stl

    seat = with_standoff(seat_for(name), 22.0)
    zs = sliced_layers(tmp_path, "post", standoff_stl(seat))
    top = 22.0 + post_top(seat.marker, seat.base_mm).pin_length_mm
    assert zs[0] == pytest.approx(0.2) and abs(max(zs) - top) <= 0.2
