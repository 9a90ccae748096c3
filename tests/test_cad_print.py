"""Every file is ready to print as written.

Families made for a mount (``stars --mount``) on the paper's finger limit fit with it; bodies lie
plate-down on Z = 0, the largest flat face on the bed, with no region starting in mid-air (a
layer analysis of the files themselves, itself checked on shapes with known answers); the
recorded transform takes the file back to family.json's centres; PrusaSlicer slices
representative files where it is installed (the full 5 mounts x 25 stars sweep is in
benchmarks/bench_cad.py); STEP plates are assemblies of named, coloured solids; 3MF files carry
a thumbnail; bought markers sit on seats at the designed centre; strokes suit the nozzle.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import zipfile
import zlib

import numpy as np
import pytest

from starforge.cad.body import FILLET_INSET_MM, BodySpec, build_body, fit_report, label_boxes
from starforge.cad.mounts import list_mounts, load_mount
from starforge.cad.primitives import Cylinder, Revolved
from starforge.cad.printability import flat_levels, layer_report, printable
from tests.conftest import run_cli
from tests.test_cad_backends import _sphere_centres_from_mesh

FINGER_BOX = (20.8, 12.6, 48.3)
MOUNTS = [m.name for m in list_mounts()]
#: every mount, those the other checks do not use checked by ``pytest -m slow``
MOUNT_PARAMS = [m if m == "flat" else pytest.param(m, marks=pytest.mark.slow) for m in MOUNTS]
PRUSA = shutil.which("prusa-slicer")
SLIC3R = shutil.which("slic3r")


@pytest.fixture(scope="module")
def made_for(tmp_path_factory):
    """A function: mount name -> (folder, family.json doc, bodies folder, bodies.json doc) for a
    3-star family made for that mount on the finger limit, bodies 1 and 2 exported (stl, 3mf,
    step, plate).  Built once per mount."""
    cache: dict = {}

    def make(mount: str):
        if mount not in cache:
            d = tmp_path_factory.mktemp(mount)
            args = ["stars", "--box", *FINGER_BOX, "--delta", 2, "--mount", mount, "--count", 3, "--out", d, "-q"]
            assert run_cli(args) == 0
            out = d / "bodies"
            fam = d / "family.json"
            assert run_cli(["export", fam, "--ids", "1,2", "--format", "stl,3mf,step", "--out", out, "-q"]) == 0
            cache[mount] = (d, json.loads(fam.read_text()), out, json.loads((out / "bodies.json").read_text()))
        return cache[mount]

    return make


@pytest.mark.parametrize("mount", MOUNT_PARAMS)
def test_a_family_made_for_its_mount_fits_the_finger_limit_and_exports(made_for, mount):
    _, fam, _, doc = made_for(mount)
    assert fam["spec"]["mount"] == mount and doc["mount"]["name"] == mount
    assert all(b["fits"] for b in doc["bodies"])
    # every star of the family, not just the exported ones, makes a body inside the limit
    m = load_mount(mount)
    for s in fam["stars"]:
        assert fit_report(build_body(s["id"], s["vertices"], 4.0, m, BodySpec()), fam["spec"]["box_mm"]).fits


def _downward_flat_areas(mesh) -> dict:
    """{height (0.01 mm): area of the faces looking straight down there}, from the triangles."""
    n = mesh.face_normals
    down = n[:, 2] < -0.9999
    z = np.round(mesh.triangles_center[down, 2], 2)
    out: dict = {}
    for h, a in zip(z, mesh.area_faces[down], strict=True):
        out[h] = out.get(h, 0.0) + a
    return out


@pytest.mark.parametrize("mount", MOUNT_PARAMS)
def test_bodies_lie_plate_down_and_print_without_supports(made_for, mount):
    import trimesh

    _, fam, out, doc = made_for(mount)
    by_id = {s["id"]: np.array(s["vertices"]) for s in fam["stars"]}
    for b in doc["bodies"]:
        mesh = trimesh.load(out / f"{b['name']}.stl", force="mesh")
        assert mesh.is_watertight and mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
        assert mesh.bounds[1, 2] == pytest.approx(b["print_height_mm"], abs=1e-5)
        rep = layer_report(mesh)
        assert printable(rep) == [], (b["name"], printable(rep))
        # the largest face looking down is the one on the bed
        flats = _downward_flat_areas(mesh)
        assert max(flats, key=flats.get) == 0.0
        # the recorded transform takes the file back to family.json's sphere centres
        back = np.array(b["print_to_placement"])
        fwd = np.array(b["placement_to_print"])
        assert np.allclose(back @ fwd, np.eye(4), atol=1e-9)
        assert np.allclose(back[:3, :3] @ back[:3, :3].T, np.eye(3), atol=1e-9)
        placed = mesh.copy().apply_transform(back)
        found = _sphere_centres_from_mesh(placed, by_id[b["id"]], b["printed_sphere_mm"] / 2)
        assert np.abs(found - by_id[b["id"]]).max() < 0.01
    plate = trimesh.load(out / "plate.stl", force="mesh")
    assert plate.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert layer_report(plate)["midair_islands"] == []


@pytest.mark.slow
@pytest.mark.parametrize("mount", ["saddle", "strap"])
def test_redesigned_mounts_stand_on_flat_ground(made_for, mount):
    """The saddle prints on two flat rails beside its channel, the strap on its tunnel's floor."""
    import trimesh

    _, _, out, doc = made_for(mount)
    mesh = trimesh.load(out / f"{doc['bodies'][0]['name']}.stl", force="mesh")
    rep = layer_report(mesh)
    p = doc["mount"]["params"]
    length = mesh.extents[1]  # the star's long side lies along the bed's Y
    if mount == "saddle":
        # two rails of land_mm each, along the whole plate: at least that much contact
        assert rep["first_layer_mm2"] >= 0.95 * 2 * p["land_mm"] * length
        assert rep["bridge_mm2"] > 0 or rep["overhang_mm2"] > 0  # the channel's vault
    else:
        # the floor is a full rectangle; the tunnel's roof steps in at 45 deg to a bridge of at most
        # 5 mm (less the 45 deg reach of one layer each side; 0.1 mm grid)
        from starforge.cad.mounts import PRINTABLE_BRIDGE_MM, strap_roof

        assert rep["first_layer_mm2"] >= 0.95 * mesh.extents[0] * length
        n, step = strap_roof(p)
        ceiling = p["strap_width_mm"] + 0.5 - 2 * n * step
        assert ceiling <= PRINTABLE_BRIDGE_MM + 1e-9
        assert rep["max_bridge_mm"] == pytest.approx(ceiling - 2 * 0.2, abs=0.2)


