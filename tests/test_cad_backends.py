"""Both backends build the same body: STEP (OpenCascade) and STL/3MF (manifold3d).

Files are written under tmp_path and reloaded with build123d / trimesh; volumes, validity,
single-solid-ness and the sphere centres are measured on the reloaded files.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from starforge.cad.body import BodySpec, build_body
from starforge.cad.mounts import list_mounts, load_mount
from starforge.stars.model import load_family

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"


@pytest.fixture(scope="module")
def family():
    return load_family(DATA)


def _fit_sphere(points: np.ndarray):
    """Least-squares sphere through points: (centre (3,), radius)."""
    A = np.column_stack([2 * points, np.ones(len(points))])
    b = (points**2).sum(1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    return c, float(np.sqrt(sol[3] + c @ c))


def _sphere_centres_from_mesh(mesh, centres, r_printed):
    """Fit a sphere to the mesh vertices on each printed sphere (away from its stem)."""
    v = np.asarray(mesh.vertices)
    out = []
    for c in centres:
        d = np.linalg.norm(v - c, axis=1)
        near = v[(d > 0.97 * r_printed) & (d < 1.03 * r_printed)]
        # drop the stem junction: vertices below the sphere's equator that sit on the stem
        near = near[near[:, 1] > c[1] - 0.5 * r_printed]
        assert len(near) > 50
        fc, fr = _fit_sphere(near)
        out.append(fc)
    return np.array(out)


def _solid_sphere_centres(solid):
    """Centres of the spherical faces of a build123d solid (from the surface definitions)."""
    import build123d as bd

    out = [tuple(f.axis_of_rotation.position) for f in solid.faces() if f.geom_type == bd.GeomType.SPHERE]
    return np.unique(np.round(np.array(out), 9), axis=0)


def load_3mf(path):
    """{object name: trimesh} of a 3MF file: trimesh's reader (needs lxml), else a stdlib parse."""
    import importlib.util
    import xml.etree.ElementTree as ET
    import zipfile

    import trimesh

    if importlib.util.find_spec("lxml") is not None:
        scene = trimesh.load(path)
        return dict(scene.geometry)
    ns = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
    root = ET.fromstring(zipfile.ZipFile(path).read("3D/3dmodel.model"))
    out = {}
    for obj in root.iter(f"{ns}object"):
        v = [[float(e.get(k)) for k in "xyz"] for e in obj.iter(f"{ns}vertex")]
        f = [[int(e.get(k)) for k in ("v1", "v2", "v3")] for e in obj.iter(f"{ns}triangle")]
        out[obj.get("name")] = trimesh.Trimesh(v, f, process=True)
    return out


def _extreme_params(m):
    """Mount overrides at the low and the high ends of every range."""
    lo = {k: r[0] for k, r in m.ranges.items()}
    hi = {k: r[1] for k, r in m.ranges.items()}
    return {"lo": lo, "hi": hi}


CASES = [(m.name, which) for m in list_mounts() for which in ("default", "lo", "hi")]


@pytest.mark.parametrize(("mount_name", "which"), CASES)
def test_every_mount_builds_in_both_backends(family, mount_name, which):
    from starforge.cad.brep import body_solid
    from starforge.cad.mesh import body_mesh

    m = load_mount(mount_name)
    if which != "default":
        params = _extreme_params(m)[which]
        if m.kind == "saddle" and which == "lo":
            params["segment_mm"] = 30.0  # a 10 mm segment cannot carry a 15 mm wide star: see below
        m = load_mount(mount_name, params)
    s = family.stars[2]
    spec = BodySpec(label_depth_mm=0.4)
    b = build_body(s.id, s.vertices, 4.0, m, spec)
    mesh = body_mesh(b, spec.sphere_segments, spec.cylinder_segments)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.is_volume
    assert mesh.body_count == 1
    assert (mesh.area_faces > 1e-10).all()  # no degenerate triangles
    solid = body_solid(b)
    assert solid.is_valid
    assert mesh.volume == pytest.approx(solid.volume, rel=0.01)
    # the sphere centres the STEP solid carries are family.json's
    centres = _solid_sphere_centres(solid)
    assert len(centres) == 4
    for c in s.vertices:
        assert np.linalg.norm(centres - c, axis=1).min() < 0.01


def test_saddle_channel_wider_than_the_segment_is_refused(family):
    from starforge.errors import StarforgeError

    s = family.stars[2]
    with pytest.raises(StarforgeError, match="channel_mm 12 must be < segment_mm 10"):
        build_body(s.id, s.vertices, 4.0, load_mount("saddle", {"segment_mm": 10}), BodySpec())


