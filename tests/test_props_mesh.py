"""Prop loading and repair, built-in props, candidate sites and constrained areas."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starforge.errors import StarforgeError
from starforge.props.builtin import BUILTIN, builtin_mesh
from starforge.props.mesh import load_prop
from starforge.props.sites import BoxRegion, Constraints, SphereRegion, forbidden_sites, sample_sites


def _messy(path):
    """Two overlapping boxes (one inside out), a sphere with a hole, duplicate and degenerate faces."""
    import trimesh

    a = trimesh.creation.box(extents=(0.2, 0.1, 0.1))
    b = trimesh.creation.box(extents=(0.1, 0.1, 0.3))
    b.apply_translation((0.05, 0, 0.1))
    b.invert()
    c = trimesh.creation.icosphere(2, 0.03)
    c.apply_translation((0.3, 0, 0))
    c = trimesh.Trimesh(c.vertices, c.faces[1:], process=False)
    m = trimesh.util.concatenate([a, b, c])
    m = trimesh.Trimesh(m.vertices, np.vstack([m.faces, m.faces[:3], [[0, 0, 1]]]), process=False)
    m.export(path)
    return path


def test_messy_mesh_is_repaired_and_reported(tmp_path):
    p = load_prop(str(_messy(tmp_path / "messy.stl")))
    text = " ".join(p.notes)
    for word in ("degenerate", "flipped", "filled", "united"):
        assert word in text
    m = p.mesh
    assert m.is_watertight and m.volume > 0
    # union volume by hand: 0.002 + 0.003 - 0.001 overlap, plus the sphere
    sphere = 4 / 3 * np.pi * 0.03**3
    assert m.volume == pytest.approx(0.004 + sphere, rel=0.03)
    # outward normals: a point just outside every face along its normal is outside the solid
    probe = m.triangles_center + 1e-4 * m.face_normals
    assert not m.contains(probe).any()
    # no candidate site is buried inside the other box
    sites = sample_sites(m, 300, np.random.default_rng(0))
    inner = np.all(
        (sites.points > [0.0 + 1e-4, -0.05 + 1e-4, -0.05 + 1e-4])
        & (sites.points < [0.1 - 1e-4, 0.05 - 1e-4, 0.05 - 1e-4]),
        axis=1,
    )
    assert not inner.any()


def test_units_scale_the_mesh(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(200.0, 100.0, 50.0)).export(tmp_path / "box_mm.ply")
    p = load_prop(str(tmp_path / "box_mm.ply"), units="mm")
    assert np.allclose(sorted(p.extents_m), [0.05, 0.1, 0.2])
    with pytest.raises(StarforgeError, match="units must be one of"):
        load_prop(str(tmp_path / "box_mm.ply"), units="inch")


@pytest.mark.parametrize(
    "content, match",
    [
        (None, "not found"),
        (b"", "empty"),
        (b"solid x\nfacet normal garbage\n", "cannot read|no triangles"),
        (b"\x00\x01\x02" * 40, "cannot read|no triangles"),
    ],
)
def test_bad_mesh_files(tmp_path, content, match):
    path = tmp_path / "bad.stl"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(StarforgeError, match=match):
        load_prop(str(path))


def test_unknown_prop_lists_builtins():
    with pytest.raises(StarforgeError, match="built-ins: hammer"):
        load_prop("teapot")


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_props_are_realistic_solids(name):
    m = builtin_mesh(name)
    assert m.is_watertight and m.volume > 0
    assert 0.1 < max(m.extents) < 1.2  # handheld, metres
    assert len(m.split(only_watertight=False)) == 1


def test_sites_are_poisson_disk_on_the_surface():
    from scipy.spatial import cKDTree

    m = builtin_mesh("bottle")
    s = sample_sites(m, 500, np.random.default_rng(2))
    assert len(s) == 500
    d, _ = cKDTree(s.points).query(s.points, k=2)
    assert d[:, 1].min() >= s.radius_m * (1 - 1e-9) and s.radius_m > 0
    _, dist, tri = m.nearest.on_surface(s.points)
    assert dist.max() < 1e-9
    assert np.allclose(np.linalg.norm(s.normals, axis=1), 1)
    assert np.allclose(np.einsum("ij,ij->i", s.normals, m.face_normals[s.faces]), 1)
    t = sample_sites(m, 500, np.random.default_rng(2))
    assert np.array_equal(s.points, t.points)


def test_constrained_areas(tmp_path):
    import trimesh

    m = builtin_mesh("box")  # 0.4 x 0.3 x 0.25, base at z = 0
    s = sample_sites(m, 400, np.random.default_rng(0))
    top = Constraints(boxes=(BoxRegion((-1, -1, 0.249), (1, 1, 1)),))
    bad = forbidden_sites(s, top)
    assert np.array_equal(bad, s.points[:, 2] > 0.249)
    ball = Constraints(spheres=(SphereRegion((0.2, 0.15, 0.25), 0.1),))
    assert np.array_equal(
        forbidden_sites(s, ball), np.linalg.norm(s.points - [0.2, 0.15, 0.25], axis=1) <= 0.1
    )
    # a second mesh: a slab through the bottom 5 cm
    slab = trimesh.creation.box(extents=(1, 1, 0.1))
    slab.export(tmp_path / "slab.stl")
    in_slab = forbidden_sites(s, Constraints(mesh=str(tmp_path / "slab.stl"), mesh_margin_m=0.0))
    assert np.array_equal(in_slab, s.points[:, 2] <= 0.05 + 1e-9)
    # per-face mask: forbid the two faces of the +x side of the box
    mask = (m.face_normals[:, 0] > 0.5).astype(int)
    (tmp_path / "mask.txt").write_text("\n".join(map(str, mask)))
    got = forbidden_sites(
        s, Constraints(mask=str(tmp_path / "mask.txt")), np.arange(len(m.faces)), len(m.faces)
    )
    assert np.array_equal(got, s.normals[:, 0] > 0.5)
    (tmp_path / "short.txt").write_text("1 0 1")
    with pytest.raises(StarforgeError, match="has 3 values, the prop has 12 faces"):
        forbidden_sites(s, Constraints(mask=str(tmp_path / "short.txt")), np.arange(12), 12)
    for bad in ("nan", "inf"):  # a mask of the right length with a value that is no 0 or 1
        (tmp_path / "bad.txt").write_text("\n".join([bad, *map(str, mask[1:])]))
        with pytest.raises(StarforgeError, match=r"bad.txt has a value that is not a finite number; give --mask"):
            forbidden_sites(s, Constraints(mask=str(tmp_path / "bad.txt")), np.arange(12), 12)


def test_open_shell_with_inward_normals_is_turned_outward():
    import trimesh

    from starforge.props.mesh import repair_mesh

    b = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    keep = ~((b.face_normals[:, 2] > 0.5) | (b.face_normals[:, 0] > 0.5))  # open top and +x side
    inward = trimesh.Trimesh(b.vertices, b.faces[keep][:, ::-1], process=False)
    m, _, notes = repair_mesh(inward)
    assert any("inside out" in n for n in notes)
    # every remaining face of a box centred at the origin faces away from the centre
    assert np.all(np.einsum("ij,ij->i", m.face_normals, m.triangles_center) > 0)
    outward = trimesh.Trimesh(b.vertices, b.faces[keep], process=False)
    m2, _, notes2 = repair_mesh(outward)
    assert not any("inside out" in n for n in notes2)
    assert np.all(np.einsum("ij,ij->i", m2.face_normals, m2.triangles_center) > 0)


def test_dart_throw_is_the_greedy_brute_force():
    """The compiled greedy keeps exactly what a plain O(n^2) pass keeps: visit the points in
    order, keep one unless a kept one lies within the radius; stop at the limit."""
    from starforge.props.sites import _dart_throw

    rng = np.random.default_rng(7)
    for n, radius, limit in ((300, 0.08, 1000), (300, 0.08, 40), (200, 0.0, 50), (5, 10.0, 3)):
        pts = rng.random((n, 3))
        kept: list[int] = []
        for i in range(n):
            if all(np.linalg.norm(pts[i] - pts[j]) > radius for j in kept):
                kept.append(i)
                if len(kept) >= limit:
                    break
        assert _dart_throw(pts, radius, limit).tolist() == kept


def test_a_prop_is_kept_as_arrays_and_its_mesh_built_on_first_use(tmp_path, monkeypatch):
    import pickle

    from starforge.props import builtin
    from starforge.props.mesh import PropMesh

    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(tmp_path / "cache"))
    want = builtin_mesh("hammer")
    first = load_prop("hammer")  # built, and kept in the empty cache folder
    monkeypatch.setattr(builtin, "builtin_mesh", lambda name: pytest.fail("built again"))
    for prop in (first, load_prop("hammer")):  # the second is read back
        assert "mesh" not in prop.__dict__
        assert np.array_equal(prop.vertices, want.vertices) and np.array_equal(prop.faces, want.faces)
        np.testing.assert_array_equal(prop.bounds_m, want.bounds)
        np.testing.assert_array_equal(prop.extents_m, want.extents)
        m = prop.mesh
        assert np.array_equal(m.vertices, want.vertices) and np.array_equal(m.faces, want.faces)
        assert m.is_watertight and m.volume == pytest.approx(want.volume, rel=1e-12)
    # a pickled prop carries its arrays, not the mesh built of them
    again = pickle.loads(pickle.dumps(first))
    assert "mesh" not in again.__dict__ and np.array_equal(again.mesh.faces, want.faces)
    # a mesh given is kept as it is, with what trimesh computed of it
    held = PropMesh.of(want, "h", "x.stl", "m", np.arange(len(want.faces)))
    assert held.mesh is want and np.array_equal(held.vertices, want.vertices)
    # the box the faces span: a vertex no face uses is left out, as trimesh leaves it out
    import trimesh

    stray = trimesh.Trimesh(np.vstack([want.vertices, [[5.0, 5.0, 5.0]]]), want.faces, process=False)
    np.testing.assert_array_equal(PropMesh.of(stray, "s", "x.stl", "m", np.arange(len(want.faces))).bounds_m, want.bounds)


def test_a_repaired_mesh_file_is_read_back_from_the_cache_until_the_file_changes(tmp_path, monkeypatch):
    from starforge.props import mesh as pm

    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(tmp_path / "cache"))
    path = _messy(tmp_path / "messy.stl")
    computed = load_prop(str(path))
    assert computed.notes and "mesh" in computed.__dict__  # computed: the repaired mesh is kept
    calls = []
    real = pm.repair_mesh
    monkeypatch.setattr(pm, "repair_mesh", lambda raw, **kw: calls.append(1) or real(raw, **kw))
    read = load_prop(str(path))
    assert calls == [] and "mesh" not in read.__dict__
    assert np.array_equal(read.vertices, computed.vertices) and np.array_equal(read.faces, computed.faces)
    assert read.faces.dtype == computed.faces.dtype == np.int64
    assert np.array_equal(read.face_origin, computed.face_origin) and read.face_origin.dtype == np.int64
    assert (read.notes, read.source_faces, read.name, read.source) == (computed.notes, computed.source_faces, computed.name, computed.source)
    assert read.mesh.is_watertight and read.mesh.volume == pytest.approx(computed.mesh.volume, rel=1e-12)
    load_prop(str(path), units="mm")  # other units: computed again
    assert calls == [1]
    import trimesh

    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(path)  # the file changes
    assert len(load_prop(str(path)).faces) == 12 and calls == [1, 1]
    monkeypatch.setattr(pm, "KEEP_BYTES", 10)  # a file larger than this is repaired on every run
    load_prop(str(path))
    load_prop(str(path))
    assert calls == [1, 1, 1, 1]
    path.write_bytes(b"solid x\nnot a mesh\n")  # a broken file is refused every time, never kept
    for _ in range(2):
        with pytest.raises(StarforgeError):
            load_prop(str(path))


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 60),
    seed=st.integers(0, 2**31 - 1),
    scale=st.sampled_from([1e-3, 0.3, 40.0, 900.0]),
)
def test_merged_vertices_are_trimeshs_bit_for_bit(n, seed, scale):
    """Exact copies, copies off by less than the merge's rounding and by more, vertices no face
    uses, at a prop's size and at the largest accepted: the arrays equal trimesh's own merge."""
    import trimesh

    from starforge.props.mesh import merge_vertices

    rng = np.random.default_rng(seed)
    base = (rng.random((n, 3)) - 0.5) * scale
    picks = rng.integers(0, n, 3 * n)
    jitter = rng.choice([0.0, 1e-10, 3e-9, 2e-8, 1e-6], size=(3 * n, 3))
    v = np.vstack([base, base[picks] + jitter * rng.choice([-1.0, 1.0], size=(3 * n, 3))])
    f = rng.integers(0, len(v), (2 * n, 3))
    got_v, got_f = merge_vertices(v, f)
    m = trimesh.Trimesh(v.copy(), f.copy(), process=False)
    m.merge_vertices()
    assert np.array_equal(got_v, m.vertices) and np.array_equal(got_f, m.faces)
    assert got_f.dtype == np.asarray(m.faces).dtype