def test_step_and_mesh_agree_and_the_plate_is_a_named_coloured_assembly(made_for):
    import build123d as bd

    from starforge.cad.brep import read_step

    for mount in ("flat", "saddle"):
        _, _, out, doc = made_for(mount)
        for b in doc["bodies"]:
            assert b["mesh_volume_mm3"] == pytest.approx(b["step_volume_mm3"], rel=1e-4)  # within 0.01 %
        plate = bd.import_step(str(out / "plate.step"))
        assert sorted(c.label for c in plate.children) == sorted(b["name"] for b in doc["bodies"])
        assert all(c.color is not None for c in plate.children)
        assert len(read_step(out / "plate.step")) == len(doc["bodies"])
        single = bd.import_step(str(out / f"{doc['bodies'][0]['name']}.step"))
        solid = single.solids()[0]
        assert solid.bounding_box().min.Z == pytest.approx(0.0, abs=1e-6)  # the STEP lies on the bed too


def _png_rgba(data: bytes) -> np.ndarray:
    """Decode an 8-bit RGBA, non-interlaced PNG with filter 0 rows (what starforge writes)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat = 8, b""
    w = h = 0
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        assert zlib.crc32(kind + body) == struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])[0]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (8, 6)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 4 * w)
    assert (raw[:, 0] == 0).all()
    return raw[:, 1:].reshape(h, w, 4)


def test_3mf_carries_a_thumbnail_of_the_body_and_colours(made_for):
    _, _, out, doc = made_for("flat")
    for name in (doc["bodies"][0]["name"], "plate"):
        z = zipfile.ZipFile(out / f"{name}.3mf")
        img = _png_rgba(z.read("Metadata/thumbnail.png"))
        assert img.shape == (256, 256, 4)
        covered = img[:, :, 3] > 0
        assert 0.1 < covered.mean() < 0.9  # the body fills the picture, with background around it
        assert "metadata/thumbnail" in z.read("_rels/.rels").decode()
        assert "displaycolor=" in z.read("3D/3dmodel.model").decode()


def test_thumbnail_silhouette_matches_the_projected_hull():
    """A convex body's silhouette is the hull of its projected vertices: compare pixel coverage."""
    import trimesh
    from shapely.geometry import MultiPoint

    from starforge.cad.raster import rasterize, view_rotation

    box = trimesh.creation.box((30, 10, 5))
    img = rasterize(box.vertices, box.faces, size_px=200, supersample=4)
    q = box.vertices @ view_rotation().T
    hull = MultiPoint(q[:, [0, 2]].tolist()).convex_hull
    lo, hi = q[:, [0, 2]].min(0), q[:, [0, 2]].max(0)
    px_per_mm = (200 * 4 - 4) / 4 / (hi - lo).max()
    expected = hull.area * px_per_mm**2
    got = img[:, :, 3].astype(float).sum() / 255
    assert got == pytest.approx(expected, rel=0.02)


