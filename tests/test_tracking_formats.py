"""Rigid-body files: every element and attribute the vendors' parsers require (written here from
their documented structure, independently of starforge's writers), exact round trips, ids that
stay unique across a lab, and a lab's own files read back as input."""

from __future__ import annotations

import configparser
import csv
import itertools
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.tracking.bodies import load_bodies
from starforge.tracking.export import write_rigid_bodies
from starforge.tracking.formats import READERS, TRACKER_FORMATS
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
        key = p.stem if p.parent.name in ("atracsys", "rom") else name
        # exact, not approximate (NDI's .rom holds float32: exact to float32)
        want = truth[key].astype(np.float32).astype(float) if p.parent.name == "rom" else truth[key]
        assert np.array_equal(pts, want)
        # and a lab's file is input again: the same body through load_bodies
        (b,) = load_bodies(p).bodies
        assert np.array_equal(b.points_mm, want)


def brute_margin(points_list) -> float:
    """The one-marker-hidden margin by brute force: every pair of different triangles (sorted
    sides, max difference) and every triangle's closest two sides."""
    tri = []
    for P in points_list:
        for a, b, c in itertools.combinations(range(len(P)), 3):
            tri.append(
                sorted(
                    [np.linalg.norm(P[a] - P[b]), np.linalg.norm(P[b] - P[c]), np.linalg.norm(P[a] - P[c])]
                )
            )
    T = np.array(tri)
    best = np.diff(T, axis=1).min()
    for i, j in itertools.combinations(range(len(T)), 2):
        best = min(best, np.abs(T[i] - T[j]).max())
    return float(best)


def test_qtm_files_hold_what_the_settings_parser_requires(small_family, tmp_path):
    out, doc = small_family
    summary = write_rigid_bodies(out / "family.json", ["qtm"], tmp_path)
    bs = load_bodies(out / "family.json")
    margin = brute_margin([b.points_mm for b in bs.bodies])
    assert summary["qtm"]["margin_mm"] == pytest.approx(margin, abs=1e-6)
    colours = set()
    for f in sorted((tmp_path / "qtm").glob("*.xml")):
        (body,) = qtm_6dof_bodies(f)
        # the midpoint between matching itself and another body, unless the noise needs more
        bone = body["bone_tolerance"]
        assert bone == pytest.approx(margin / 2, abs=1e-6) or (
            bone > margin / 2 and "note" in summary["tolerances"]
        )
        assert body["min_markers"] == 3 and len(body["points"]) == 4
        assert "0.2 mm marker noise" in f.read_text()  # the file says which noise it assumes
        colours.add(body["color"])
    assert len(colours) == len(doc["stars"])  # every body its own colour
    # the file's own gate keeps the frames at that noise (Monte Carlo, independent of the derivation)
    gate_loss = noise_gate_loss(bs.bodies[0].points_mm, 0.2, body["bone_tolerance"], body["max_residual"])
    assert gate_loss["bone"] <= 3e-4 and gate_loss["residual"] <= 3e-4


def noise_gate_loss(P, noise_mm, bone_mm, residual_mm, frames=100_000, seed=1) -> dict:
    """Share of frames of body ``P`` at ``noise_mm`` rejected by a bone-length gate (some
    distance off by more than ``bone_mm``) and by a residual gate (some marker farther than
    ``residual_mm`` from the best rigid fit), simulated."""
    from starforge.geometry.rigid import kabsch

    rng = np.random.default_rng(seed)
    X = P[None] + rng.normal(0.0, noise_mm, size=(frames, *P.shape))
    i, j = np.triu_indices(len(P), 1)
    d_true = np.linalg.norm(P[i] - P[j], axis=1)
    d = np.linalg.norm(X[:, i] - X[:, j], axis=2)
    R, t = kabsch(np.broadcast_to(P, X.shape), X)
    fit = np.einsum("fij,kj->fki", R, P) + t[:, None]
    res = np.linalg.norm(X - fit, axis=2)
    return {
        "bone": float((np.abs(d - d_true) > bone_mm).any(axis=1).mean()),
        "residual": float((res > residual_mm).any(axis=1).mean()),
    }


