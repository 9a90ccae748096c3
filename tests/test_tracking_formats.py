"""Rigid-body files: every element and attribute the vendors' parsers require (written here from
their documented structure, independently of starforge's writers), exact round trips, ids that
stay unique across a lab, and a lab's own files read back as input."""

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
from tests.conftest import run_cli


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


def qtm_6dof_bodies(path) -> list[dict]:
    """What Qualisys' settings parser needs from a 6DOF body (RT protocol >= 1.24), read the way
    ``Deserialize6DOFSettings`` documents it: the root's ``The_6D`` child, each ``Body`` with a
    Name; Color R/G/B; MaximumResidual, MinimumMarkersInBody, BoneLengthTolerance; Filter@Preset;
    Points/Point@X,Y,Z,Virtual,PhysicalId,Name; Data_origin (type; X,Y,Z,Relative_body) and
    Data_orientation (the same type and Relative_body; R11..R33).  Any missing piece fails."""
    root = ET.parse(path).getroot()
    the6d = root.find("The_6D")
    assert the6d is not None, "no The_6D element under the root"
    out = []
    for b in the6d.findall("Body"):
        body = {"name": b.findtext("Name")}
        assert body["name"], "Body without Name"
        assert b.findtext("Enabled") in ("true", "false")
        c = b.find("Color")
        body["color"] = tuple(int(c.get(k)) for k in "RGB")
        assert all(0 <= v <= 255 for v in body["color"])
        body["max_residual"] = float(b.findtext("MaximumResidual"))
        body["min_markers"] = int(b.findtext("MinimumMarkersInBody"))
        body["bone_tolerance"] = float(b.findtext("BoneLengthTolerance"))
        assert b.find("Filter").get("Preset") is not None
        pts = b.find("Points").findall("Point")
        body["points"] = np.array([[float(p.get(k)) for k in "XYZ"] for p in pts])
        for p in pts:
            int(p.get("Virtual"))
            int(p.get("PhysicalId"))
            assert p.get("Name")
        org, ori = b.find("Data_origin"), b.find("Data_orientation")
        assert int(org.text) == int(ori.text)
        assert int(org.get("Relative_body")) == int(ori.get("Relative_body"))
        [float(org.get(k)) for k in "XYZ"]
        R = np.array([[float(ori.get(f"R{i}{j}")) for j in (1, 2, 3)] for i in (1, 2, 3)])
        assert np.allclose(R @ R.T, np.eye(3))
        out.append(body)
    assert out, "no Body"
    return out


def vicon_markers(path) -> dict:
    """A VSK the way Vicon software writes one: parameters by name and value; a segment with a
    JointFree holding MEAN (6) and COVARIANCE (36); markers with NAME, SEGMENT, RGB, a POSITION of
    three parameter names, a 9-value COVARIANCE and a RADIUS; sticks between named markers."""
    root = ET.parse(path).getroot()
    assert root.tag == "KinematicModel"
    params = {p.get("NAME"): float(p.get("VALUE")) for p in root.find("Parameters").findall("Parameter")}
    seg = root.find("Skeleton").find("Segment")
    joint = seg.find("JointFree")
    assert len(joint.get("MEAN").split()) == 6 and len(joint.get("COVARIANCE").split()) == 36
    assert len(seg.get("BOUNDS").split()) == 6 and len(seg.get("RGB").split()) == 3
    ms = root.find("MarkerSet")
    names, pts = [], []
    for m in ms.find("Markers").findall("Marker"):
        assert m.get("SEGMENT") == seg.get("NAME")
        assert len(m.get("COVARIANCE").split()) == 9 and float(m.get("RADIUS")) > 0
        assert len(m.get("RGB").split()) == 3
        refs = m.get("POSITION").split()
        assert len(refs) == 3 and all(r in params for r in refs), "POSITION must name parameters"
        names.append(m.get("NAME"))
        pts.append([params[r] for r in refs])
    for s in ms.find("Sticks").findall("Stick"):
        assert s.get("MARKER1") in names and s.get("MARKER2") in names and s.get("RGB")
    return {"segment": seg.get("NAME"), "markers": names, "points": np.array(pts)}


def test_family_round_trips_in_every_format(small_family, tmp_path):
    out, _ = small_family
    bs = load_bodies(out / "family.json")
    summary = write_rigid_bodies(out / "family.json", list(TRACKER_FORMATS), tmp_path)
    paths = [tmp_path / f for f in summary["files"]]
    assert len(paths) == len(TRACKER_FORMATS) * len(bs.bodies)
    truth = {b.name: b.points_mm for b in bs.bodies}
    for p in paths:
        got = READERS[p.parent.name](p)
        assert len(got) == 1
        name, pts = next(iter(got.items()))
        key = p.stem if p.parent.name == "atracsys" else name
        assert np.array_equal(pts, truth[key])  # exact, not approximate
        # and a lab's file is input again: the same body through load_bodies
        (b,) = load_bodies(p).bodies
        assert np.array_equal(b.points_mm, truth[key])


def test_qtm_files_hold_what_the_settings_parser_requires(small_family, tmp_path):
    out, doc = small_family
    write_rigid_bodies(out / "family.json", ["qtm"], tmp_path)
    tol = doc["spec"]["tolerance_mm"] or doc["spec"]["delta_mm"]
    colours = set()
    for f in sorted((tmp_path / "qtm").glob("*.xml")):
        (body,) = qtm_6dof_bodies(f)
        assert body["bone_tolerance"] == pytest.approx(tol / 2)  # from the family, not a constant
        assert body["max_residual"] == pytest.approx(tol / 4)
        assert body["min_markers"] == 3 and len(body["points"]) == 4
        colours.add(body["color"])
    assert len(colours) == len(doc["stars"])  # every body its own colour


