"""Placement on a finely tessellated mesh: the exact surface distance, the one-shell repair, the
simplified drawing, and a placement whose markers sit on the surface on valid seats."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from starforge.props.builtin import builtin_mesh
from starforge.props.mesh import repair_mesh, signed_volume
from starforge.props.surface import surface_distance
from starforge.render.prop_views import DRAWN_FACES, drawn_faces


def _fine(name: str = "hammer", times: int = 4) -> trimesh.Trimesh:
    """A built-in prop with every face split into 4**times (the same surface, finely tessellated)."""
    m = builtin_mesh(name)
    v, f = m.vertices, m.faces
    for _ in range(times):
        v, f = trimesh.remesh.subdivide(v, f)
    return trimesh.Trimesh(v, f, process=False)


def _brute_distance(mesh, points) -> np.ndarray:
    """Distance from each point to the closest point of every face, the least of them."""
    tri = np.asarray(mesh.triangles)
    out = []
    for p in points:
        q = np.repeat(p[None], len(tri), axis=0)
        out.append(np.linalg.norm(trimesh.triangles.closest_point(tri, q) - q, axis=1).min())
    return np.array(out)


@pytest.mark.parametrize("name,times", [("hammer", 0), ("hammer", 2), ("racket", 1)])
def test_surface_distance_is_the_brute_force_minimum(name, times):
    mesh = _fine(name, times)
    lo, hi = mesh.bounds
    rng = np.random.default_rng(3)
    pts = rng.uniform(lo - 0.02, hi + 0.02, (60, 3))
    pts[:20] = mesh.vertices[rng.choice(len(mesh.vertices), 20)]  # on the surface: 0
    d = surface_distance(mesh, pts)
    brute = _brute_distance(mesh, pts)
    np.testing.assert_allclose(d, brute, rtol=0, atol=1e-12)
    assert np.all(d[:20] <= 1e-12)
    reach = float(np.median(brute[20:]))  # up to a reach: exact within it, inf past it
    near = surface_distance(mesh, pts, reach)
    np.testing.assert_allclose(near[brute <= reach], brute[brute <= reach], rtol=0, atol=1e-12)
    assert np.isinf(near[brute > reach]).all() and (brute > reach).any()


def test_surface_distance_with_faces_of_very_different_sizes():
    # a fine sphere beside one large triangle: the groups by size each find their own nearest faces
    ball = trimesh.creation.icosphere(4, radius=0.02)
    big = trimesh.Trimesh([[0.1, -0.5, -0.5], [0.1, 0.5, -0.5], [0.1, 0.0, 0.5]], [[0, 1, 2]], process=False)
    mesh = trimesh.util.concatenate([ball, big])
    pts = np.random.default_rng(5).uniform(-0.05, 0.15, (80, 3))
    np.testing.assert_allclose(surface_distance(mesh, pts), _brute_distance(mesh, pts), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["hammer", "racket", "bottle"])
def test_signed_volume_is_the_enclosed_volume(name):
    mesh = builtin_mesh(name)
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    assert signed_volume(box) == pytest.approx(0.1 * 0.2 * 0.3, rel=1e-12)
    assert signed_volume(mesh) == pytest.approx(mesh.volume, rel=1e-9)  # trimesh's mass properties
    flipped = trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)
    assert signed_volume(flipped) == pytest.approx(-mesh.volume, rel=1e-9)


def test_one_shell_repair_turns_an_inside_out_mesh_outward():
    mesh = _fine("hammer", 2)
    inside_out = trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)
    assert inside_out.volume < 0
    fixed, origin, notes = repair_mesh(inside_out)
    assert fixed.volume > 0 and fixed.is_watertight and fixed.is_winding_consistent
    assert any("flipped" in n for n in notes)
    np.testing.assert_array_equal(origin, np.arange(len(mesh.faces)))
    again, _, notes = repair_mesh(fixed)  # an outward mesh is left as it is
    np.testing.assert_array_equal(again.faces, fixed.faces)
    assert not any("flipped" in n for n in notes)


def test_a_fine_mesh_is_drawn_closed_and_small():
    mesh = _fine("hammer", 4)  # 36k faces: above the drawing limit
    tris, normals = drawn_faces(mesh.vertices, mesh.faces)
    assert 0 < len(tris) <= DRAWN_FACES
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    lo, hi = mesh.bounds
    pts = tris.reshape(-1, 3)
    assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)
    # every drawn corner lies near the surface (within a grid cell), and the area is close
    cell = float(np.ptp(mesh.vertices, axis=0).max()) / np.sqrt(DRAWN_FACES)
    assert surface_distance(mesh, pts[::7]).max() <= cell
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum()
    assert area == pytest.approx(mesh.area, rel=0.1)
    # the drawn normals face the same way as the surface beneath them
    nearest = mesh.nearest.on_surface(tris.mean(axis=1))[2]
    agree = np.einsum("ij,ij->i", normals, mesh.face_normals[nearest]) > 0
    assert agree.mean() > 0.95
    small = _fine("hammer", 0)  # at or under the limit: the faces as they are
    t, n = drawn_faces(small.vertices, small.faces)
    np.testing.assert_array_equal(t, small.triangles)
    np.testing.assert_allclose(n, small.face_normals, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_placement_on_a_fine_mesh_sits_on_the_surface_on_valid_seats(tmp_path):
    from starforge.props.placement import run_placement

    path = tmp_path / "fine.stl"
    _fine("hammer", 4).export(path)
    res = run_placement(str(path), sites=200, resolution=1, orientations=8)
    mesh = res.prop.mesh
    pts = np.asarray(res.marker_points)
    assert len(pts) >= 4
    idx = list(res.marker_sites)
    # on the surface: each lies in the plane of the face it was drawn on and inside it (its
    # barycentric coordinates there are >= 0), recomputed from the face's corners (trimesh's
    # closest-point query misjudges faces a fraction of a millimetre across in metres)
    tri = np.asarray(mesh.triangles)[np.asarray(res.sites.faces)[idx]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", pts - tri[:, 0], n)).max() < 1e-12
    area = lambda a, b, c: np.einsum("ij,ij->i", np.cross(b - a, c - a), n)  # noqa: E731
    whole = area(tri[:, 0], tri[:, 1], tri[:, 2])
    parts = [area(pts, tri[:, 1], tri[:, 2]), area(tri[:, 0], pts, tri[:, 2]), area(tri[:, 0], tri[:, 1], pts)]
    assert all((w / whole >= -1e-9).all() for w in parts)
    assert np.all(np.asarray(res.seat_report.ok)[idx])
    # the ball clears the surface: re-measured by brute force over every face
    need = min(res.seat.ball_radius_m, res.seat.centre_height_m) - res.spec.seat.clearance_tol_mm / 1000.0
    assert _brute_distance(mesh, res.centres()).min() >= need - 1e-12
    normals = np.asarray(res.marker_normals)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)


def test_layouts_evaluated_together_score_as_each_alone():
    # the evaluation looks at the layouts' shared markers once: every layout's figures are the
    # ones it gets evaluated on its own, on the same poses and losses
    from starforge.props.evaluate import camera_hits, evaluate_layouts, random_poses
    from starforge.props.rig import load_rig
    from starforge.props.spec import EvalSettings

    mesh = builtin_mesh("hammer")
    rng = np.random.default_rng(2)
    faces = rng.choice(len(mesh.faces), 9, replace=False)
    c, n = mesh.triangles_center[faces] + 0.005 * mesh.face_normals[faces], mesh.face_normals[faces]
    layouts = {"a": (c[:5], n[:5]), "b": (c[3:8], n[3:8]), "c": (c[[0, 8, 4, 2]], n[[0, 8, 4, 2]])}
    rig = load_rig("default")
    pivot = mesh.bounds.mean(axis=0)
    settings = EvalSettings(poses=60)
    together = evaluate_layouts(mesh, layouts, rig, pivot, settings, 7, 15.0)
    for name, lay in layouts.items():
        alone = evaluate_layouts(mesh, {name: lay}, rig, pivot, settings, 7, 15.0)
        assert alone[name] == {k: v for k, v in together[name].items() if k in alone[name]}
    # and each marker's hits are its own, whatever else is looked at with it
    poses = random_poses(rig.volume, 20, pivot, np.random.default_rng(1))
    both = camera_hits(mesh, c, n, rig, poses)
    for i in (0, 4, 8):
        np.testing.assert_array_equal(both[:, i], camera_hits(mesh, c[i : i + 1], n[i : i + 1], rig, poses)[:, 0])