def test_vsk_follows_vicons_layout(tmp_path):
    src = placement_json(tmp_path / "placement.json", POS_M)
    write_rigid_bodies(src, ["vsk"], tmp_path / "out")
    v = vicon_markers(tmp_path / "out" / "vsk" / "wand.vsk")
    assert v["segment"] == "wand" and v["markers"] == ["M1", "M2", "M3", "M4"]
    assert np.array_equal(v["points"], np.array(POS_M) * 1000.0)


def atracsys_geometry(text: str) -> tuple[int, np.ndarray]:
    """An Atracsys geometry the way Atracsys' own INI code (as kept in PlusLib) reads it: a line
    holding [ and ] opens a section; otherwise a line with = is key=value inside the current
    section, the key taken verbatim (no trimming); anything else must be blank or a ; comment.
    [geometry] needs count and id; then [fiducial0].. each with x, y, z.  The SDK's geometry
    holds at most 6 fiducials (FTK_MAX_FIDUCIALS)."""
    sections: dict = {}
    current = ""
    for line in text.replace("\r", "").split("\n"):
        if "[" in line and "]" in line:
            current = line[line.index("[") + 1 : line.rindex("]")]
            sections[current] = {}
        elif "=" in line and current:
            key, _, value = line.partition("=")
            sections[current][key] = value
        else:
            assert line.replace(" ", "").replace("\t", "") == "" or line.lstrip().startswith(";"), line
    geometry = sections["geometry"]
    count, gid = int(geometry["count"]), int(geometry["id"])
    assert 1 <= count <= 6 and 0 <= gid < 2**32
    pts = np.array([[float(sections[f"fiducial{i}"][c]) for c in "xyz"] for i in range(count)])
    return gid, pts


def test_atracsys_files_parse_the_way_atracsys_reads_them(small_family, tmp_path):
    out, _ = small_family
    summary = write_rigid_bodies(out / "family.json", ["atracsys"], tmp_path, id_start=40)
    truth = {b.name: b.points_mm for b in load_bodies(out / "family.json").bodies}
    ids = []
    for f in sorted((tmp_path / "atracsys").glob("*.ini")):
        gid, pts = atracsys_geometry(f.read_text())
        assert np.array_equal(pts, truth[f.stem])
        assert gid == summary["atracsys_ids"][f.stem]
        ids.append(gid)
    assert sorted(ids) == list(range(40, 40 + len(truth)))


def test_atracsys_refuses_bodies_its_geometry_cannot_hold(tmp_path):
    seven = [
        [0.0, 0, 0],
        [0.05, 0, 0],
        [0, 0.06, 0],
        [0, 0, 0.07],
        [0.04, 0.05, 0],
        [0.03, 0, 0.08],
        [0.09, 0.02, 0.03],
    ]
    src = placement_json(tmp_path / "placement.json", seven)
    with pytest.raises(StarforgeError, match="holds at most 6 markers"):
        write_rigid_bodies(src, ["qtm", "atracsys"], tmp_path / "out")
    assert not (tmp_path / "out").exists()
    rc = run_cli(["export", src, "--format", "atracsys", "--out", tmp_path / "cli"])
    assert rc == 2 and not (tmp_path / "cli").exists()


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


