"""OptiTrack Motive profiles (.motive): what starforge writes holds the structure a public Motive
profile writer produces (checked here element by element, independently of starforge's writer),
a profile written the way that plugin writes one is read, and bad files give one line."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.tracking.bodies import load_bodies
from starforge.tracking.export import write_rigid_bodies


def motive_rigid_bodies(path) -> dict:
    """Profile > NodeAssets > rigid_body (version, id) > markers > marker (id) > position 'x,y,z'
    in metres, size, residual, label_id; properties > property > name, value: NodeName,
    MaxMarkerDeflection, MarkerLocation<i>.  Any missing piece fails."""
    root = ET.parse(path).getroot()
    assert root.tag == "Profile" and root.get("version") == "1"
    out = {}
    for rb in root.find("NodeAssets").findall("rigid_body"):
        assert rb.get("version") and int(rb.get("id")) >= 0
        pts = []
        for k, m in enumerate(rb.find("markers").findall("marker")):
            assert int(m.get("id")) == k and int(m.findtext("label_id")) == k
            float(m.findtext("size")), float(m.findtext("residual"))
            pts.append([float(v) for v in m.findtext("position").split(",")])
        props = {p.findtext("name"): p.findtext("value") for p in rb.find("properties").findall("property")}
        locs = [[float(v) for v in props[f"MarkerLocation{k}"].split(",")] for k in range(len(pts))]
        assert np.allclose(locs, pts)
        out[props["NodeName"]] = {"m": np.array(pts), "deflection_m": float(props["MaxMarkerDeflection"])}
    assert out
    return out


def test_family_written_as_motive_profiles(small_family, tmp_path):
    out, doc = small_family
    summary = write_rigid_bodies(out / "family.json", ["motive"], tmp_path, noise_mm=0.2)
    truth = {b.name: b.points_mm for b in load_bodies(out / "family.json").bodies}
    files = sorted((tmp_path / "motive").glob("*.motive"))
    assert len(files) == len(truth)
    for f in files:
        ((name, body),) = motive_rigid_bodies(f).items()
        assert np.allclose(body["m"] * 1000.0, truth[name], atol=1e-9)  # metres in the file
        assert body["deflection_m"] * 1000 == pytest.approx(summary["tolerances"]["bone_length_tolerance_mm"])
        assert "0.2 mm marker noise" in f.read_text()
        (b,) = load_bodies(f).bodies
        assert np.array_equal(b.points_mm, truth[name])  # exact round trip in mm


def test_a_plugin_style_profile_with_two_bodies_is_read(tmp_path):
    def prop(name, value, default=None):
        d = f"<defaultValue>{default}</defaultValue>" if default is not None else ""
        return f"<property><name>{name}</name><value>{value}</value>{d}</property>"

    def body(i, name, pts):
        markers = "".join(
            f'<marker id="{k}"><position>{p}</position><size>0.012</size><residual>0.0</residual>'
            f"<label_id>{k}</label_id></marker>"
            for k, p in enumerate(pts)
        )
        props = prop("NodeName", name) + prop("Color", "8454079") + prop("MaxMarkerDeflection", "0.003")
        props += prop("Smoothing", "0.135") + prop("AcquisitionFrames", "1")
        props += "".join(prop(f"MarkerLocation{k}", p, "0,0,0") for k, p in enumerate(pts))
        return f'<rigid_body version="1.1" id="{i}"><markers>{markers}</markers><properties>{props}</properties></rigid_body>'

    wand = ["0,0,0", "0.05,0,0", "0,0.035,0.01", "0.02,0.02,0.04"]
    tri = ["0.1,0,0", "0,0.07,0", "0,0,0.045"]
    path = tmp_path / "lab.motive"
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?><Profile version="1"><NodeAssets>'
        + body(1, "Wand", wand)
        + body(2, "Tri", tri)
        + "</NodeAssets></Profile>"
    )
    bs = load_bodies(path)
    assert bs.names == ["Wand", "Tri"] and [b.n_markers for b in bs.bodies] == [4, 3]
    assert np.allclose(bs.bodies[0].points_mm, [[0, 0, 0], [50, 0, 0], [0, 35, 10], [20, 20, 40]])
    assert np.allclose(bs.bodies[1].points_mm, [[100, 0, 0], [0, 70, 0], [0, 0, 45]])


@pytest.mark.parametrize(
    "text, message",
    [
        ('<Profile version="1"><NodeAssets/></Profile>', "no Motive rigid body"),
        (
            '<Profile><NodeAssets><rigid_body id="1"><markers><marker id="0"><position>1,2</position>'
            "</marker></markers></rigid_body></NodeAssets></Profile>",
            "needs x,y,z",
        ),
        (
            '<Profile><NodeAssets><rigid_body id="1"><markers><marker id="0"><position>a,0,0</position>'
            "</marker></markers></rigid_body></NodeAssets></Profile>",
            "not a number",
        ),
    ],
)
def test_bad_motive_files_give_one_line(tmp_path, text, message):
    path = tmp_path / "bad.motive"
    path.write_text(text)
    with pytest.raises(StarforgeError, match=message) as exc:
        load_bodies(path)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize(
    "name, message", [("tool.tra", "Motive 1.x"), ("tool.bin", "not a format starforge reads")]
)
def test_unsupported_binary_files_are_named_in_one_line(tmp_path, name, message):
    path = tmp_path / name
    path.write_bytes(bytes(range(256)) * 2)
    with pytest.raises(StarforgeError, match=message) as exc:
        load_bodies(path)
    assert "\n" not in str(exc.value) and "motive" in str(exc.value)