def test_step_file_reimports_as_one_valid_named_solid(family, tmp_path):
    from starforge.cad.brep import body_solid, read_step, write_step

    for s in family.stars[:2]:
        b = build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec())
        solid = body_solid(b)
        path = tmp_path / f"{b.name}.step"
        write_step(solid, path)
        back = read_step(path)
        assert len(back) == 1
        assert back[0].is_valid
        assert back[0].volume == pytest.approx(solid.volume, rel=1e-6)
        # expected volume, independently: printed spheres + stems + plate - cuts, within 1 %
        approx = sum(p.volume() for p in b.add)
        assert back[0].volume < approx  # overlaps and cuts only remove volume
        assert f"'{b.name}'" in path.read_text(errors="replace")  # product name


def test_stl_and_3mf_reload_watertight_with_centres(family, tmp_path):
    import trimesh

    from starforge.cad.mesh import body_mesh
    from starforge.cad.threemf import threemf_bytes

    for s in family.stars[:3]:
        b = build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec())
        mesh = body_mesh(b)
        (tmp_path / "a.stl").write_bytes(mesh.export(file_type="stl"))
        (tmp_path / "a.3mf").write_bytes(threemf_bytes([mesh], [b.name]))
        stl = trimesh.load(tmp_path / "a.stl", force="mesh")
        objects = load_3mf(tmp_path / "a.3mf")
        assert list(objects) == [b.name]
        tmf = objects[b.name]
        for m in (stl, tmf):
            assert m.is_watertight and m.is_volume and m.body_count == 1
            assert m.volume == pytest.approx(mesh.volume, rel=1e-5)
            got = _sphere_centres_from_mesh(m, s.vertices, b.printed_mm / 2)
            assert np.abs(got - s.vertices).max() < 0.01


def test_posts_build_in_both_backends(family):
    from starforge.cad.brep import body_solid
    from starforge.cad.mesh import body_mesh

    s = family.stars[0]
    b = build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec(seat="post"))
    mesh = body_mesh(b)
    solid = body_solid(b)
    assert mesh.is_watertight and mesh.body_count == 1 and solid.is_valid
    assert mesh.volume == pytest.approx(solid.volume, rel=0.01)
    # each post's tip (its flat end's centre) is the marker centre: the end's rim is centred on it
    v = np.asarray(mesh.vertices)
    for c in s.vertices:
        rim = v[np.linalg.norm(v - c, axis=1) < 0.9]
        assert len(rim) >= 16
        assert np.linalg.norm(rim.mean(axis=0) - c) < 0.01


@pytest.mark.parametrize("tip", ["sphere"])
def test_volumes_agree_for_every_star(family, tip):
    from starforge.cad.brep import body_solid
    from starforge.cad.mesh import body_mesh

    for s, name in itertools.product(family.stars, ["magnet"]):
        b = build_body(s.id, s.vertices, 4.0, load_mount(name), BodySpec(seat=tip))
        assert body_mesh(b).volume == pytest.approx(body_solid(b).volume, rel=0.01)


def test_volume_matches_closed_form_for_a_simple_body():
    """Isolated vertical stems, no hole, no label: plate + spheres + the stems' free parts."""
    from starforge.cad.brep import body_solid
    from starforge.cad.mesh import body_mesh
    from starforge.cad.primitives import Box

    c = np.array([[0, 0, 0], [20, 3, 0], [0, 1, 25], [20, 5, 25]], float)
    spec = BodySpec(label=False, fillet_mm=0.0)
    b = build_body(9, c, 4.0, load_mount("flat", {"holes": 0}), spec)
    plate = [p for p in b.add if isinstance(p, Box)][0]
    y_top = plate.bounds()[1, 1]
    R, a = (4.0 - spec.coating_mm) / 2, spec.stem_for(4.0) / 2
    inside_sphere = 2 * np.pi / 3 * (R**3 - (R**2 - a**2) ** 1.5)  # stem ending at the centre
    expected = plate.volume() + sum(
        4 / 3 * np.pi * R**3 + np.pi * a**2 * (ci[1] - y_top) - inside_sphere for ci in c
    )
    assert body_solid(b).volume == pytest.approx(expected, rel=1e-6)
    assert body_mesh(b).volume == pytest.approx(expected, rel=1e-3)
