"""What the export does faster must give the same result: a vertical stem with its root fillet
as one solid of revolution (merge_coaxial), an engraving's boxes as one prism (brep.cut_tools), the
STL written from arrays (stl.stl_bytes), the mesh volume without trimesh (mesh.mesh_volume)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from starforge.cad.body import BodySpec, build_body
from starforge.cad.mounts import load_mount
from starforge.cad.primitives import Box, Cylinder, Revolved, fillet_profile, merge_coaxial
from starforge.stars.model import load_family

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"


def _inside(p, pts) -> np.ndarray:
    """Brute-force membership of points (n, 3) in a Cylinder or a Revolved."""
    p0, p1 = np.array(p.p0), np.array(p.p1)
    L = np.linalg.norm(p1 - p0)
    u = (p1 - p0) / L
    t = (pts - p0) @ u
    r = np.linalg.norm(pts - p0 - t[:, None] * u, axis=1)
    if isinstance(p, Cylinder):
        return (t >= 0) & (t <= L) & (r <= p.radius_mm)
    prof = np.array(p.profile)
    lim = np.interp(t, prof[:, 0], prof[:, 1], left=-1.0, right=-1.0)
    return (t >= prof[0, 0]) & (t <= prof[-1, 0]) & (r <= lim)


@pytest.mark.parametrize("inset", [0.0, 0.05, 0.3])
def test_a_vertical_stem_and_its_fillet_merge_into_the_same_solid(inset):
    root = np.array([1.0, 2.0, 3.0])
    stem = Cylinder(root - [0, 0.3, 0], root + [0, 6.0, 0], 0.9)
    fillet = Revolved(root - [0, 0.3, 0], root + [0, 0.45, 0], fillet_profile(0.9, 0.45, 0.3, inset_mm=inset))
    tilted = Cylinder(root - [0.1, 0.3, 0], root + [2.0, 6.0, 0], 0.9)
    merged = merge_coaxial([stem, fillet, tilted])
    assert len(merged) == 2 and isinstance(merged[0], Revolved) and merged[1] == tilted
    rng = np.random.default_rng(1)
    pts = root + rng.uniform([-2, -0.5, -2], [2, 6.5, 2], size=(200_000, 3))
    union = _inside(stem, pts) | _inside(fillet, pts)
    assert (_inside(merged[0], pts) == union).all()
    # a fillet whose axis does not match stays apart
    assert len(merge_coaxial([tilted, fillet])) == 2


def test_each_vertical_stem_of_a_family_merges_with_its_fillet():
    from starforge.cad.body import body_bounds

    fam = load_family(DATA)
    for s in fam.stars:
        b = build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec())
        merged = merge_coaxial(b.add)
        vertical = sum(
            abs(np.subtract(st.p1, st.p0)[1] / st.length_mm - 1.0) <= 1e-12 for st in b.stems
        )
        assert len(b.add) - len(merged) == vertical
        bb = np.array([p.bounds() for p in merged])
        assert np.allclose([bb[:, 0].min(0), bb[:, 1].max(0)], body_bounds(b, finished=False), atol=1e-12)


@pytest.mark.parametrize("mount", ["flat", "strap", "adhesive"])
def test_the_engraving_prism_is_the_union_of_its_boxes(mount):
    """The plate cut by the prisms against the plate cut box by box."""
    from starforge.cad.brep import cut_tools, primitive_solid

    s = load_family(DATA).stars[0]
    b = build_body(s.id, s.vertices, 4.0, load_mount(mount), BodySpec(label_mm=4.0))
    plate = primitive_solid([p for p in b.add if isinstance(p, Box)][0])
    one_by_one = plate.cut(*(primitive_solid(c) for c in b.subtract))
    cuts = cut_tools(b.subtract)
    assert len(cuts) < len(b.subtract)  # the id's boxes became fewer tools
    as_prisms = plate.cut(*(c for c, _ in cuts))
    assert as_prisms.is_valid
    assert as_prisms.volume == pytest.approx(one_by_one.volume, rel=1e-12, abs=1e-9)
    for solid, bounds in cuts:  # the bounds the cut is sorted by hold the solid
        box = solid.bounding_box()
        assert (np.array(tuple(box.min)) >= bounds[0] - 1e-6).all()
        assert (np.array(tuple(box.max)) <= bounds[1] + 1e-6).all()


def test_stl_from_arrays_reloads_as_the_mesh_with_its_volume(tmp_path):
    import trimesh

    from starforge.cad.mesh import body_arrays, mesh_volume
    from starforge.meshfiles import face_normals, stl_bytes

    s = load_family(DATA).stars[1]
    v, f = body_arrays(build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec()))
    (tmp_path / "a.stl").write_bytes(stl_bytes(v, f))
    back = trimesh.load(tmp_path / "a.stl", force="mesh")
    assert back.is_watertight and back.is_volume and len(back.faces) == len(f)
    ref = trimesh.Trimesh(v, f, process=False)
    assert mesh_volume(v, f) == pytest.approx(ref.volume, rel=1e-12)
    assert back.volume == pytest.approx(ref.volume, rel=1e-6)  # float32 corners
    raw = np.frombuffer((tmp_path / "a.stl").read_bytes()[84:], dtype=np.uint8).reshape(-1, 50)
    normals = raw[:, :12].copy().view("<f4").reshape(-1, 3)
    assert np.allclose(normals, ref.face_normals, atol=1e-6)
    assert np.allclose(face_normals(v, f), ref.face_normals, atol=1e-12)
