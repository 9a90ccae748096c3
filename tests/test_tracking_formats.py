"""Rigid-body files: parsed with real parsers (xml.etree, configparser, csv) independently of
starforge's readers, and round-tripped exactly."""

from __future__ import annotations

import configparser
import csv
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.tracking.bodies import load_bodies
from starforge.tracking.formats import READERS, TRACKER_FORMATS, write_rigid_bodies


def placement_json(path: Path, positions_m, name="wand") -> Path:
    doc = {
        "format": "starforge.placement",
        "version": 1,
        "prop": {"name": name},
        "marker_diameter_m": 0.0127,
        "markers": [
            {"position": list(p), "normal": [0.0, 0.0, 1.0], "site": i, "visibility": 0.5}
            for i, p in enumerate(positions_m)
        ],
    }
    path.write_text(json.dumps(doc))
    return path


POS_M = [[0.0123, -0.0456, 0.1], [0.0781, 0.0029, 0.0333], [-0.05, 0.0611, 0.0207], [0.0017, 0.0091, -0.0642]]


def test_family_round_trips_in_every_format(small_family, tmp_path):
    out, _ = small_family
    bs = load_bodies(out / "family.json")
    paths = write_rigid_bodies(out / "family.json", list(TRACKER_FORMATS), tmp_path)
    assert len(paths) == len(TRACKER_FORMATS) * len(bs.bodies)
    truth = {b.name: b.points_mm for b in bs.bodies}
    for p in paths:
        got = READERS[p.parent.name](p)
        assert len(got) == 1
        name, pts = next(iter(got.items()))
        key = p.stem if p.parent.name == "atracsys" else name
        assert np.array_equal(pts, truth[key])  # exact, not approximate


def test_qtm_and_vsk_parse_with_etree(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M)
    paths = write_rigid_bodies(src, ["qtm", "vsk"], tmp_path / "out")
    mm = np.array(POS_M) * 1000.0
    qtm = ET.parse(tmp_path / "out" / "qtm" / "wand.xml").getroot()
    assert qtm.tag == "QTM_Body_File_Ver_1.00"
    (body,) = qtm.findall("./Bodies/Body")
    assert body.findtext("Name") == "wand"
    pts = np.array([[float(pt.get(c)) for c in "XYZ"] for pt in body.findall("./Points/Point")])
    assert np.array_equal(pts, mm)
    vsk = ET.parse(tmp_path / "out" / "vsk" / "wand.vsk").getroot()
    assert vsk.tag == "KinematicModel"
    markers = vsk.findall("./MarkerSet/Markers/Marker")
    assert [m.get("SEGMENT") for m in markers] == ["wand"] * 4
    assert vsk.find("./Skeleton/Segment").get("NAME") == "wand"
    pts = np.array([[float(v) for v in m.get("POSITION").split()] for m in markers])
    assert np.array_equal(pts, mm)
    assert float(markers[0].get("RADIUS")) == pytest.approx(12.7 / 2)
    assert len(paths) == 2


def test_atracsys_and_csv_parse_with_stdlib(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M, name="probe tool")
    write_rigid_bodies(src, "atracsys,csv", tmp_path / "out")
    mm = np.array(POS_M) * 1000.0
    cp = configparser.ConfigParser()
    cp.read(tmp_path / "out" / "atracsys" / "probe_tool.ini")
    assert cp.getint("geometry", "count") == 4
    assert cp.has_option("geometry", "id")
    pts = np.array([[cp.getfloat(f"fiducial{i}", c) for c in "xyz"] for i in range(4)])
    assert np.array_equal(pts, mm)
    with open(tmp_path / "out" / "csv" / "probe_tool.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["body"] for r in rows] == ["probe_tool"] * 4
    assert np.array_equal(np.array([[float(r[c]) for c in ("x_mm", "y_mm", "z_mm")] for r in rows]), mm)


def test_several_placements_give_several_bodies(tmp_path):
    a = placement_json(tmp_path / "a.json", POS_M, name="wand")
    b = placement_json(tmp_path / "b.json", np.array(POS_M)[::-1] * 1.3, name="wand")
    bs = load_bodies([a, b])
    assert bs.kind == "placement" and bs.names == ["wand", "wand_2"]
    assert bs.marker_mm == pytest.approx(12.7)


def test_bad_inputs_raise_one_line_errors(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M)
    with pytest.raises(StarforgeError, match="unknown tracker format 'fbx'"):
        write_rigid_bodies(src, ["qtm", "fbx"], tmp_path / "out")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(StarforgeError, match="not valid JSON"):
        write_rigid_bodies(bad, ["csv"], tmp_path / "out")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something.else"}))
    with pytest.raises(StarforgeError, match="neither a star family nor a prop placement"):
        write_rigid_bodies(other, ["csv"], tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(
    not (Path(__file__).parents[1] / "starforge" / "cli" / "export.py").exists(),
    reason="starforge export (the CAD engineer's command) is not there yet",
)
def test_export_command_writes_tracker_files(small_family, tmp_path):
    from starforge.cli import main

    out, _ = small_family
    rc = main(["export", str(out / "family.json"), "--format", "qtm,csv", "--out", str(tmp_path / "exp")])
    assert rc == 0
    files = sorted(p.name for p in (tmp_path / "exp").rglob("*.xml"))
    assert len(files) == len(load_bodies(out / "family.json").bodies)
