"""``starforge export`` / ``mounts`` / ``preview``: files, reloads, one-line errors, nothing half-written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from starforge.cli import main

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"


NS_3MF = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"


def _model_3mf(path):
    """The root element of a 3MF file's model, parsed with zipfile + ElementTree (independent of
    any 3MF library)."""
    import xml.etree.ElementTree as ET
    import zipfile

    return ET.fromstring(zipfile.ZipFile(path).read("3D/3dmodel.model"))


def _read_3mf_stdlib(path):
    """{object name: trimesh} of a 3MF file (:func:`_model_3mf`)."""
    import trimesh

    ns = NS_3MF
    root = _model_3mf(path)
    assert root.get("unit") == "millimeter"
    out = {}
    for obj in root.iter(f"{ns}object"):
        v = [[float(e.get(k)) for k in "xyz"] for e in obj.iter(f"{ns}vertex")]
        f = [[int(e.get(k)) for k in ("v1", "v2", "v3")] for e in obj.iter(f"{ns}triangle")]
        out[obj.get("name")] = trimesh.Trimesh(v, f, process=True)
    return out


def _run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def fam(tmp_path):
    folder = tmp_path / "small"
    folder.mkdir()
    shutil.copy(DATA, folder / "family.json")
    return folder / "family.json"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """One full export of stars 1 and 3 (step, stl, 3mf, plate, preview), shared by the checks."""
    folder = tmp_path_factory.mktemp("cli") / "small"
    folder.mkdir()
    shutil.copy(DATA, folder / "family.json")
    code = main(
        ["export", str(folder / "family.json"), "--ids", "1,3", "--preview", "--bed", "120x120", "-q"]
    )
    assert code == 0
    return folder / "bodies"


def test_export_writes_one_file_per_star_per_format(exported):
    names = sorted(p.name for p in exported.iterdir() if p.is_file())
    for sid in (1, 3):
        for ext in ("step", "stl", "3mf"):
            assert f"star_{sid:03d}.{ext}" in names
    assert {"plate.stl", "plate.3mf", "bodies.json"} <= set(names)
    assert (exported / "preview" / "star_001.png").stat().st_size > 1000
    assert (exported / "preview" / "sheet.png").stat().st_size > 1000
    assert not list(exported.parent.glob(".*staging"))  # no leftovers


def test_exported_files_reload_with_centres(exported):
    import trimesh

    from starforge.cad.brep import read_step
    from starforge.stars.model import load_family

    fam = load_family(exported.parent / "family.json")
    doc = json.loads((exported / "bodies.json").read_text())
    assert [b["id"] for b in doc["bodies"]] == [1, 3]
    for entry, star in zip(doc["bodies"], fam.by_id([1, 3]), strict=True):
        stl = trimesh.load(exported / f"{entry['name']}.stl", force="mesh")
        assert stl.is_watertight and stl.body_count == 1
        step = read_step(exported / f"{entry['name']}.step")
        assert len(step) == 1 and step[0].is_valid
        assert stl.volume == pytest.approx(step[0].volume, rel=0.01)
        # the file lies in its printing orientation: plate down on Z = 0
        assert stl.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
        assert entry["print_height_mm"] == pytest.approx(stl.bounds[1, 2], abs=1e-6)
        T = np.array(entry["placement_to_print"])
        assert np.allclose(np.linalg.inv(T), entry["print_to_placement"], atol=1e-8)
        # printed sphere surface: every family centre, carried into the printing orientation,
        # has mesh vertices at the printed radius
        v = np.asarray(stl.vertices)
        r = entry["printed_sphere_mm"] / 2
        for c in star.vertices @ T[:3, :3].T + T[:3, 3]:
            d = np.linalg.norm(v - c, axis=1)
            shell = d[(d > 0.5 * r) & (d < 1.5 * r)]
            assert len(shell) > 50 and np.abs(np.median(shell) - r) < 0.01
        assert len(entry["visibility"]) == 4 and all(0 <= x <= 1 for x in entry["visibility"])


def _box(shape) -> np.ndarray:
    """(2, 3) bounding box of a build123d shape, mm."""
    b = shape.bounding_box()
    return np.array([tuple(b.min), tuple(b.max)])


def test_each_step_file_is_its_mesh_named_and_coloured(exported):
    """Each body's STEP file, read back, against its STL file and bodies.json: one valid solid
    named after the body in the body's colour, the volume the worker reported, the STL's volume
    within the mesh's chord error, and the STL's box within a sphere segment's sagitta along and
    across the segments (the mesh's vertices lie within that of the exact surfaces); the plate's STEP holds the
    same solids moved by its bed translations."""
    import build123d as bd
    import trimesh

    from starforge.cad.body import BodySpec

    doc = json.loads((exported / "bodies.json").read_text())
    r_max = max(e["printed_sphere_mm"] for e in doc["bodies"]) / 2
    sagitta = r_max * (1 - np.cos(np.pi / BodySpec().sphere_segments))
    singles = {}
    for entry in doc["bodies"]:
        step = bd.import_step(str(exported / f"{entry['name']}.step"))
        assert step.label == entry["name"] and len(step.solids()) == 1 and step.solids()[0].is_valid
        assert np.allclose(tuple(step.color)[:3], np.array(entry["colour_rgb"]) / 255, atol=0.5 / 255)
        assert step.volume == pytest.approx(entry["step_volume_mm3"], rel=1e-6)
        stl = trimesh.load(exported / f"{entry['name']}.stl", force="mesh")
        assert stl.is_watertight and stl.body_count == 1
        assert stl.volume == pytest.approx(step.volume, rel=1e-3)
        box = _box(step)
        assert np.abs(box - stl.bounds).max() <= 2 * sagitta + 1e-4
        singles[entry["name"]] = (step.volume, box)
    (plate_doc,) = doc["plates"]
    plate = bd.import_step(str(exported / "plate.step"))
    children = {c.label: c for c in plate.children}
    assert sorted(children) == sorted(plate_doc["bodies"])
    for name, T in zip(plate_doc["bodies"], plate_doc["print_to_bed"], strict=True):
        volume, box = singles[name]
        assert children[name].volume == pytest.approx(volume, rel=1e-9)
        assert np.abs(_box(children[name]) - (box + np.array(T)[:3, 3])).max() < 1e-3


def _build_items(path):
    """[(object name, 3x4 build transform)] of a 3MF file (:func:`_model_3mf`)."""
    ns = NS_3MF
    root = _model_3mf(path)
    names = {o.get("id"): o.get("name") for o in root.iter(f"{ns}object")}
    out = []
    for item in root.iter(f"{ns}item"):
        m = np.array([float(x) for x in item.get("transform", "1 0 0 0 1 0 0 0 1 0 0 0").split()]).reshape(4, 3)
        out.append((names[item.get("objectid")], m))
    return out


def test_a_single_body_3mf_lies_at_the_bed_centre(exported):
    """A slicer that keeps a 3MF's places (Slic3r --dont-arrange) finds each single body in the
    middle of the export's bed: its build item translates the printing-frame vertices, which stay
    those of the body's STL."""
    import trimesh

    doc = json.loads((exported / "bodies.json").read_text())
    assert doc["bed_mm"] == [120.0, 120.0]
    for entry in doc["bodies"]:
        (name, m), = _build_items(exported / f"{entry['name']}.3mf")
        assert name == entry["name"] and np.array_equal(m[:3], np.eye(3))
        obj = _read_3mf_stdlib(exported / f"{entry['name']}.3mf")[name]
        stl = trimesh.load(exported / f"{entry['name']}.stl", force="mesh")
        assert np.allclose(obj.bounds, stl.bounds, atol=1e-4)  # object coordinates: the printing frame
        assert np.allclose(m[3], entry["print_to_3mf_build_mm"], atol=1e-6)
        lo, hi = obj.bounds + m[3]
        assert lo[2] == pytest.approx(0.0, abs=1e-6)
        assert np.allclose((lo[:2] + hi[:2]) / 2, [60.0, 60.0], atol=1e-4)
        assert (lo[:2] >= 0).all() and (hi[:2] <= 120).all()


def test_plate_holds_every_body_on_the_bed(exported):
    import trimesh

    objects = _read_3mf_stdlib(exported / "plate.3mf")
    assert sorted(objects) == ["star_001", "star_003"]
    assert all(np.array_equal(m, np.eye(4, 3)) for _, m in _build_items(exported / "plate.3mf"))  # placed in its vertices
    assert all(o.is_watertight for o in objects.values())
    plate = trimesh.load(exported / "plate.stl", force="mesh")
    assert plate.body_count == 2 and plate.is_watertight
    lo, hi = plate.bounds
    assert lo[2] == pytest.approx(0, abs=1e-6) and (lo[:2] >= 0).all() and (hi[:2] <= 120).all()
    single = [trimesh.load(exported / f"star_00{i}.stl", force="mesh").volume for i in (1, 3)]
    assert plate.volume == pytest.approx(sum(single), rel=1e-6)


def test_refuses_to_overwrite_and_force_replaces(fam, capsys):
    code, _, _ = _run(["export", fam, "--ids", "2", "--format", "stl", "--no-plate", "-q"], capsys)
    assert code == 0
    out = fam.parent / "bodies"
    before = (out / "star_002.stl").stat().st_mtime_ns
    code, _, err = _run(["export", fam, "--ids", "2", "--format", "stl", "--no-plate"], capsys)
    assert code == 2 and "--force" in err and err.count("\n") == 1
    assert (out / "star_002.stl").stat().st_mtime_ns == before
    code, _, _ = _run(["export", fam, "--ids", "2", "--format", "stl", "--no-plate", "--force", "-q"], capsys)
    assert code == 0


def _bad_family(path: Path, kind: str) -> Path:
    data = json.loads(DATA.read_text())
    if kind == "corrupt":
        path.write_text('{"format": "starforge.family", "vers')
    elif kind == "version":
        data["version"] = 99
        path.write_text(json.dumps(data))
    elif kind == "other":
        path.write_text(json.dumps({"format": "starforge.placement", "version": 1}))
    return path


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["missing"], "not found"),
        (["corrupt"], "not valid JSON"),
        (["version"], "version 99"),
        (["other"], "print a family.json or a tracker file"),
        (["ok", "--stem-mm", "0.5"], "printable minimum"),
        (["ok", "--mount", "strap"], r"mount strap does not fit: .* by \d+\.\d\d mm; pass --allow-oversize"),
        (["ok", "--mount", "bogus"], r"--mount must be .*got 'bogus'; known .*: adhesive, flat, magnet, saddle, strap"),
        (["ok", "--format", "step,obj"], r"--format must be one or more of step, stl, 3mf \(CAD\), .*got 'obj'"),
        (["ok", "--ids", "1,77"], "77 not in the family"),
        (["ok", "--set", "hole_mm=99"], r"hole_mm must be in \[1.0, 4.5\]"),
        (["ok", "--bed", "20x20"], "larger than the 20 x 20 mm bed"),
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, args, message):
    import re

    path = tmp_path / "fam" / "family.json"
    path.parent.mkdir()
    kind, *rest = args
    if kind == "ok":
        shutil.copy(DATA, path)
    elif kind != "missing":
        _bad_family(path, kind)
    out = tmp_path / "out"
    code, _, err = _run(["export", path, "--out", out, *rest], capsys)
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert re.search(message, err), err
    assert not out.exists() or not any(out.rglob("*"))
    assert not list(tmp_path.glob(".*staging"))


