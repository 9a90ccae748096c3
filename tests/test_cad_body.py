"""Body description, stem routing, visibility, fit and plate layout: pure checks (no CAD kernel).

Results are re-checked independently: sampled distances instead of the closed forms, mesh
ray casts instead of the analytic visibility, mesh bounds instead of primitive bounds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starforge.cad.body import BodySpec, body_bounds, build_body, fit_report, label_boxes
from starforge.cad.export import parse_ids
from starforge.cad.mounts import KINDS, MAX_GRID, find_spot, list_mounts, load_mount
from starforge.cad.plate import layout_plates
from starforge.cad.primitives import Box, Cylinder, Sphere
from starforge.cad.stems import route_stems
from starforge.cad.visibility import sphere_visibility
from starforge.errors import StarforgeError
from starforge.geometry.distance import (
    hemisphere_directions,
    point_segment_distance,
    segment_segment_distance,
)
from starforge.stars.model import load_family

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"


@pytest.fixture(scope="module")
def family():
    return load_family(DATA)


def _sampled_segment_distance(p, a, b, k=4001):
    t = np.linspace(0, 1, k)[:, None]
    return np.linalg.norm(a + t * (b - a) - p, axis=1).min()


# --- primitives ------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=12, max_size=12))
@pytest.mark.slow
def test_segment_distances_match_sampling(xs):
    a0, a1, b0, b1 = np.array(xs).reshape(4, 3)
    t = np.linspace(0, 1, 801)
    pa = a0 + t[:, None] * (a1 - a0)
    pb = b0 + t[:, None] * (b1 - b0)
    brute = np.linalg.norm(pa[:, None] - pb[None], axis=2).min()
    d = segment_segment_distance(a0, a1, b0, b1)
    assert d <= brute + 1e-9
    assert d >= brute - 0.02 * (np.linalg.norm(a1 - a0) + np.linalg.norm(b1 - b0)) / 2 - 1e-9
    assert point_segment_distance([b0], a0, a1)[0] == pytest.approx(
        _sampled_segment_distance(b0, a0, a1), abs=0.01
    )


def test_hemisphere_directions_are_unit_up_and_balanced():
    d = hemisphere_directions(2000)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert (d[:, 1] >= 0).all()
    # equal-area: mean of cos(theta) over a uniform hemisphere is 1/2, horizontal parts cancel
    assert d[:, 1].mean() == pytest.approx(0.5, abs=0.01)
    assert np.abs(d[:, [0, 2]].mean(axis=0)).max() < 0.02


def test_primitive_bounds_contain_sampled_surface():
    rng = np.random.default_rng(1)
    c = Cylinder((0, 0, 0), (1, 2, 3), 0.7)
    lo, hi = c.bounds()
    ax = np.array([1, 2, 3]) / np.linalg.norm([1, 2, 3])
    u = np.cross(ax, [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(ax, u)
    a = rng.uniform(0, 2 * np.pi, 2000)
    t = rng.uniform(0, 1, 2000)[:, None]
    pts = t * np.array([1, 2, 3]) + 0.7 * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    assert (pts >= lo - 1e-9).all() and (pts <= hi + 1e-9).all()
    assert (pts.min(0) - lo).max() < 0.02 and (hi - pts.max(0)).max() < 0.02
    assert Sphere((1, 2, 3), 2).volume() == pytest.approx(4 / 3 * np.pi * 8)
    assert Box((0, 0, 0), (1, 2, 3)).volume() == 6


# --- stems -----------------------------------------------------------------------------------


def _check_stems(centres, roots, rf, rs, cl, y_top, max_tilt):
    n = len(centres)
    for i in range(n):
        assert roots[i, 1] == pytest.approx(y_top)
        axis = centres[i] - roots[i]
        tilt = np.degrees(np.arccos(axis[1] / np.linalg.norm(axis)))
        assert tilt <= max_tilt + 1e-6
        for j in range(n):
            if j != i:  # brute force: sample the stem axis
                assert _sampled_segment_distance(centres[j], roots[i], centres[i]) >= rf + rs + cl - 1e-3
                if j < i:
                    t = np.linspace(0, 1, 400)[:, None]
                    pi = roots[i] + t * (centres[i] - roots[i])
                    pj = roots[j] + t * (centres[j] - roots[j])
                    assert np.linalg.norm(pi[:, None] - pj[None], axis=2).min() >= 2 * rs + cl - 0.02


def test_stems_of_the_family_keep_clear(family):
    for s in family.stars:
        c = s.vertices
        y_top = c[:, 1].min() - 2 - 1
        roots = route_stems(c, 2.0, 0.6, y_top, 0.3, 40)
        _check_stems(c, roots, 2.0, 0.6, 0.3, y_top, 40)


def test_stem_is_rerouted_around_a_sphere_below():
    # B sits right above A: a vertical stem to B would pass through A
    c = np.array([[0, 0, 0], [0, 6, 0], [10, 0, 0], [0, 0, 12]], float)
    roots = route_stems(c, 2.0, 0.6, -3.0, 0.3, 45)
    _check_stems(c, roots, 2.0, 0.6, 0.3, -3.0, 45)
    assert np.hypot(*(roots[1] - c[1])[[0, 2]]) > 2.0  # it had to lean
    assert np.allclose(roots[[0, 2, 3]][:, [0, 2]], c[[0, 2, 3]][:, [0, 2]])  # the others stand straight


def test_unroutable_stem_is_a_clear_error():
    c = np.array([[0, 0, 0], [0, 6, 0], [10, 0, 0], [0, 0, 12]], float)
    with pytest.raises(StarforgeError, match="no stem route for sphere B"):
        route_stems(c, 2.0, 0.6, -3.0, 0.3, 5)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000))
def test_random_stars_route_or_refuse(seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform([-8, -4, 0], [8, 4, 40], size=(4, 3))
    d = np.linalg.norm(c[:, None] - c[None], axis=2) + np.eye(4) * 99
    if d.min() < 5:
        return  # spheres overlap: not a star
    y_top = c[:, 1].min() - 3
    try:
        roots = route_stems(c, 2.0, 0.6, y_top, 0.3, 45)
    except StarforgeError:
        return
    _check_stems(c, roots, 2.0, 0.6, 0.3, y_top, 45)


# --- body, label, fit -------------------------------------------------------------------------


def test_body_keeps_centres_and_sizes(family):
    spec = BodySpec()
    for s in family.stars:
        b = build_body(s.id, s.vertices, family.spec.marker_mm, load_mount("flat"), spec)
        assert np.allclose(b.centres_array, s.vertices)
        spheres = [p for p in b.add if isinstance(p, Sphere)]
        assert len(spheres) == 4
        assert all(p.radius_mm == pytest.approx((4.0 - 0.2) / 2) for p in spheres)
        assert b.name == f"star_{s.id:03d}" and b.label == str(s.id)
        plate = [p for p in b.add if isinstance(p, Box)][0]
        top = plate.bounds()[1, 1]
        # the lowest finished sphere stands standoff_mm above the plate
        assert s.vertices[:, 1].min() - 2.0 - top == pytest.approx(spec.standoff_mm)
        # engraving: inside the plate top, clear of every stem root
        lb = [p for p in b.subtract if isinstance(p, Box)]
        assert lb
        pb = plate.bounds()
        for box in lb:
            lo, hi = box.bounds()
            assert lo[0] >= pb[0, 0] - 1e-9 and hi[0] <= pb[1, 0] + 1e-9
            assert lo[2] >= pb[0, 2] - 1e-9 and hi[2] <= pb[1, 2] + 1e-9
            assert top - lo[1] == pytest.approx(spec.label_depth_mm)
            for stem in b.stems:
                r = np.array(stem.p0)[[0, 2]]
                gap = np.linalg.norm(
                    np.maximum(np.abs(r - np.array(box.centre)[[0, 2]]) - np.array(box.size)[[0, 2]] / 2, 0)
                )
                assert gap >= stem.radius_mm


def test_label_glyphs_are_whole_pixels_without_diagonal_joins():
    from starforge.cad.label import COLS, FONT, ROWS, glyph_counters, glyph_rects

    for ch, rows in FONT.items():
        ink = {(c, r) for r in range(ROWS) for c in range(COLS) if rows[r][c] == "#"}
        rects = glyph_rects(ch)
        covered = [(c, r) for c0, r0, c1, r1 in rects for c in range(c0, c1) for r in range(r0, r1)]
        assert sorted(covered) == sorted(ink)  # the rectangles tile the ink, no overlap
        # no 2x2 window (the glyph's border counts as empty) with a checkerboard: two cuts or two
        # standing pixels touching only along an edge would make a non-manifold edge
        for r in range(-1, ROWS):
            for c in range(-1, COLS):
                a, b, d, e = ((c, r) in ink, (c + 1, r) in ink, (c, r + 1) in ink, (c + 1, r + 1) in ink)
                assert not (a == e and b == d and a != b), (ch, c, r)
    assert glyph_counters("8") == [(1, 1), (1, 3)] and glyph_counters("0") == [(1, 1), (1, 2), (1, 3)]
    assert glyph_counters("1") == [] and len(glyph_counters("6")) == 1 and len(glyph_counters("9")) == 1
    assert len(label_boxes("8", 3.0, (0, 0), 0.0, 0.4)) == 7  # 3 bars, 4 pixels between them
    with pytest.raises(StarforgeError, match="digits"):
        label_boxes("A", 3.0, (0, 0), 0.0, 0.4)


def test_label_reads_right_side_up_on_the_bed():
    """In the printing orientation (x -> X, -z -> Y) the first glyph is at the left (-X) and the
    top row (a 7's bar) at +Y: seen from above, the id reads as written."""
    from starforge.cad.label import label_rects
    from starforge.cad.plate import TO_BED

    rects = label_rects("17", 5.0, (0.0, 0.0))
    centres = np.array([[(x0 + x1) / 2, 0.0, (z0 + z1) / 2] for x0, x1, z0, z1 in rects]) @ TO_BED.T
    one, seven = centres[centres[:, 0] < 0], centres[centres[:, 0] > 0]
    assert len(one) and len(seven)
    bar = max(rects, key=lambda r: r[1] - r[0])  # the widest rectangle: the 1's foot or the 7's bar
    foot_y = (np.array([0, 0, (bar[2] + bar[3]) / 2]) @ TO_BED.T)[1]
    seven_bar = [r for r in rects if r[0] > 0 and r[1] - r[0] > 2.0]
    assert seven_bar and (np.array([0, 0, (seven_bar[0][2] + seven_bar[0][3]) / 2]) @ TO_BED.T)[1] > 0
    assert foot_y < 0  # the 1's foot is at the bottom of the page


def test_posts_instead_of_spheres(family):
    s = family.stars[0]
    b = build_body(
        s.id, s.vertices, 4.0, load_mount("flat"), BodySpec(seat="post", post_mm=1.5, post_length_mm=2.0)
    )
    assert not [p for p in b.add if isinstance(p, Sphere)]
    posts = [p for p in b.add if isinstance(p, Cylinder) and p.radius_mm == pytest.approx(0.75)]
    assert len(posts) == 4
    for p, c in zip(posts, s.vertices, strict=True):
        # the post enters the marker at its surface and reaches post_length_mm into it
        assert np.linalg.norm(np.array(p.p0) - c) == pytest.approx(2.0 + 0.2, abs=1e-9)
        assert np.linalg.norm(np.array(p.p1) - c) == pytest.approx(0.0, abs=1e-9)


def test_fit_report_against_sorted_limit(family):
    s = family.stars[0]
    b = build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec())
    bb = body_bounds(b)
    size = bb[1] - bb[0]
    # independent: spheres' finished extents and the plate corners
    c = s.vertices
    lo = np.minimum(c.min(0) - 2.0, [p.bounds()[0] for p in b.add if isinstance(p, Box)][0])
    hi = np.maximum(c.max(0) + 2.0, [p.bounds()[1] for p in b.add if isinstance(p, Box)][0])
    assert np.allclose(size, hi - lo, atol=1e-6) or (size >= hi - lo - 1e-6).all()
    ok = fit_report(b, np.sort(size)[::-1] + 0.1)  # any axis order
    assert ok.fits and max(ok.excess_mm) == 0
    tight = np.sort(size) - np.array([0.0, 0.0, 1.5])
    bad = fit_report(b, tight[::-1])
    assert not bad.fits and bad.worst_mm == pytest.approx(1.5)
    assert "by 1.50 mm" in bad.message("star_001")