def test_vsk_follows_vicons_layout(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M)
    write_rigid_bodies(src, ["vsk"], tmp_path / "out")
    v = vicon_markers(tmp_path / "out" / "vsk" / "wand.vsk")
    assert v["segment"] == "wand" and v["markers"] == ["M1", "M2", "M3", "M4"]
    assert np.array_equal(v["points"], np.array(POS_M) * 1000.0)


def test_atracsys_ids_are_unique_across_families_and_csv_parses(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M, name="probe tool")
    s1 = write_rigid_bodies(src, "atracsys,csv", tmp_path / "a", id_start=100)
    s2 = write_rigid_bodies(src, "atracsys", tmp_path / "b", id_start=200)
    assert s1["atracsys_ids"] == {"probe_tool": 100} and s2["atracsys_ids"] == {"probe_tool": 200}
    cp = configparser.ConfigParser()
    cp.read(tmp_path / "a" / "atracsys" / "probe_tool.ini")
    assert cp.getint("geometry", "count") == 4 and cp.getint("geometry", "id") == 100
    pts = np.array([[cp.getfloat(f"fiducial{i}", c) for c in "xyz"] for i in range(4)])
    assert np.array_equal(pts, np.array(POS_M) * 1000.0)
    with open(tmp_path / "a" / "csv" / "probe_tool.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["body"] for r in rows] == ["probe_tool"] * 4
    with pytest.raises(StarforgeError, match="id_start"):
        write_rigid_bodies(src, "atracsys", tmp_path / "c", id_start=-1)


def test_vicon_made_vsk_with_named_and_negated_parameters_is_read(tmp_path):
    p = tmp_path / "tool.vsk"
    p.write_text(
        '<?xml version="1.0" standalone="yes"?><KinematicModel><Parameters>'
        '<Parameter NAME="W" VALUE="40"/><Parameter NAME="H" VALUE="25.5"/></Parameters>'
        '<Skeleton><Segment NAME="tool" POSITION="0 0 0" ORIENTATION="0 0 0" BOUNDS="0 0 0 0 0 0" RGB="0 128 0">'
        '<JointFree MEAN="0 0 0 0 0 0" COVARIANCE="' + " ".join(["0"] * 36) + '"/></Segment></Skeleton>'
        '<MarkerSet NAME="tool"><Markers>'
        '<Marker NAME="A" SEGMENT="tool" POSITION="W 0 0"/><Marker NAME="B" SEGMENT="tool" POSITION="-W 0 0"/>'
        '<Marker NAME="C" SEGMENT="tool" POSITION="0 H 10"/><Marker NAME="D" SEGMENT="tool" POSITION="5 -H 30"/>'
        "</Markers></MarkerSet></KinematicModel>"
    )
    (b,) = load_bodies(p).bodies
    assert np.array_equal(b.points_mm, [[40, 0, 0], [-40, 0, 0], [0, 25.5, 10], [5, -25.5, 30]])


def test_several_placements_and_tracker_files_give_several_bodies(tmp_path):
    a = placement_json(tmp_path / "a.json", POS_M, name="wand")
    b = placement_json(tmp_path / "b.json", np.array(POS_M)[::-1] * 1.3, name="wand")
    bs = load_bodies([a, b])
    assert bs.kind == "placement" and bs.names == ["wand", "wand_2"]
    assert bs.marker_mm == pytest.approx(12.7)
    write_rigid_bodies(a, ["qtm"], tmp_path / "q")
    mixed = load_bodies([b, tmp_path / "q" / "qtm" / "wand.xml"])
    assert mixed.kind == "mixed" and len(mixed.bodies) == 2


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
    metres = placement_json(tmp_path / "m.json", np.array(POS_M) * 1e4)  # 100 m markers: other units
    with pytest.raises(StarforgeError, match="other units"):
        load_bodies(metres)
    broken = tmp_path / "broken.xml"
    broken.write_text("<QTM_Settings><The_6D><Body><Name>x</Name><Points><Point X='a' Y='0' Z='0'/>")
    with pytest.raises(StarforgeError, match="not valid XML"):
        load_bodies(broken)
    ini = tmp_path / "g.ini"
    ini.write_text("[geometry]\ncount=4\nid=3\n[fiducial0]\nx=1\n")
    with pytest.raises(StarforgeError, match="not an Atracsys geometry file"):
        load_bodies(ini)
    assert not (tmp_path / "out").exists()


def test_export_command_writes_tracker_files_and_a_summary(small_family, tmp_path):
    out, _ = small_family
    rc = run_cli(
        [
            "export",
            out / "family.json",
            "--format",
            "qtm,atracsys",
            "--id-start",
            500,
            "--out",
            tmp_path / "exp",
        ]
    )
    assert rc == 0
    n = len(load_bodies(out / "family.json").bodies)
    assert len(list((tmp_path / "exp" / "qtm").glob("*.xml"))) == n
    summary = json.loads((tmp_path / "exp" / "trackers.json").read_text())
    assert sorted(summary["atracsys_ids"].values()) == list(range(500, 500 + n))
