"""A scanned prop's noise: measured, smoothed away where it tilts the faces, left alone on CAD
bodies; checked against the shapes' own formulas, not the fit."""

from __future__ import annotations

import numpy as np
import pytest

from starforge.props.scan import NOISE_SHARE, median_edge, noisy, smooth_scan, surface_noise


def _sphere(radius=0.04, subdivisions=5):
    import trimesh

    return trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)


def _noisy(mesh, sigma, seed=0):
    """The mesh with every vertex moved by Gaussian noise of ``sigma`` (m) along each axis."""
    import trimesh

    rng = np.random.default_rng(seed)
    return trimesh.Trimesh(mesh.vertices + rng.normal(0.0, sigma, mesh.vertices.shape), mesh.faces, process=False)


@pytest.mark.parametrize("sigma", [5e-5, 1e-4, 2e-4])
def test_a_noisy_sphere_is_measured_and_smoothed_back_onto_the_sphere(sigma):
    clean = _sphere()
    scan = _noisy(clean, sigma)
    noise = surface_noise(scan.vertices, scan.faces)
    # the residual off a fitted surface is the noise along the normal (one of three axes),
    # less what the fit absorbs
    assert 0.5 * sigma <= noise <= 1.2 * sigma
    assert noisy(scan.vertices, scan.faces)[0] == noise
    out = smooth_scan(scan.vertices, scan.faces)
    before = np.linalg.norm(scan.vertices, axis=1) - 0.04
    after = np.linalg.norm(out, axis=1) - 0.04
    # off the true sphere: the noise cut at least threefold, the sphere neither shrunk nor grown
    assert np.sqrt(np.mean(after**2)) <= np.sqrt(np.mean(before**2)) / 3
    assert abs(float(np.mean(after))) <= 0.1 * sigma + 2e-6
    assert np.array_equal(np.asarray(scan.faces), np.asarray(scan.faces))  # the faces are kept


def test_clean_bodies_are_left_alone():
    """CAD bodies, coarse and fine, flat and curved, measure below the line and are not touched
    by the repair; a finely tessellated sphere measures its tessellation, far below it."""
    import trimesh

    from starforge.props.builtin import BUILTIN, builtin_mesh
    from starforge.props.mesh import repair_mesh

    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    v, f = box.vertices, box.faces
    for _ in range(4):
        v, f = trimesh.remesh.subdivide(v, f)
    fine_box = trimesh.Trimesh(v, f, process=False)
    bodies = [builtin_mesh(n) for n in BUILTIN] + [fine_box, _sphere(), trimesh.creation.cylinder(0.02, 0.2, sections=64)]
    for mesh in bodies:
        assert noisy(mesh.vertices, mesh.faces)[0] == 0.0
        repaired, _, notes = repair_mesh(mesh)
        assert not any("smoothed" in n for n in notes)
    sphere = _sphere()
    assert surface_noise(sphere.vertices, sphere.faces) < 0.05 * NOISE_SHARE * median_edge(sphere.vertices, sphere.faces)


def test_the_repair_smooths_a_scan_and_says_by_how_much():
    from starforge.props.mesh import repair_mesh

    scan = _noisy(_sphere(), 1e-4, seed=3)
    repaired, origin, notes = repair_mesh(scan)
    (note,) = [n for n in notes if "smoothed" in n]
    assert "scanner noise of 0.09" in note and len(repaired.faces) == len(scan.faces)
    r = np.linalg.norm(np.asarray(repaired.vertices), axis=1)
    assert np.sqrt(np.mean((r - 0.04) ** 2)) < 4e-5
    kept, _, notes = repair_mesh(scan, smooth=False)
    assert not any("smoothed" in n for n in notes)
    assert np.allclose(np.sort(np.linalg.norm(kept.vertices, axis=1)), np.sort(np.linalg.norm(scan.vertices, axis=1)))


def _sheet(n: int, z: float, up: bool):
    """A square sheet of ``n`` x ``n`` vertices 1 mm apart at height ``z`` (m), facing up or down."""
    g = np.arange(n) * 0.001 - (n - 1) * 0.0005
    x, y = np.meshgrid(g, g, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, z)])
    k = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    faces = np.vstack([np.column_stack([k, k + n, k + 1]), np.column_stack([k + 1, k + n, k + n + 1])])
    return vertices, faces if up else faces[:, ::-1]