@pytest.mark.skipif(PRUSA is None, reason="PrusaSlicer is not installed here")
@pytest.mark.parametrize(("mount", "name"), [pytest.param("saddle", "star_001.stl", marks=pytest.mark.slow),
     pytest.param("strap", "star_002.3mf", marks=pytest.mark.slow), ("flat", "plate.3mf")])
def test_prusaslicer_slices_the_files_as_written(made_for, tmp_path, mount, name):
    """The slicer that must slice the file: no error, and the sliced height is the body's."""
    _, _, out, doc = made_for(mount)
    g = tmp_path / "out.gcode"
    res = subprocess.run(
        [PRUSA, "--export-gcode", str(out / name), "--layer-height", "0.2", "--first-layer-height", "0.2",
         "--output", str(g)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert res.returncode == 0 and g.exists(), res.stdout[-2000:] + res.stderr[-2000:]
    zs = [float(m) for m in re.findall(r"^;Z:([0-9.]+)", g.read_text(), flags=re.M)]
    height = max(b["print_height_mm"] for b in doc["bodies"])
    if name.startswith("star_"):
        height = next(b["print_height_mm"] for b in doc["bodies"] if name.startswith(b["name"]))
    assert zs[0] == pytest.approx(0.2, abs=1e-6)
    assert abs(max(zs) - height) <= 0.2  # within one layer: the body lies flat, as written


#: star 17 of the 25-star finger family made for the flat mount (``stars --count 25 --mount
#: flat``), and where the plate put it: with the fillet flush with its stems, this one body
#: alone at this spot made Slic3r 1.3 fail 12 loops ("Unable to close this loop")
FLAT17 = [
    [2.39394319, 2.380913243, 0.0],
    [-5.342627944, -2.380913243, 8.586062871],
    [5.342627944, -2.38091324, 17.631797037],
    [-5.342627944, 2.380913243, 35.670652743],
]
FLAT17_ON_PLATE = (127.024, 58.3)


def _slic3r_warnings(path, tmp_path, *extra) -> list[str]:
    """Slic3r 1.3's complaints slicing ``path`` at 0.2 mm layers (slices only, as SVG; run in
    ``tmp_path``, where Slic3r unpacks a 3MF's model)."""
    res = subprocess.run(
        [SLIC3R, str(path), "--layer-height", "0.2", "--first-layer-height", "0.2", "--nozzle-diameter", "0.4",
         *extra, "--export-svg", "-o", str(tmp_path / "slices.svg")],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=tmp_path,
    )
    assert res.returncode == 0 and (tmp_path / "slices.svg").exists(), res.stdout[-2000:] + res.stderr[-2000:]
    return [ln.strip() for ln in (res.stdout + res.stderr).splitlines() if re.search(r"warn|unable|error", ln, re.I)]


@pytest.mark.skipif(SLIC3R is None, reason="Slic3r is not installed here (Debian: apt-get install slic3r)")
def test_slic3r_closes_every_loop_of_a_body_where_the_plate_puts_it(tmp_path):
    from starforge.cad.mesh import body_mesh
    from starforge.cad.plate import print_transform

    mesh = body_mesh(build_body(17, FLAT17, 4.0, load_mount("flat"), BodySpec()))
    mesh.apply_transform(print_transform(mesh.bounds))
    mesh.apply_translation([FLAT17_ON_PLATE[0] - mesh.bounds[0, 0], FLAT17_ON_PLATE[1] - mesh.bounds[0, 1], 0.0])
    mesh.export(tmp_path / "star_017.stl")
    assert _slic3r_warnings(tmp_path / "star_017.stl", tmp_path) == []


@pytest.mark.skipif(SLIC3R is None, reason="Slic3r is not installed here (Debian: apt-get install slic3r)")
def test_slic3r_slices_a_plate_without_a_warning(made_for, tmp_path):
    _, _, out, _ = made_for("flat")
    assert _slic3r_warnings(out / "plate.stl", tmp_path) == []


@pytest.mark.skipif(SLIC3R is None, reason="Slic3r is not installed here (Debian: apt-get install slic3r)")
@pytest.mark.parametrize("name", ["star_001.3mf", "plate.3mf"])
def test_slic3r_keeps_a_3mf_where_it_lies_and_finds_it_on_the_bed(made_for, tmp_path, name):
    """Slic3r arranging nothing (--dont-arrange) takes the 3MF's own places: a single body at the
    bed centre, a plate as laid out; neither overflows its 200 mm bed ("might not fit")."""
    _, _, out, _ = made_for("flat")
    assert _slic3r_warnings(out / name, tmp_path, "--dont-arrange") == []


@pytest.mark.parametrize("marker", ["4mm-flat", "6.4mm-post", "9.5mm-m3", "12.7mm-m3", "14mm-m4"])
def test_bought_markers_sit_on_seats_at_the_designed_centre(marker):
    from starforge.cad.mesh import body_mesh
    from starforge.markers import load_marker

    mt = load_marker(marker)
    d = mt.diameter_mm
    # a spread-out star for this marker size
    c = np.array([[0, 0, 0], [4.0 * d, 0.5 * d, 0], [0, 0.3 * d, 4.5 * d], [4.2 * d, 0.9 * d, 4.0 * d]])
    b = build_body(1, c, d, load_mount("flat", {"holes": 0}), BodySpec(marker=marker, label=False))
    assert b.printed_mm is None
    for k, centre in enumerate(c):
        stem = b.stems[k]
        u = (centre - np.array(stem.p0)) / np.linalg.norm(centre - np.array(stem.p0))
        seat = centre - mt.centre_height_mm * u
        # the seat (shoulder, pad or boss top) ends exactly at the marker's base plane
        tops = [p for p in b.add if isinstance(p, Cylinder | Revolved) and np.allclose(p.p1, seat, atol=1e-9)]
        assert tops, f"no seat at the base plane of marker {k}"
        top_r = tops[0].radius_mm if isinstance(tops[0], Cylinder) else tops[0].profile[-1][1]
        if mt.attach in ("screw", "insert"):
            holes = [
                p for p in b.subtract if isinstance(p, Cylinder) and np.linalg.norm(np.array(p.p1) - seat) < 1.0
            ]
            assert holes and all(h.radius_mm * 2 < top_r * 2 - 2.0 for h in holes)
    assert body_mesh(b).is_watertight


def test_catalogue_marker_must_match_the_family():
    from starforge.errors import StarforgeError

    c = np.array([[0, 0, 0], [20, 2, 0], [0, 1, 22], [21, 4, 20]], float)
    with pytest.raises(StarforgeError, match="designed for 4 mm markers"):
        build_body(1, c, 4.0, load_mount("flat"), BodySpec(marker="9.5mm-m3"))


@pytest.mark.parametrize("nozzle", [0.25, 0.4, 0.6, 0.8])
def test_engraved_strokes_suit_the_nozzle(nozzle):
    spec = BodySpec(nozzle_mm=nozzle)
    h = spec.label_height()
    boxes = label_boxes("18", h, (0.0, 0.0), 0.0, spec.label_depth_mm)
    widths = [min(b.size[0], b.size[2]) for b in boxes]
    assert min(widths) >= 2.0 * nozzle - 1e-9


def test_stems_scale_with_the_marker_and_have_a_fillet_at_the_root():
    spec = BodySpec()
    assert spec.stem_for(4.0) == pytest.approx(1.8) and spec.stem_for(9.5) == pytest.approx(4.0)
    c = np.array([[0, 0, 0], [20, 2, 0], [0, 1, 22], [21, 4, 20]], float)
    b = build_body(1, c, 4.0, load_mount("flat"), spec)
    fillets = [p for p in b.add if isinstance(p, Revolved)]
    assert len(fillets) == 4
    rs, f = spec.stem_for(4.0) / 2, spec.fillet_for(4.0)
    plate_top = min(s.p0[1] for s in b.stems) + 0.3
    for fl, stem in zip(fillets, b.stems, strict=True):
        assert np.allclose(fl.axis, [0, 1, 0])  # about the plate's normal, through the stem's root
        u = np.subtract(stem.p1, stem.p0) / stem.length_mm
        root = np.array(stem.p0) + u * (0.3 / u[1])
        assert np.allclose(np.array(fl.p0) + [0, 0.3, 0], root)
        prof = np.array(fl.profile)
        # the arc ends FILLET_INSET_MM inside the stem, plus the tilt's shift of the stem's axis
        tan = np.sqrt(1 - u[1] ** 2) / u[1]
        inset = f * tan + FILLET_INSET_MM
        assert prof[0, 1] == pytest.approx(rs + f - inset) and prof[-1, 1] == pytest.approx(rs - inset)
        # the arc: every facet corner on the circle of radius f round (plate + f, rs + f - inset)
        t0 = fl.p0[1]
        arc = prof[1:]
        centre = np.array([plate_top - t0 + f, rs + f - inset])
        assert np.allclose(np.linalg.norm(arc - centre, axis=1), f)
        assert (np.diff(arc[:, 1]) < 0).all()  # narrowing upward: nothing overhangs
        assert fl.volume() > np.pi * rs**2 * (prof[-1, 0] - prof[0, 0])  # it adds material round the stem


def _fillet_top_ring_inside_stem(fl, stem, samples: int = 72) -> float:
    """Least distance (mm) from the fillet's top ring (profile's last point, revolved) in to
    the stem's surface: > 0 when the ring lies strictly inside the stem."""
    from starforge.geometry.distance import point_segment_distance

    t, r = fl.profile[-1]
    a = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    top = np.array(fl.p0) + t * np.array(fl.axis)
    ring = top + r * np.column_stack([np.cos(a), np.zeros_like(a), np.sin(a)])
    return float(stem.radius_mm - point_segment_distance(ring, stem.p0, stem.p1).max())


@pytest.mark.parametrize("mount", MOUNTS)
def test_no_flat_level_is_made_of_slivers(mount):
    """No horizontal sliver triangles where two tessellations of a stem's circle disagree (a
    root fillet's flat end flush with its stem would leave them at the fillet's top, where a
    slicer's layer plane cannot close its loops): every flat level of the mesh as written
    (float32) is a face somebody designed, at least one extrusion squared, and every fillet's
    top ring lies inside its stem (tilted ones included), checked with exact segment distances."""
    from starforge.cad.mesh import body_mesh
    from starforge.cad.plate import print_transform
    from starforge.cad.printability import flat_levels

    spec = BodySpec()
    # stem 1 has to lean (sphere 0 sits right above its root), the others stand upright
    c = np.array([[0, 6, 0], [2.5, 0, 1.0], [14, 1, 2], [3, 2, 18]], float)
    b = build_body(7, c, 4.0, load_mount(mount), spec)
    tilts = [np.degrees(np.arccos(np.subtract(s.p1, s.p0)[1] / s.length_mm)) for s in b.stems]
    assert max(tilts) > 5 and min(tilts) < 1e-6
    mesh = body_mesh(b)
    mesh.apply_transform(print_transform(mesh.bounds))
    levels = flat_levels(mesh.vertices, mesh.faces)
    assert levels and levels[0][0] == pytest.approx(0.0, abs=1e-6)
    thin = [(round(z, 4), a) for z, a, _ in levels if a < spec.nozzle_mm**2]
    assert thin == []
    fillets = [p for p in b.add if isinstance(p, Revolved)]
    for fl, stem in zip(fillets, b.stems, strict=True):
        assert _fillet_top_ring_inside_stem(fl, stem) >= FILLET_INSET_MM - 1e-6


def test_flat_levels_finds_the_faces_of_a_box_and_a_sliver():
    import trimesh

    box = trimesh.creation.box((4.0, 3.0, 2.0))
    levels = flat_levels(box.vertices, box.faces)
    assert [(round(z, 6), round(a, 6), n) for z, a, n in levels] == [(-1.0, 12.0, 2), (1.0, 12.0, 2)]
    # a flat sliver 1e-4 mm wide, 1 mm long, at z = 0.5: found as its own level of 5e-5 mm^2
    v = np.vstack([box.vertices, [[0, 0, 0.5], [1, 0, 0.5], [0.5, 1e-4, 0.5]]])
    f = np.vstack([box.faces, [[8, 9, 10]]])
    levels = flat_levels(v, f)
    assert [round(z, 6) for z, _, _ in levels] == [-1.0, 0.5, 1.0]
    assert levels[1][1] == pytest.approx(5e-5, rel=1e-3) and levels[1][2] == 1


def test_strap_and_saddle_room_is_what_their_geometry_needs():
    from starforge.cad.reserve import mount_reserve_mm

    spec = BodySpec()
    flat = mount_reserve_mm("flat", 4.0, spec)
    strap = load_mount("strap")
    r = mount_reserve_mm(strap, 4.0, spec)
    # the tunnel adds roof, its 45 deg steps, strap and floor under the star, and nothing to the sides
    from starforge.cad.mounts import strap_roof

    n, step = strap_roof(strap.params)
    assert n * step > 0  # the default 5 mm strap's 5.5 mm tunnel needs one step to a 5 mm bridge
    assert r[0] == pytest.approx(
        spec.standoff_mm + strap["thickness_mm"] + strap["slot_mm"] + n * step + strap["floor_mm"]
    )
    assert r[1:] == flat[1:]


# --- the layer analysis on shapes whose answers are known -------------------------------------


def _on_bed(*parts):
    import trimesh

    m = trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]
    return m


def _box(size, centre):
    import trimesh

    return trimesh.creation.box(size, trimesh.transformations.translation_matrix(centre))


def test_layer_analysis_of_a_block_on_the_bed():
    rep = layer_report(_box((20, 10, 4), (0, 0, 2)))
    assert rep["layers"] == 20 and rep["height_mm"] == pytest.approx(4)
    assert rep["first_layer_mm2"] == pytest.approx(200)
    assert rep["midair_islands"] == [] and rep["overhang_mm2"] == 0 and rep["bridge_mm2"] == 0
    assert rep["com_margin_mm"] == pytest.approx(5) and printable(rep) == []


def test_layer_analysis_finds_a_part_that_starts_in_mid_air():
    rep = layer_report(_on_bed(_box((10, 10, 2), (0, 0, 1)), _box((4, 4, 2), (20, 0, 3))))
    assert len(rep["midair_islands"]) == 1
    i = rep["midair_islands"][0]
    assert i["z_mm"] == pytest.approx(2.1) and i["area_mm2"] == pytest.approx(16)
    assert any("mid-air" in p for p in printable(rep))


def test_layer_analysis_tells_a_bridge_from_an_overhang():
    import trimesh

    # an arch: two pillars 8 mm apart under a 2 mm roof: the roof's first layer is a bridge
    arch = trimesh.boolean.union(
        [_box((3, 10, 4), (-5.5, 0, 2)), _box((3, 10, 4), (5.5, 0, 2)), _box((14, 10, 2), (0, 0, 5))],
        engine="manifold",
    )
    rep = layer_report(arch)
    assert rep["midair_islands"] == []
    assert rep["max_bridge_mm"] == pytest.approx(8 - 2 * 0.2, abs=0.2)  # sampled on a 0.1 mm grid
    assert rep["bridge_mm2"] == pytest.approx((8 - 0.4) * 10, rel=1e-6) and rep["overhang_mm2"] == 0
    # a shelf held on one side only: an overhang of its width less one layer's reach
    shelf = trimesh.boolean.union([_box((3, 10, 6), (0, 0, 3)), _box((5, 10, 1), (4, 0, 5.5))], engine="manifold")
    rep = layer_report(shelf)
    assert rep["bridge_mm2"] == 0 and rep["overhang_mm2"] == pytest.approx((6.5 - 1.5 - 0.2) * 10, rel=1e-6)
    assert printable(rep) == []  # reported, not refused
    # a wider bridge than a printer spans is refused
    wide = trimesh.boolean.union(
        [_box((3, 10, 4), (-11, 0, 2)), _box((3, 10, 4), (11, 0, 2)), _box((25, 10, 2), (0, 0, 5))],
        engine="manifold",
    )
    assert any("bridge spans" in p for p in printable(layer_report(wide)))


def test_layer_analysis_refuses_a_body_that_would_tip_over():
    import trimesh

    # a heavy block over a small foot at one end: its centre of mass is outside the contact
    leaning = trimesh.boolean.union(
        [_box((2, 2, 3), (0, 0, 1.5)), _box((30, 6, 6), (14, 0, 6))], engine="manifold"
    )
    rep = layer_report(leaning)
    assert not rep["com_over_contact"] and rep["first_layer_mm2"] == pytest.approx(4)
    problems = printable(rep)
    assert any("bed contact" in p for p in problems) and any("centre of mass" in p for p in problems)