def test_oversize_can_be_exported_on_request(fam, capsys):
    code, _, err = _run(
        ["export", fam, "--ids", "1", "--mount", "strap", "--format", "stl", "--allow-oversize"], capsys
    )
    assert code == 0
    assert "warning: star_001: body" in err and "exceeds the size limit" in err
    doc = json.loads((fam.parent / "bodies" / "bodies.json").read_text())
    assert doc["bodies"][0]["fits"] is False and max(doc["bodies"][0]["excess_mm"]) > 1
    assert any("exceeds the size limit" in w for w in doc["warnings"])  # what -q leaves unsaid is recorded


def test_tracker_formats_route_to_the_tracking_module(fam, capsys):
    pytest.importorskip("starforge.tracking.formats")
    code, _, err = _run(["export", fam, "--ids", "1", "--format", "stl,csv", "--no-plate", "-q"], capsys)
    assert code == 0, err
    out = fam.parent / "bodies"
    assert (out / "star_001.stl").is_file()
    assert list((out / "csv").glob("*.csv"))


def test_mounts_lists_and_details(capsys):
    code, out, _ = _run(["mounts"], capsys)
    assert code == 0
    for name in ("flat", "strap", "saddle", "adhesive", "magnet"):
        assert name in out
    code, out, _ = _run(["mounts", "saddle"], capsys)
    assert code == 0 and "segment_mm" in out and "range" in out
    code, _, err = _run(["mounts", "nope"], capsys)
    assert code == 2 and "got 'nope'; known (starforge templates mounts): adhesive, flat, magnet, saddle, strap" in err