def test_a_thin_wall_keeps_both_its_faces():
    """A scanned wall 2 mm thick, thinner than the fitting radius: each face is fitted from its
    own side (the far side faces away), so the wall keeps its thickness."""
    import trimesh

    top_v, top_f = _sheet(61, 0.001, True)
    bottom_v, bottom_f = _sheet(61, -0.001, False)
    wall = trimesh.Trimesh(np.vstack([top_v, bottom_v]), np.vstack([top_f, bottom_f + len(top_v)]), process=False)
    scan = _noisy(wall, 5e-5, seed=1)
    assert noisy(scan.vertices, scan.faces)[0] > 0
    out = smooth_scan(scan.vertices, scan.faces)
    inner = np.all(np.abs(np.asarray(scan.vertices)[:, :2]) < 0.025, axis=1)  # away from the rim
    top = np.arange(len(scan.vertices)) < len(top_v)
    for side, height in ((top, 0.001), (~top, -0.001)):
        before, after = np.asarray(scan.vertices)[inner & side, 2], out[inner & side, 2]
        assert abs(float(np.mean(after)) - height) < 1e-5
        assert np.std(after) < np.std(before) / 2.5


def test_landmarks_of_a_prop_with_corners_but_no_end_a_person_finds():
    """A ring (its ends along every axis are curves, no point of them stands out) with a cube
    in it: the cube's corners are named, and nothing fails for want of an end."""
    import trimesh

    from starforge.props.guide import mesh_landmarks

    ring = trimesh.creation.torus(major_radius=0.05, minor_radius=0.015, major_sections=128, minor_sections=64)
    mesh = trimesh.util.concatenate([ring, trimesh.creation.box(extents=(0.01, 0.01, 0.01))])
    marks = mesh_landmarks(mesh)
    assert marks and all(m["kind"] == "corner" for m in marks)
    corners = np.array([m["point"] for m in marks])
    assert np.allclose(np.abs(corners), 0.005, atol=1e-9)


def test_a_scan_file_is_smoothed_unless_told_and_each_kept_apart_in_the_cache(tmp_path, monkeypatch):
    from starforge.props.mesh import load_prop

    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(tmp_path / "cache"))
    path = tmp_path / "scan.stl"
    _noisy(_sphere(subdivisions=4), 1e-4, seed=5).export(path)
    for _ in range(2):  # computed, then read back from the cache
        smoothed, kept = load_prop(str(path)), load_prop(str(path), smooth=False)
        assert any("smoothed" in n for n in smoothed.notes) and not any("smoothed" in n for n in kept.notes)
        r_smoothed = np.linalg.norm(smoothed.vertices, axis=1) - 0.04
        r_kept = np.linalg.norm(kept.vertices, axis=1) - 0.04
        assert np.sqrt(np.mean(r_smoothed**2)) < np.sqrt(np.mean(r_kept**2)) / 2


@pytest.mark.slow
def test_a_scanned_bottle_is_placed_with_every_marker_clear_on_the_true_shape(tmp_path):
    """``starforge place`` on a bottle scanned with 0.1 mm of depth noise: refused when the
    noise is kept (no base seats), placed when it is smoothed, and every marker, moved to the
    noise-free bottle, keeps the placement error of room (brute force over its faces and edges)."""
    import json

    from benchmarks._scans import scanned_bottle
    from benchmarks.bench_props_real import margin_shortfall
    from starforge.cli import main
    from starforge.props.mesh import repair_mesh

    path = tmp_path / "scan.stl"
    scanned_bottle(1e-4).export(path)
    assert main(["place", "run", str(path), "--keep-noise", "--out", str(tmp_path / "kept"), "-q"]) == 2
    assert not (tmp_path / "kept").exists()
    assert main(["place", "run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    doc = json.loads((tmp_path / "out" / "placement.json").read_text())
    assert any("smoothed scanner noise" in n for n in doc["prop"]["repairs"])
    clean = repair_mesh(scanned_bottle(0.0), smooth=False)[0]
    points = np.array([m["position"] for m in doc["markers"]])
    on, _, face = clean.nearest.on_surface(points)
    seat = doc["seat"]
    below, rooms = margin_shortfall(clean, on, clean.face_normals[face], seat["base_mm"] / 2000, seat["placement_error_mm"] / 1000)
    assert len(points) >= 4 and below == 0, rooms
