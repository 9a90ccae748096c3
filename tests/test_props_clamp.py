"""Clamps round a rod (``place --standoff`` on a shaft too thin for a post's foot): which sites take
one, the rod's radius and axis, the room along the rod, and the printed ring, each checked
against the shape's own formulas (a cylinder's radius and axis, the distance to a flange, a
ring's cross-section)."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import trimesh

from starforge.props.clamp import CLAMP_MAX_R_M, CLAMP_ROOM_M, CLAMP_WALL_MM, MARGIN_STEP_M, clamp_fit
from starforge.props.seat import SeatRules, seat_for, seat_report, with_standoff
from starforge.props.standoff import (
    CLAMP_OPENING,
    POST_SEGMENTS,
    clamp_sizes,
    clamp_solid,
    clamps_solid,
    standoff_words,
)
from tests.conftest import run_cli
from tests.test_props_standoff import sliced_layers

ROD_R = 0.004
FLANGE_Z = 0.0  # the flange's face; the rod runs from it up to ROD_TOP
ROD_TOP = 0.1
WIDTH, ERROR, CAP = 0.007, 0.002, 0.005


def _rod_with_flange(sections: int = 64) -> trimesh.Trimesh:
    rod = trimesh.creation.cylinder(radius=ROD_R, height=ROD_TOP + 0.01, sections=sections)
    rod.apply_translation([0, 0, (ROD_TOP - 0.01) / 2])
    flange = trimesh.creation.cylinder(radius=0.02, height=0.01, sections=sections)
    flange.apply_translation([0, 0, FLANGE_Z - 0.005])
    return trimesh.boolean.union([rod, flange], engine="manifold")


def _on_rod(z: np.ndarray, angle: np.ndarray, mesh=None):
    """Sites on the rod at heights ``z`` and angles round it: on the circle, or on ``mesh``'s
    surface nearest it, with that face's normal (a prism's flats lie inside the circle)."""
    n = np.column_stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)])
    p = n * ROD_R + np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    if mesh is None:
        return p, n
    q, _, face = trimesh.proximity.closest_point(mesh, p)
    return q, mesh.face_normals[face]


@pytest.mark.parametrize("sections", [16, pytest.param(64, marks=pytest.mark.slow)])
def test_a_clamp_fits_round_a_rod_with_the_room_the_rod_has(sections):
    """Against the cylinder's own numbers: its radius (less the flats' sag on a prism), its axis
    (z), and the room along it, the rod's straight stretch beyond the ring's half-width, up to
    the cap; a ring whose outside comes within the wall and the room of the flange is refused."""
    mesh = _rod_with_flange(sections)
    z = np.arange(0.004, 0.097, 0.0025)
    pts, nrm = _on_rod(z, np.linspace(0.1, 6.0, len(z)), mesh)
    r, axis, margin = clamp_fit(mesh, pts, nrm, WIDTH, ERROR, CAP)
    flats = ROD_R * math.cos(math.pi / sections)  # a prism's flat lies this far from its axis
    ok = r > 0
    assert np.all((r[ok] >= flats - 2e-5) & (r[ok] <= ROD_R + 2e-5))
    assert np.allclose(np.abs(axis[ok, 2]), 1.0, atol=1e-6)
    # the straight rod beyond the ring's half-width, on the shorter side, in the test's steps
    room = np.minimum(z - FLANGE_Z, ROD_TOP - z) - WIDTH / 2
    want = np.minimum(np.floor(room / MARGIN_STEP_M + 1e-9) * MARGIN_STEP_M, CAP)
    assert np.allclose(margin[ok], want[ok], atol=MARGIN_STEP_M + 1e-9)
    # it fits where the ring, set the error off its mark, still has the rod and the flange is
    # clear of its outside, and nowhere else (a hair either side of the limits left out)
    out = CLAMP_WALL_MM / 1000.0 + CLAMP_ROOM_M
    edge = np.minimum(z - FLANGE_Z - out, ROD_TOP - z) - WIDTH / 2 - ERROR
    clear = np.abs(edge) > 1e-3
    assert np.array_equal(ok[clear], (edge >= 0)[clear])
    assert ok.sum() >= len(z) // 2


def test_no_clamp_on_a_flat_face_a_thick_drum_or_a_thin_plate():
    box = trimesh.creation.box([0.1, 0.1, 0.1])  # flat: the chord is the box
    drum = trimesh.creation.cylinder(radius=2 * CLAMP_MAX_R_M, height=0.1, sections=64)  # too thick
    plate = trimesh.creation.box([0.1, 0.1, 0.0015])  # a 0.75 mm "radius" chord, no circle round it
    for mesh, p, n in [
        (box, [[0.0, 0.0, 0.05]], [[0.0, 0.0, 1.0]]),
        (drum, [[2 * CLAMP_MAX_R_M, 0.0, 0.0]], [[1.0, 0.0, 0.0]]),
        (plate, [[0.0, 0.0, 0.00075]], [[0.0, 0.0, 1.0]]),
    ]:
        r, _, _ = clamp_fit(mesh, np.array(p), np.array(n), WIDTH, ERROR, CAP)
        assert (r == 0).all()
    wall = trimesh.boolean.difference(  # a tube's wall is 4 mm thick: a chord that is no rod
        [trimesh.creation.cylinder(radius=0.04, height=0.1, sections=64), trimesh.creation.cylinder(radius=0.036, height=0.11, sections=64)],
        engine="manifold",
    )
    r, _, _ = clamp_fit(wall, np.array([[0.0, 0.036, 0.0]]), np.array([[0.0, -1.0, 0.0]]), WIDTH, ERROR, CAP)
    assert (r == 0).all()


def test_the_seat_takes_a_clamp_only_with_a_post_and_only_where_no_foot_rests():
    mesh = _rod_with_flange()
    z = np.array([0.03, 0.05, 0.07])
    pts, nrm = _on_rod(z, np.zeros(3), mesh)
    base = seat_for("9.5mm-m3")
    stuck = seat_report(mesh, pts, nrm, base, SeatRules())
    assert not stuck.ok.any() and stuck.clamp_m is None  # a 4 mm rod seats no base
    posts = seat_report(mesh, pts, nrm, with_standoff(base, 20.0), SeatRules())
    assert posts.ok.all() and np.allclose(posts.clamp_m, ROD_R, atol=1e-4)
    top = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])  # the flange's flat top, beside the rod
    flange = seat_report(mesh, np.array([[0.012, 0.0, 0.0]]), top[1], with_standoff(base, 20.0), SeatRules())
    assert flange.clamp_m[0] == 0.0  # its foot rests there, or nothing does: never a clamp


def _solid_mesh(solid) -> trimesh.Trimesh:
    m = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], m.tri_verts)


@pytest.mark.parametrize("name", ["9.5mm-m3", "6.4mm-post"])
def test_the_printed_clamp_holds_the_post_round_the_rod(name):
    """One closed solid; its bore is the rod; its opening, opposite the post, narrower than the
    rod; its post's top as far from the rod as a post's from its foot; it lies on z = 0."""
    seat = with_standoff(seat_for(name), 20.0)
    d = 7.0
    mesh = _solid_mesh(clamp_solid(seat, d))
    assert mesh.is_watertight and mesh.body_count == 1 and mesh.is_winding_consistent
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(0.0) and hi[2] == pytest.approx(seat.base_mm)
    plain = _solid_mesh(clamp_solid(with_standoff(seat_for("9.5mm-m3"), 20.0), d))
    assert plain.bounds[1][0] == pytest.approx(d / 2 + 20.0)  # a screw stud's post: its flat top
    mid = seat.base_mm / 2
    r, wall = d / 2, CLAMP_WALL_MM
    phi = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    ring = np.column_stack([(r + wall / 2) * np.cos(phi), (r + wall / 2) * np.sin(phi), np.full_like(phi, mid)])
    inside = mesh.contains(ring)
    half_gap = math.asin(CLAMP_OPENING * d / 2 / (r + wall / 2))  # the opening's half-angle at mid-wall
    open_ = np.abs(np.angle(np.exp(1j * (phi - np.pi)))) < half_gap - 0.02
    shut = np.abs(np.angle(np.exp(1j * (phi - np.pi)))) > half_gap + 0.02
    assert not inside[open_].any() and inside[shut].all()
    bore = np.column_stack([0.98 * r * np.cos(phi), 0.98 * r * np.sin(phi), np.full_like(phi, mid)])
    assert not mesh.contains(bore).any()
    assert CLAMP_OPENING * d < d  # it snaps on: the opening is narrower than the rod
    assert POST_SEGMENTS >= 32


def test_one_clamp_per_rod_size_and_the_words_name_them():
    seat = with_standoff(seat_for("9.5mm-m3"), 20.0)
    assert clamp_sizes([7.0, 7.04, 12.0, 6.96]) == [7.0, 12.0]
    mesh = _solid_mesh(clamps_solid(seat, [7.0, 12.0, 7.0]))
    assert mesh.body_count == 2 and mesh.is_watertight
    words = standoff_words(seat, [0.0, 7.0, 0.0, 12.0, 7.0])
    assert "print 2;" in words and "markers 2, 5: the post on a split ring snapped round the 7 mm rod" in words
    assert "marker 4: the post on a split ring snapped round the 12 mm rod (clamps.stl), print 1" in words


def _screwdriver():
    handle = trimesh.creation.cylinder(radius=0.016, height=0.1, sections=48)
    handle.apply_translation([0, 0, 0.05])
    shaft = trimesh.creation.cylinder(radius=0.0035, height=0.13, sections=48)
    shaft.apply_translation([0, 0, 0.16])
    return trimesh.boolean.union([handle, shaft], engine="manifold")


@pytest.mark.slow
def test_place_writes_clamps_where_posts_stand_on_the_shaft(tmp_path):
    """A screwdriver held by its handle: the layout puts posts on the shaft, placement.json names
    their rod, clamps.stl holds one clamp of that size, and a later run with no clamp removes
    the stale file only with --force."""
    path = tmp_path / "screwdriver.stl"
    _screwdriver().export(path)
    out = tmp_path / "p"
    args = ["place", "run", str(path), "--sites", "300", "--resolution", "1", "--orientations", "8"]
    assert run_cli([*args, "--standoff", "20", "--out", out, "-q"]) == 0
    doc = json.loads((out / "placement.json").read_text())
    rods = [m.get("clamp_rod_mm") for m in doc["markers"]]
    assert any(rods)
    for m in doc["markers"]:  # a clamped marker's mark is on the shaft, its normal square to it
        if m.get("clamp_rod_mm"):
            assert m["clamp_rod_mm"] == pytest.approx(7.0, abs=0.1)
            assert math.hypot(*m["position"][:2]) == pytest.approx(0.0035, abs=1e-4) and m["position"][2] > 0.1
            assert abs(m["normal"][2]) < 1e-6
    clamps = trimesh.load(out / "clamps.stl")
    assert clamps.is_watertight and clamps.body_count == 1
    # the same folder, markers stuck on: the clamps would not fit them
    box_args = ["place", "run", "box", "--sites", "150", "--resolution", "1", "--orientations", "6", "--no-hand"]
    assert run_cli([*box_args, "--standoff", "12", "--out", out, "-q"]) == 2  # no overwrite without --force
    assert run_cli([*box_args, "--standoff", "12", "--out", out, "-q", "--force"]) == 0
    assert not (out / "clamps.stl").exists() and (out / "standoff.stl").exists()


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("prusa-slicer") is None, reason="PrusaSlicer is not installed here")
def test_prusaslicer_slices_the_clamp_lying_on_its_ring(tmp_path):
    """The slicer that must print it: no error, the first layer on the bed, the last at the
    ring's width, within a layer."""
    from starforge.props.standoff import solid_stl

    seat = with_standoff(seat_for("9.5mm-m3"), 20.0)
    zs = sliced_layers(tmp_path, "clamps", solid_stl(clamps_solid(seat, [7.0])))
    assert zs[0] == pytest.approx(0.2) and abs(max(zs) - seat.base_mm) <= 0.2