def _vsk_skeleton(path: Path) -> Path:
    """A VSK laid out as Vicon software writes a skeleton (cf. the VSK kept in the DART project):
    parameters by name, nested segments with joints, markers in their segment's frame."""
    params = {"W": 40.0, "L": 300.0, "A_X": 12.0, "A_Y": -5.5, "B_Z": 33.0}
    ptxt = "".join(f'<Parameter NAME="{k}" VALUE="{v}" PRIOR="0"/>' for k, v in params.items())
    cov36 = " ".join(["1.000000"] * 36)
    path.write_text(
        '<?xml version="1.0" standalone="yes"?>\n<KinematicModel><Parameters>' + ptxt + "</Parameters>"
        '<Skeleton><Segment NAME="Root" POSITION="0 0 0" ORIENTATION="0 0 0" BOUNDS="0 0 0 0 0 0" RGB="0 128 0">'
        f'<JointFree MEAN="0 0 0 0 0 0 " COVARIANCE="{cov36}"/>'
        '<Segment NAME="Arm" POSITION="W 0 0" ORIENTATION="0 0 0.5" BOUNDS="0 0 0 0 0 0" RGB="0 128 0">'
        '<JointBall MEAN="0 0 0" COVARIANCE="1 0 0 0 1 0 0 0 1"/>'
        '<Segment NAME="Hand" POSITION="0 -L 0" ORIENTATION="0 0 0" BOUNDS="0 0 0 0 0 0" RGB="0 128 0">'
        '<JointHinge AXIS="1 0 0" MEAN="0" COVARIANCE="1"/></Segment></Segment></Segment></Skeleton>'
        '<MarkerSet NAME="subject"><Markers>'
        '<Marker NAME="R1" SEGMENT="Root" POSITION="A_X A_Y 0" RADIUS="7"/>'
        '<Marker NAME="R2" SEGMENT="Root" POSITION="-W 0 10"/>'
        '<Marker NAME="R3" SEGMENT="Root" POSITION="0 25 -B_Z"/>'
        '<Marker NAME="A1" SEGMENT="Arm" POSITION="0 -L 0"/>'
        '<Marker NAME="A2" SEGMENT="Arm" POSITION="10 -120 4"/>'
        '<Marker NAME="A3" SEGMENT="Arm" POSITION="-8 -60 12"/>'
        '<Marker NAME="A4" SEGMENT="Arm" POSITION="0 -200 -15"/>'
        '<Marker NAME="H1" SEGMENT="Hand" POSITION="0 -40 0"/>'
        "</Markers><Sticks/></MarkerSet></KinematicModel>\n"
    )
    return path


def test_vicon_skeleton_gives_one_body_per_segment(tmp_path):
    bs = load_bodies(_vsk_skeleton(tmp_path / "subject.vsk"))
    # each segment's markers are in that segment's frame: one rigid body per segment
    assert bs.names == ["subject_Root", "subject_Arm"]
    assert np.array_equal(bs.bodies[0].points_mm, [[12.0, -5.5, 0], [-40.0, 0, 10], [0, 25.0, -33.0]])
    assert np.array_equal(bs.bodies[1].points_mm[0], [0, -300.0, 0])
    # the one-marker hand is no rigid body: skipped, and said so
    assert any("Hand (1 marker)" in w for w in bs.warnings)
    assert bs.kind == "tracker" and bs.tips_mm().tolist() == [[0, 0, 0], [0, 0, 0]]


def test_older_qtm_layouts_and_metre_csv_are_read(tmp_path):
    old = tmp_path / "bodies.xml"
    old.write_text(
        "<QTM_Body_File_Ver_1.00><Bodies><Body><Name>probe</Name><Points>"
        '<Point X="0" Y="0" Z="0" Virtual="0"/><Point X="50" Y="0" Z="0"/><Point X="0" Y="35" Z="0"/>'
        '<Point X="10" Y="10" Z="0" Virtual="1"/><Point X="0" Y="0" Z="22"/></Points></Body>'
        "<Body><Name>wand</Name><Bone><X>0</X><Y>0</Y><Z>0</Z></Bone><Bone><X>60</X><Y>0</Y><Z>0</Z></Bone>"
        "<Bone><X>0</X><Y>41</Y><Z>0</Z></Bone></Body></Bodies></QTM_Body_File_Ver_1.00>"
    )
    bs = load_bodies(old)
    assert bs.names == ["probe", "wand"]
    assert len(bs.bodies[0].points_mm) == 4  # the virtual point carries no marker
    assert np.array_equal(bs.bodies[1].points_mm, [[0, 0, 0], [60, 0, 0], [0, 41, 0]])
    csv_m = tmp_path / "lab.csv"
    csv_m.write_text("body,marker,x_m,y_m,z_m\ntool,2,0.05,0,0\ntool,1,0,0,0\ntool,3,0,0.031,0.012\n")
    (b,) = load_bodies(csv_m).bodies
    assert np.allclose(b.points_mm, [[0, 0, 0], [50, 0, 0], [0, 31, 12]])