def test_body_spec_validation_names_the_parameter():
    with pytest.raises(StarforgeError, match="stem_mm must be >= the printable minimum"):
        BodySpec(stem_mm=0.5)
    with pytest.raises(StarforgeError, match="coating_mm"):
        BodySpec(coating_mm=-0.1)
    with pytest.raises(StarforgeError, match="seat"):
        BodySpec(seat="cube")


def test_parse_ids():
    assert parse_ids("1,2,5") == [1, 2, 5]
    assert parse_ids("1-3,9,2") == [1, 2, 3, 9]
    assert parse_ids(None) is None
    with pytest.raises(StarforgeError, match="ids"):
        parse_ids("1,x")


# --- mounts ----------------------------------------------------------------------------------


def test_every_kind_has_a_template_with_ranges():
    mounts = list_mounts()
    assert {m.kind for m in mounts} == set(KINDS)
    for m in mounts:
        for k, v in m.params.items():
            lo, hi = m.ranges[k]
            assert lo <= v <= hi


def test_mount_errors_name_the_problem():
    with pytest.raises(StarforgeError, match=r"known \(starforge templates mounts\): adhesive, flat, magnet, saddle, strap"):
        load_mount("nope")
    with pytest.raises(StarforgeError, match=r"hole_mm must be in \[1.0, 4.5\]"):
        load_mount("flat", {"hole_mm": 9})
    with pytest.raises(StarforgeError, match="unknown flat mount parameter"):
        load_mount("flat", {"strap_width_mm": 9})