def test_the_prop_with_its_markers_shows_each_clamp_round_its_rod():
    """``prop_markers``: a clamped marker's ring lies round the rod's axis, between the rod and
    the wall's outside, as wide as the post; a marker on its foot gets none."""
    from starforge.props.files import marker_parts

    seat = with_standoff(seat_for("9.5mm-m3"), 20.0)
    t = np.array([0.0, 0.6, 0.8])
    n = np.cross(t, [1.0, 0.0, 0.0])
    n /= np.linalg.norm(n)
    centre = np.array([0.01, 0.02, 0.03])
    p = centre + 0.0035 * n
    with_ring = trimesh.Trimesh(*marker_parts(p[None], n[None], seat, [7.0], t[None]))
    without = trimesh.Trimesh(*marker_parts(p[None], n[None], seat))
    assert len(with_ring.split(only_watertight=False)) == len(without.split(only_watertight=False)) + 1
    ring = min(with_ring.split(only_watertight=False), key=lambda m: np.linalg.norm(m.vertices.mean(axis=0) - centre))
    rel = ring.vertices - centre
    along = rel @ t
    radial = np.linalg.norm(rel - along[:, None] * t, axis=1)
    assert np.allclose(np.abs(along), seat.base_radius_m, atol=1e-6)  # its two faces, as wide as the post (float32)
    assert radial.min() >= 0.0035 - 1e-6 and radial.max() <= 0.0035 + CLAMP_WALL_MM / 1000.0 + 1e-6