def test_a_labs_bodies_beside_a_family_and_a_placement(small_family, tmp_path):
    out, _ = small_family
    write_rigid_bodies(placement_json(tmp_path / "p.json", POS_M), ["qtm"], tmp_path / "lab")
    prop = placement_json(tmp_path / "prop.json", np.array(POS_M) * [1.1, 0.9, 1.2], name="sword")
    doc = json.loads(prop.read_text())
    doc["prop"]["bounds_m"] = [[-0.06, -0.05, -0.07], [0.09, 0.07, 0.4]]
    prop.write_text(json.dumps(doc))
    bs = load_bodies([out / "family.json", tmp_path / "lab" / "qtm" / "wand.xml", prop])
    fam = load_bodies(out / "family.json")
    assert bs.kind == "mixed" and len(bs.bodies) == len(fam.bodies) + 2
    assert bs.tolerance_mm == fam.tolerance_mm and len(set(bs.names)) == len(bs.names)
    tips = bs.tips_mm()
    assert np.array_equal(tips[0], fam.default_tip_mm)  # the family's tip
    assert np.array_equal(tips[-2], [0, 0, 0])  # a tracker file: its origin
    # the prop: the bounding-box corner with the largest predicted TRE, checked on a dense grid
    from starforge.geometry.rigid import tre_rms

    P = bs.bodies[-1].points_mm
    lo, hi = np.array(doc["prop"]["bounds_m"]) * 1000
    grid = np.stack(np.meshgrid(*[np.linspace(a, b, 9) for a, b in zip(lo, hi, strict=True)]), -1).reshape(
        -1, 3
    )
    worst = max(tre_rms(P, g, 1.0) for g in grid)
    assert tre_rms(P, tips[-1], 1.0) == pytest.approx(worst, rel=1e-9)
    assert any(np.allclose(tips[-1], c) for c in itertools.product(*zip(lo, hi, strict=True)))


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("nan.csv", "body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,2,nan,0,0\nt,3,0,9,0\n", "not finite"),
        ("twice.csv", "body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,2,0,0,0\nt,3,0,9,0\n", "two markers"),
        ("two.csv", "body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,2,20,0,0\n", "at least 3"),
        (
            "same.csv",
            "body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,1,20,0,0\nt,3,0,9,0\n",
            "numbers a marker twice",
        ),
        ("m.csv", "body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,2,0.02,0,0\nt,3,0,0.03,0\n", "other units"),
        ("huge.ini", "[geometry]\ncount=1000000\nid=3\n", "outside 1..64"),
        (
            "bad.vsk",
            '<KinematicModel><MarkerSet NAME="x"><Markers><Marker NAME="a" POSITION="1 2"/>',
            "not valid XML",
        ),
        (
            "tok.vsk",
            '<KinematicModel><MarkerSet><Markers><Marker NAME="a" POSITION="Q 0 0"/></Markers>'
            "</MarkerSet></KinematicModel>",
            "POSITION token",
        ),
        ("empty.xml", "<QTM_Settings><The_6D/></QTM_Settings>", "holds no QTM Body"),
    ],
)
def test_corrupt_tracker_files_give_one_line(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(StarforgeError, match=message) as exc:
        load_bodies(path)
    assert "\n" not in str(exc.value)


def test_oversized_tracker_file_is_refused_before_parsing(tmp_path, monkeypatch):
    from starforge.tracking.formats import _common

    monkeypatch.setattr(_common, "MAX_FILE_BYTES", 100)
    path = tmp_path / "big.xml"
    path.write_text("<QTM_Settings><The_6D>" + " " * 200 + "</The_6D></QTM_Settings>")
    with pytest.raises(StarforgeError, match="at most 100 B"):
        load_bodies(path)
