"""Issue 12: every file is ready to print as written.  Families made for a mount fit with it;
bodies lie plate-down on Z = 0 with no region starting in mid-air (a layer analysis of the
files themselves), PrusaSlicer slices them where it is installed, STEP plates are assemblies of
named, coloured solids, 3MF files carry a thumbnail, bought markers sit on seats at the designed
centre, engraved strokes suit the nozzle."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import zipfile

import numpy as np
import pytest

from starforge.cad.body import BodySpec, build_body, fit_report, label_boxes
from starforge.cad.mounts import load_mount
from starforge.cad.primitives import Cylinder
from starforge.cad.printability import layer_report
from tests.conftest import run_cli

# a box each mount fits (the strap's slots need a wider middle side)
BOXES = {
    "flat": (16, 12, 24),
    "saddle": (16, 12, 26),
    "magnet": (16, 12, 24),
    "adhesive": (16, 12, 24),
    "strap": (36, 14, 40),
}


@pytest.fixture(scope="module", params=sorted(BOXES))
def made(request, tmp_path_factory):
    """A family made for the mount, and its first two bodies and plate exported (stl, 3mf, step)."""
    mount = request.param
    d = tmp_path_factory.mktemp(mount)
    args = ["stars", "--box", *BOXES[mount], "--delta", 2, "--mount", mount, "--count", 3, "--out", d, "-q"]
    assert run_cli(args) == 0
    out = d / "bodies"
    assert (
        run_cli(["export", d / "family.json", "--ids", "1,2", "--format", "stl,3mf,step", "--out", out, "-q"])
        == 0
    )
    return mount, d, out, json.loads((out / "bodies.json").read_text())


def test_a_family_made_for_its_mount_exports_without_refusal(made):
    mount, d, _, doc = made
    fam = json.loads((d / "family.json").read_text())
    assert fam["spec"]["mount"] == mount and doc["mount"]["name"] == mount
    assert all(b["fits"] for b in doc["bodies"])
    # and every star of the family, not just the exported ones, makes a body inside the limit
    m = load_mount(mount)
    for s in fam["stars"]:
        assert fit_report(build_body(s["id"], s["vertices"], 4.0, m, BodySpec()), fam["spec"]["box_mm"]).fits


def test_bodies_lie_plate_down_with_nothing_in_mid_air(made):
    import trimesh

    _, _, out, doc = made
    for b in doc["bodies"]:
        mesh = trimesh.load(out / f"{b['name']}.stl", force="mesh")
        assert mesh.is_watertight and mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
        rep = layer_report(mesh)
        assert rep["midair_islands"] == [], rep["midair_islands"]
        assert rep["first_layer_mm2"] >= 40.0  # real contact, not edges
        # the plate (the saddle's two rails) is the largest flat face, down on the bed
        assert rep["first_layer_mm2"] >= 0.2 * np.prod(mesh.extents[:2])
        # the recorded transform takes the family's centres into the file's frame
        T = np.array(b["placement_to_print"])
        for c in np.array(b["centres_mm"]) @ T[:3, :3].T + T[:3, 3]:
            assert mesh.contains([c])[0]
    plate = trimesh.load(out / "plate.stl", force="mesh")
    assert layer_report(plate)["midair_islands"] == []


def test_step_and_mesh_agree_and_the_plate_is_a_named_coloured_assembly(made):
    from starforge.cad.occ import read_step

    _, _, out, doc = made
    for b in doc["bodies"]:
        assert b["mesh_volume_mm3"] == pytest.approx(b["step_volume_mm3"], rel=1e-4)  # within 0.01 %
    import build123d as bd

    plate = bd.import_step(str(out / "plate.step"))
    names = sorted(c.label for c in plate.children)
    assert names == sorted(b["name"] for b in doc["bodies"])
    assert all(c.color is not None for c in plate.children)
    assert len(read_step(out / "plate.step")) == len(doc["bodies"])


def test_3mf_carries_a_thumbnail_and_colours(made):
    _, _, out, doc = made
    z = zipfile.ZipFile(out / f"{doc['bodies'][0]['name']}.3mf")
    png = z.read("Metadata/thumbnail.png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert "metadata/thumbnail" in z.read("_rels/.rels").decode()
    assert "displaycolor=" in z.read("3D/3dmodel.model").decode()


@pytest.mark.skipif(shutil.which("prusa-slicer") is None, reason="PrusaSlicer is not installed here")
def test_prusaslicer_slices_every_file_as_written(made, tmp_path):
    """The slicer that must slice the file: no error, and the sliced height is the body's."""
    _, _, out, doc = made
    for name, height in [(b["name"], b["print_height_mm"]) for b in doc["bodies"][:1]] + [("plate", None)]:
        for ext in ("stl", "3mf"):
            g = tmp_path / f"{name}.{ext}.gcode"
            res = subprocess.run(
                ["prusa-slicer", "--export-gcode", str(out / f"{name}.{ext}"), "--output", str(g)],
                capture_output=True,
                text=True,
                timeout=240,
            )
            assert res.returncode == 0 and g.exists(), res.stdout[-2000:] + res.stderr[-2000:]
            zs = [float(m) for m in re.findall(r"^;Z:([0-9.]+)", g.read_text(), flags=re.M)]
            if height is not None:
                assert abs(max(zs) - height) <= 0.35  # within one layer (PrusaSlicer: 0.3, first 0.35)


@pytest.mark.parametrize("marker", ["4mm-flat", "6.4mm-post", "9.5mm-m3", "12.7mm-m3", "14mm-m4"])
def test_bought_markers_sit_on_seats_at_the_designed_centre(marker):
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
        tops = [p for p in b.add if isinstance(p, Cylinder) and np.allclose(p.p1, seat, atol=1e-9)]
        assert tops, f"no seat at the base plane of marker {k}"
        if mt.attach in ("screw", "insert"):
            holes = [
                p
                for p in b.subtract
                if isinstance(p, Cylinder) and np.linalg.norm(np.array(p.p1) - seat) < 1.0
            ]
            assert holes and all(h.radius_mm * 2 < tops[0].radius_mm * 2 - 2.0 for h in holes)
    from starforge.cad.mesh import body_mesh

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
    assert min(widths) >= 1.5 * nozzle - 1e-9


def test_stems_scale_with_the_marker_and_flare_at_the_root():
    spec = BodySpec()
    assert spec.stem_for(4.0) == pytest.approx(1.8) and spec.stem_for(9.5) == pytest.approx(4.0)
    c = np.array([[0, 0, 0], [20, 2, 0], [0, 1, 22], [21, 4, 20]], float)
    b = build_body(1, c, 4.0, load_mount("flat"), spec)
    flares = [p for p in b.add if isinstance(p, Cylinder) and p.radius1_mm is not None]
    assert len(flares) == 4 and all(f.radius_mm > f.r1 for f in flares)


def test_strap_on_the_finger_box_is_refused_with_the_reason(tmp_path, capsys):
    assert run_cli(["stars", "--mount", "strap", "--out", tmp_path / "s"]) == 2
    assert "mount strap needs" in capsys.readouterr().err and not (tmp_path / "s").exists()