# --- visibility ------------------------------------------------------------------------------


def test_isolated_spheres_see_their_whole_hemisphere():
    c = np.array([[0, 0, 0], [30, 0, 0], [0, 0, 30], [30, 0, 30]], float)
    b = build_body(1, c, 4.0, load_mount("flat", {"holes": 0}), BodySpec())
    vis = sphere_visibility(b)
    # only grazing rays toward a neighbour at the same height are blocked
    assert (vis > 0.99).all()
    # a lone sphere high above the rest sees everything
    high = c + np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 20.0, 0]])
    b = build_body(1, high, 4.0, load_mount("flat", {"holes": 0}), BodySpec(max_tilt_deg=0))
    assert sphere_visibility(b, directions=200)[3] == 1.0


def test_visibility_matches_mesh_ray_casts():
    """Analytic visibility vs rays cast against the body's own mesh (coating 0: mesh = finished)."""
    import trimesh

    from starforge.cad.mesh import body_mesh

    c = np.array([[0, 0, 0], [1.0, 5.0, 0.5], [8, 2, 3], [-3, 1, 12]], float)  # B hangs over A
    spec = BodySpec(coating_mm=0.0, max_tilt_deg=50)
    b = build_body(2, c, 4.0, load_mount("flat", {"holes": 0}), spec)
    vis = sphere_visibility(b, directions=300)
    assert vis[0] < 0.95  # A is shadowed by B
    mesh = body_mesh(b, 48, 24)
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    d = hemisphere_directions(300)
    for i in range(4):
        o = c[i] + (2.0 + 0.02) * d  # just outside the sphere's surface
        hit = inter.intersects_any(o, d)
        assert 1 - hit.mean() == pytest.approx(vis[i], abs=0.04)