def test_the_guide_draws_each_clamps_ring_where_the_printed_ring_sits():
    """The guide's views outline a clamped marker's ring by its two faces: circles round the rod's
    axis at the wall's outside, the post's half-width either side of the mark, on the ring
    ``prop_markers`` shows; a marker on its foot gets none, and a layout without clamps none."""
    from starforge.props.files import marker_parts
    from starforge.render.prop_views import clamp_rings

    seat = with_standoff(seat_for("9.5mm-m3"), 20.0)
    t = np.array([0.0, 0.6, 0.8])
    n = np.cross(t, [1.0, 0.0, 0.0])
    n /= np.linalg.norm(n)
    centre = np.array([0.01, 0.02, 0.03])
    p = np.array([centre + 0.0035 * n, centre + [0.05, 0.0, 0.0]])
    normals = np.array([n, [1.0, 0.0, 0.0]])
    rings = clamp_rings(p, normals, [7.0, 0.0], [t, [0.0, 0.0, 0.0]], seat.base_radius_m)
    assert np.isnan(rings[1]).all() and np.isfinite(rings[0]).all()
    rel = rings[0].reshape(-1, 3) - centre
    along = rel @ t
    radial = np.linalg.norm(rel - along[:, None] * t, axis=1)
    assert np.allclose(np.abs(along), seat.base_radius_m) and np.allclose(radial, 0.0035 + CLAMP_WALL_MM / 1000.0)
    parts = trimesh.Trimesh(*marker_parts(p[:1], n[None], seat, [7.0], t[None])).split(only_watertight=False)
    printed = min(parts, key=lambda m: np.linalg.norm(m.vertices.mean(axis=0) - centre)).vertices - centre
    p_along = printed @ t
    p_radial = np.linalg.norm(printed - p_along[:, None] * t, axis=1)
    rim = p_radial > p_radial.max() - 1e-6  # the printed ring's outer edges (float32)
    assert np.allclose(p_radial[rim], radial[0], atol=1e-6) and np.allclose(np.abs(p_along[rim]), seat.base_radius_m, atol=1e-6)
    assert clamp_rings(p, normals, [0.0, 0.0], np.zeros((2, 3)), seat.base_radius_m) is None