@pytest.mark.parametrize("marker", [4.0, 6.4])
def test_mounts_show_the_room_stars_mount_reserves(marker, capsys):
    """The room `mounts` shows is the reserve `stars --mount` computes, rounded up (never less)."""
    import re

    from starforge.cad.mounts import list_mounts
    from starforge.cad.reserve import mount_reserve_mm

    code, out, _ = _run(["mounts", "--marker", marker], capsys)
    assert code == 0
    text = " ".join(out.split())  # the console wraps long lines
    for m in list_mounts():
        hit = re.search(rf"\b{m.name} \({m.kind}\): [^;]*; room ([0-9.]+) ([0-9.]+) ([0-9.]+) mm", text)
        assert hit, m.name
        shown = np.array([float(v) for v in hit.groups()])
        exact = np.array(mount_reserve_mm(m, marker))
        assert np.all(shown >= exact - 1e-12) and np.all(shown - exact < 0.01 + 1e-9), (m.name, shown, exact)
    code, _, err = _run(["mounts", "--marker", 0], capsys)
    assert code == 2 and "--marker" in err and len(err.strip().splitlines()) == 1


def test_preview_command_draws_bodies_and_sheet(fam, capsys):
    code, _, err = _run(["preview", fam, "--ids", "2", "--mount", "magnet", "--allow-oversize"], capsys)
    assert code == 0, err
    pv = fam.parent / "bodies" / "preview"
    assert sorted(p.name for p in pv.iterdir()) == ["sheet.png", "star_002.png"]