# --- plate ------------------------------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(2, 30), st.floats(2, 30), st.floats(2, 30)), min_size=1, max_size=40))
def test_plate_layout_is_on_the_beds_without_overlaps(sizes):
    rng = np.random.default_rng(len(sizes))
    bounds = []
    for s in sizes:
        lo = rng.uniform(-10, 10, 3)
        lo[2] = 0.0  # bodies arrive in their printing orientation: on Z = 0
        bounds.append([lo, lo + np.array(s)])
    bounds = np.array(bounds)
    beds = layout_plates(bounds, (100, 100), 3.0)
    assert sorted(i for lay in beds for i in lay.members) == list(range(len(bounds)))  # each body once
    for lay in beds:
        boxes = []
        for i, T in zip(lay.members, lay.transforms, strict=True):
            assert np.allclose(T[:3, :3], np.eye(3))  # a layout only translates
            lo, hi = bounds[i, 0] + T[:3, 3], bounds[i, 1] + T[:3, 3]
            assert lo[2] == pytest.approx(0, abs=1e-9)  # standing on the bed
            assert (lo[:2] >= 3.0 - 1e-9).all() and (hi[:2] <= 100 - 3.0 + 1e-9).all()
            boxes.append((lo, hi))
        for i in range(len(boxes)):
            for j in range(i):
                (a0, a1), (b0, b1) = boxes[i], boxes[j]
                sep = np.maximum(b0[:2] - a1[:2], a0[:2] - b1[:2]).max()
                assert sep >= 3.0 - 1e-9


