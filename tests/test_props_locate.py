"""The guide's landmark readings, checked by solving them as a technician's numbers would be
solved: brute force over a dense sample of the surface, with readings drawn from the tape model
(:mod:`benchmarks._locate`)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks._locate import solved_offsets
from starforge.props.builtin import builtin_mesh
from starforge.props.guide import landmarks, locating_errors, mesh_guide, mesh_landmarks, surface_sample


@pytest.mark.parametrize("seed", [4, *(pytest.param(s, marks=pytest.mark.slow) for s in (11, 23))])
def test_the_stated_locating_error_is_what_solving_noisy_readings_gives(seed):
    mesh = builtin_mesh("hammer")
    feats = mesh_landmarks(mesh)
    lp_all = np.array([f["point"] for f in feats])
    name = {f["name"]: i for i, f in enumerate(feats)}
    rng = np.random.default_rng(seed)
    face = rng.choice(len(mesh.faces), 6, replace=False, p=mesh.area_faces / mesh.area)
    pts = mesh.triangles_center[face]
    normals = mesh.face_normals[face]
    marks = landmarks(mesh_guide(mesh), pts, normals, face)
    surface = surface_sample(mesh)
    checked = 0
    for p, n, m in zip(pts, normals, marks, strict=True):
        chosen = [name[x["name"]] for x in m["measure_from"]]
        stated = m["locating_error_mm"]
        assert stated is not None and stated > 0
        if stated > 8.0 or len(chosen) != 3:  # beyond a patch's worth; or set off one by eye
            continue
        off = solved_offsets(mesh, p, n, lp_all[chosen], rng)
        # 95 % of the solutions land within the stated error (150 of them: 0.88 is 4 standard
        # deviations below), and it is not far beyond where they land
        assert np.mean(off <= stated) >= 0.88, (m["text"], np.percentile(off, 95))
        assert np.percentile(off, 95) >= 0.6 * stated, (m["text"], np.percentile(off, 95))
        checked += 1
        # the nearest three landmarks locate it no tighter than the chosen three (the chosen are
        # the best of every triple)
        near = np.argsort(np.linalg.norm(lp_all - p, axis=1), kind="stable")[:3]
        assert locating_errors(p, n, lp_all, [near], surface)[0] >= stated - 0.005  # (stated: rounded)
    assert checked >= 3


def test_a_mark_the_readings_cannot_place_within_the_margin_is_sent_to_the_drawings():
    mesh = builtin_mesh("hammer")
    feats = mesh_landmarks(mesh)
    lp = np.array([f["point"] for f in feats])
    # the handle's end face: every landmark but the end's own lies along the normal
    lo = mesh.bounds[0]
    end = np.flatnonzero((mesh.face_normals[:, 2] < -0.99) & (mesh.triangles_center[:, 2] < lo[2] + 1e-4))
    f = end[:1]
    p, n = mesh.triangles_center[f], mesh.face_normals[f]
    m = landmarks(mesh_guide(mesh), p, n, f, placement_error_mm=2.0)[0]
    assert m["locating_error_mm"] > 2.0 and "place it by the drawings" in m["text"]
    assert landmarks(mesh_guide(mesh), p, n, f)[0]["text"].count("drawings") == 0  # no margin given: none said
    # the error grows without bound as the three directions fall in one line
    e = locating_errors(np.zeros(3), np.array([0, 0, 1.0]), np.array([[0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0.0]]), [[0, 1, 2]])
    assert np.isinf(e[0])
    assert len(lp) >= 3


@pytest.mark.slow
def test_where_the_nearest_landmarks_locate_a_mark_poorly_the_chosen_ones_do_better_solved():
    """Where the model says the nearest three landmarks are much worse than the chosen three
    (at the ends of the hammer's head, they lie nearly in one line with the mark), solving
    noisy readings by brute force says so too."""
    mesh = builtin_mesh("hammer")
    feats = mesh_landmarks(mesh)
    lp = np.array([f["point"] for f in feats])
    name = {f["name"]: i for i, f in enumerate(feats)}
    surface = surface_sample(mesh)
    rng = np.random.default_rng(7)
    face = rng.choice(len(mesh.faces), 60, replace=False, p=mesh.area_faces / mesh.area)
    marks = landmarks(mesh_guide(mesh), mesh.triangles_center[face], mesh.face_normals[face], face)
    compared = 0
    for f, m in zip(face, marks, strict=True):
        p, n = mesh.triangles_center[f], mesh.face_normals[f]
        near = np.argsort(np.linalg.norm(lp - p, axis=1), kind="stable")[:3]
        poor = locating_errors(p, n, lp, [near], surface)[0]
        if m["locating_error_mm"] > 8.0 or poor < 1.5 * m["locating_error_mm"] or len(m["measure_from"]) != 3:
            continue
        chosen = [name[x["name"]] for x in m["measure_from"]]
        assert np.percentile(solved_offsets(mesh, p, n, lp[near], rng), 95) > np.percentile(
            solved_offsets(mesh, p, n, lp[chosen], rng), 95
        ), m["text"]
        compared += 1
        if compared == 3:
            break
    assert compared >= 1


def test_a_mark_next_to_a_landmark_is_set_off_it_in_a_direction():
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
    feats = mesh_landmarks(box)
    # 2 mm from the middle of the +z face, towards +x: nearer than any three readings place it
    p = np.array([[0.002, 0.0, 0.02]])
    face = box.nearest.on_surface(p)[2]
    m = landmarks(mesh_guide(box), p, np.array([[0.0, 0, 1]]), face, placement_error_mm=2.0)[0]
    (only,) = m["measure_from"]
    middle = [f for f in feats if f["name"] == only["name"]][0]
    assert np.allclose(middle["point"], [0, 0, 0.02]) and only["distance_mm"] == 2.0 and only["towards"] == "+x"
    # 95 % within sqrt(5.99) x the larger of the reading's error (0.5 mm + 0.5 %) and 2 mm x sin(15 deg)
    want = np.sqrt(-2 * np.log(0.05)) * max(0.51, 2 * np.sin(np.radians(15)))
    assert m["locating_error_mm"] == pytest.approx(want, abs=0.01)
    assert f"2.0 mm from {only['name']} towards +x (to {want:.1f} mm)" in m["text"]


def test_a_heading_read_back_is_the_direction_to_half_a_degree():
    """The direction a mark is set off in, as printed, read back by a parser of its own: within
    half a degree of the true one for directions in an axis plane (and the nearest axis named);
    the components where a direction leaves that plane."""
    import re

    from starforge.props.guide import heading

    unit = {f"{s}{a}": (1.0 if s == "+" else -1.0) * np.eye(3)[i] for i, a in enumerate("xyz") for s in "+-"}
    rng = np.random.default_rng(5)
    for _ in range(300):
        a, b = rng.choice(3, 2, replace=False)
        t = rng.uniform(0, 2 * np.pi)
        v = np.cos(t) * np.eye(3)[a] + np.sin(t) * np.eye(3)[b]
        text = heading(v * rng.uniform(0.001, 0.3))
        m = re.fullmatch(r"([+-][xyz])(?: turned (\d+) deg to ([+-][xyz]))?", text)
        assert m, text
        main = unit[m.group(1)]
        got = main if m.group(2) is None else np.cos(np.radians(int(m.group(2)))) * main + np.sin(np.radians(int(m.group(2)))) * unit[m.group(3)]
        assert np.degrees(np.arccos(np.clip(got @ v, -1, 1))) <= 0.5 + 1e-9, (v, text)
        assert np.argmax(np.abs(v)) == np.argmax(np.abs(main))
    assert heading(np.array([0.41, -0.91, 0.0])) == "-y turned 24 deg to +x"
    assert heading(np.array([0.5, 0.5, 0.7071])).startswith("(")


def test_the_guide_read_back_from_the_cache_is_the_one_computed(tmp_path, monkeypatch):
    from starforge.props import guide
    from starforge.props.mesh import load_prop

    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(tmp_path / "cache"))
    want = mesh_guide(builtin_mesh("hammer"))
    prop = load_prop("hammer")
    computed = guide.prop_guide(prop)
    monkeypatch.setattr(guide, "mesh_guide", lambda mesh: pytest.fail("computed again"))
    for got in (computed, guide.prop_guide(load_prop("hammer"))):
        assert got.landmarks == want.landmarks
        np.testing.assert_array_equal(got.bounds, want.bounds)
        np.testing.assert_array_equal(got.flat.rank, want.flat.rank)
        assert got.flat.facing == want.flat.facing
        np.testing.assert_array_equal(got.flat.area_mm2, want.flat.area_mm2)
        np.testing.assert_array_equal(got.surface.points, want.surface.points)
        np.testing.assert_array_equal(got.surface.normals, want.surface.normals)
    # every face of a named flat face reads it back; the hammer's named faces are its box head's
    # six sides and its handle's end, the 32-sided handle's strips are curved
    m = builtin_mesh("hammer")
    named = np.flatnonzero(want.flat.rank > 0)
    assert want.flat.rank.max() == len(want.flat.facing) == 7
    assert all(want.flat.of(int(f))["id"] == f"F{want.flat.rank[f]}" for f in named)
    assert want.flat.of(int(np.flatnonzero(want.flat.rank == 0)[0])) is None
    assert np.all(np.abs(m.face_normals[named]).max(axis=1) > 0.999)  # each faces along an axis