def test_a_body_larger_than_the_bed_is_refused():
    bounds = np.array([[[0, 0, 0], [40, 10, 40]]] * 9 + [[[0, 0, 0], [140, 10, 4]]], float)
    with pytest.raises(StarforgeError, match=r"body 10 is 140.0 x 10.0 mm, larger than the 100 x 100 mm bed"):
        layout_plates(bounds, (100, 100), 5.0)
    assert len(layout_plates(bounds[:9].repeat(3, axis=0), (100, 100), 5.0)) > 1  # 27 bodies: several beds


def test_screw_holes_clear_stems_and_label(family):
    m = load_mount("flat", {"holes": 2})
    for s in family.stars:
        b = build_body(s.id, s.vertices, 4.0, m, BodySpec())
        holes = [p for p in b.subtract if isinstance(p, Cylinder)]
        assert len(holes) == 2
        labels = [p for p in b.subtract if isinstance(p, Box)]
        for h in holes:
            hxz = np.array(h.p0)[[0, 2]]
            for stem in b.stems:
                gap = np.linalg.norm(hxz - np.array(stem.p0)[[0, 2]]) - h.radius_mm - stem.radius_mm
                assert gap >= m["hole_wall_mm"] - 1e-9
            for box in labels:
                d = np.maximum(np.abs(hxz - np.array(box.centre)[[0, 2]]) - np.array(box.size)[[0, 2]] / 2, 0)
                assert np.linalg.norm(d) >= h.radius_mm
        a, c = (np.array(h.p0)[[0, 2]] for h in holes)
        assert np.linalg.norm(a - c) >= 2 * (m["hole_mm"] / 2 + m["hole_wall_mm"]) - 1e-9


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=12, max_size=12))
def test_ray_segment_distance_is_exact(xs):
    """Against brute force: dense points on the segment, each one's exact distance to the ray."""
    from starforge.geometry.distance import ray_segment_distance

    o, d, a, b = np.array(xs).reshape(4, 3)
    if np.linalg.norm(d) < 1e-3:
        return
    d = d / np.linalg.norm(d)
    got = ray_segment_distance(o[None], d[None], a, b)[0]
    q = a + np.linspace(0, 1, 4001)[:, None] * (b - a)
    rel = q - o
    t = np.clip(rel @ d, 0, None)
    brute = np.linalg.norm(rel - t[:, None] * d, axis=1).min()
    assert got <= brute + 1e-9  # never more than a point of the segment shows
    assert got >= brute - np.linalg.norm(b - a) / 4000 - 1e-9  # nor less than the sampling allows


def test_find_spot_cost_is_bounded_on_a_large_footprint():
    """A 4 m footprint (stars may have 10 m limits) is searched on at most MAX_GRID^2 candidates:
    the spot found is clear of every circle (checked directly) and the search stays small."""
    import tracemalloc

    circles = np.array([[0.0, 0.0, 300.0], [900.0, -1500.0, 200.0], [-1200.0, 1000.0, 400.0]])
    tracemalloc.start()
    spot = find_spot((-2000.0, 2000.0, -2000.0, 2000.0), (30.0, 10.0), circles, 5.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # 0.25 mm steps would be 16000^2 candidates (GBs); MAX_GRID^2 x 3 circles x 2 floats is ~8 MB
    assert peak < 40 * MAX_GRID**2 * len(circles) * 8, peak
    assert spot is not None
    x, z = spot
    assert -2000 + 5 + 15 <= x <= 2000 - 5 - 15 and -2000 + 5 + 5 <= z <= 2000 - 5 - 5
    for cx, cz, r in circles:  # nearest point of the rectangle to the circle's centre
        dx = max(abs(cx - x) - 15.0, 0.0)
        dz = max(abs(cz - z) - 5.0, 0.0)
        assert np.hypot(dx, dz) >= r - 1e-9
