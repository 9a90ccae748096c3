"""``starforge check`` end to end: outputs, internal consistency, bad input -> one line, exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from starforge.cli import main
from starforge.geometry.rigid import fle_from_sigma, tre_rms
from starforge.tracking.bodies import load_bodies


@pytest.fixture(scope="module")
def checked(small_family, tmp_path_factory):
    fam, _ = small_family
    out = tmp_path_factory.mktemp("check")
    rc = main(
        [
            "check",
            str(fam / "family.json"),
            "--frames",
            "150",
            "--ghosts",
            "0",
            "--curve",
            "3",
            "--tip",
            "0,0,60",
            "--preset",
            "art",
            "--out",
            str(out),
            "-q",
        ]
    )
    assert rc == 0
    return fam, out, json.loads((out / "check.json").read_text())


def test_check_writes_json_and_png(checked):
    _, out, doc = checked
    assert doc["format"] == "starforge.check" and doc["version"] == 1
    assert (out / "check.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for k in (
        "identification_rate",
        "mislabel_rate",
        "confusion",
        "worst_pairs",
        "accuracy",
        "curve",
        "rules",
    ):
        assert k in doc


def test_check_counts_are_consistent(checked):
    _, _, doc = checked
    M = np.array(doc["confusion"]["matrix"])
    frames = doc["settings"]["frames"]
    # every body instance is correct, a wrong body, a flip or missed: rows add up to the frames
    assert (M.sum(axis=1) + np.array(doc["flips"]) + np.array(doc["missed"]) == frames).all()
    total = M.size // len(M) * frames
    assert doc["instances"] == total
    assert doc["identification_rate"] == pytest.approx(np.trace(M) / total)
    assert doc["mislabel_rate"] == pytest.approx((M.sum() - np.trace(M) + sum(doc["flips"])) / total)
    assert doc["identification_rate"] + doc["mislabel_rate"] + doc["missed_rate"] == pytest.approx(1.0)
    assert doc["settings"]["match_mm"] == 2.0  # the ART window
    assert len(doc["curve"]["noise_mm"]) == len(doc["curve"]["identification_rate"]) >= 3


def test_check_accuracy_and_rules(checked):
    fam, _, doc = checked
    bs = load_bodies(fam / "family.json")
    fle = fle_from_sigma(doc["settings"]["noise_mm"])
    acc = doc["accuracy"]
    tip = np.array(acc["tip_mm"])
    assert np.allclose(tip, [0, 0, 60])
    for row, b in zip(acc["bodies"], bs.bodies, strict=True):
        assert row["body"] == b.name
        assert row["tip_tre_mm"] == pytest.approx(tre_rms(b.points_mm, tip, fle))
        # with one marker hidden the error only grows, and the worst marker is named
        assert row["tip_tre_hidden_mm"] >= row["tip_tre_mm"]
        hid = []
        for i in range(4):
            Q = b.points_mm.copy()
            Q[i] = np.nan
            hid.append(tre_rms(Q, tip, fle))
        assert row["tip_tre_hidden_mm"] == pytest.approx(max(hid)) and row["worst_hidden_marker"] == 1 + int(
            np.argmax(hid)
        )
    assert acc["family"]["tip_tre_hidden_mm_worst"] == pytest.approx(
        max(r["tip_tre_hidden_mm"] for r in acc["bodies"])
    )
    # a 16 x 12 x 24 mm star cannot meet ART's 30 mm minimum distance: every body is named
    named = {v["body"] for v in doc["rules"]["violations"] if v["rule"] == "min_distance"}
    assert named == set(doc["confusion"]["labels"])


def test_check_same_seed_same_result(small_family, tmp_path):
    fam, _ = small_family
    docs = []
    for k in range(2):
        out = tmp_path / f"o{k}"
        assert (
            main(
                ["check", str(fam), "--frames", "40", "--curve", "0", "--seed", "3", "--out", str(out), "-q"]
            )
            == 0
        )
        d = json.loads((out / "check.json").read_text())
        d.pop("seconds")
        docs.append(d)
    assert docs[0] == docs[1]


def test_check_refuses_to_overwrite(checked, capsys):
    fam, out, _ = checked
    rc = main(["check", str(fam / "family.json"), "--frames", "5", "--out", str(out), "-q"])
    assert rc == 2
    assert "--force" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, message",
    [
        (["--noise", "-0.5"], "noise must be >= 0"),
        (["--drop", "2"], "drop must be <= markers - 3"),
        (["--preset", "nosuch"], "--preset must be a template name or a TOML file, got 'nosuch'"),
        (["--frames", "0"], "frames must be >= 1"),
        (["--tip", "1,2"], "tip must be three numbers"),
        (["--ghosts", "200", "--frames", "1"], "ghosts must be at most 20"),
        (["--ghosts", "1000000"], "ghosts must be at most 20"),
        (["--frames", "1e20"], "--frames"),
        (["--frames", "9000000", "--ghosts", "20"], "would take about"),
        (["--world", "flat"], "world must be open or closed"),
        (["--choose", "best"], "choose must be one of fit, sides, window"),
    ],
)
def test_bad_options_one_line_exit_2(small_family, tmp_path, capsys, args, message):
    fam, _ = small_family
    rc = main(["check", str(fam / "family.json"), "--frames", "5", *args, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_corrupt_json_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "family.json"
    bad.write_text('{"format": "starforge.family", "stars": [')
    rc = main(["check", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "not valid JSON" in err and err.count("\n") == 1


def test_check_on_two_placements(tmp_path):
    pos = np.array(
        [[0.0123, -0.0456, 0.1], [0.0781, 0.0029, 0.0333], [-0.05, 0.0611, 0.0207], [0.0017, 0.0091, -0.0642]]
    )

    def placement(path, p, name):
        markers = [
            {"position": list(x), "normal": [0, 0, 1], "site": i, "visibility": 1.0} for i, x in enumerate(p)
        ]
        doc = {
            "format": "starforge.placement",
            "version": 1,
            "prop": {"name": name},
            "markers": markers,
            "marker_diameter_m": 0.01,
        }
        path.write_text(json.dumps(doc))
        return path

    a = placement(tmp_path / "a.json", pos, "wand")
    b = placement(tmp_path / "b.json", pos[[0, 2, 1, 3]] * [1.0, -1.2, 0.9], "probe")
    out = tmp_path / "o"
    rc = main(["check", str(a), str(b), "--frames", "60", "--curve", "0", "--out", str(out), "-q"])
    assert rc == 0
    doc = json.loads((out / "check.json").read_text())
    assert doc["input"]["kind"] == "placement" and doc["confusion"]["labels"] == ["wand", "probe"]
    # the window is the bone tolerance starforge writes into vendor files for these bodies
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.tolerances import export_tolerances

    written = export_tolerances([x.points_mm for x in load_bodies([a, b]).bodies], 0.2)
    assert doc["settings"]["match_mm"] == written["bone_length_tolerance_mm"]
    assert doc["settings"]["residual_mm"] == written["maximum_residual_mm"]
    # placements are metres: the TRE uses the mm layout, at the prop's origin by default
    assert doc["accuracy"]["tip_mm"] == [0.0, 0.0, 0.0]
    wand = pos * 1000.0
    assert doc["accuracy"]["bodies"][0]["tip_tre_mm"] == pytest.approx(
        tre_rms(wand, [0, 0, 0], fle_from_sigma(0.2))
    )
    assert doc["identification_rate"] > 0.9


def test_check_a_labs_files_beside_a_family(small_family, tmp_path):
    """The question a lab asks: do my existing bodies and these new stars get along?"""
    from starforge.tracking.export import write_rigid_bodies

    fam, _ = small_family
    lab = tmp_path / "lab"
    write_rigid_bodies(fam / "family.json", ["vsk", "atracsys"], lab)
    first = sorted((lab / "vsk").glob("*.vsk"))[0]
    out = tmp_path / "o"
    args = [
        "check",
        fam / "family.json",
        first,
        "--frames",
        30,
        "--curve",
        0,
        "--choose",
        "fit",
        "--ambiguity",
        1,
        "--out",
        out,
        "-q",
    ]
    assert main([str(a) for a in args]) == 0
    doc = json.loads((out / "check.json").read_text())
    assert doc["input"]["kind"] == "mixed" and doc["input"]["files"][1] == str(first)
    # the lab's copy of star 1 is congruent with star 1: an open-world tracker confuses them
    M = np.array(doc["confusion"]["matrix"])
    assert M[0, -1] + M[-1, 0] > 0.3 * 2 * 30
    assert M[1:-1, :].sum() == M[1:-1, 1:-1].sum()  # the other stars are not involved
    assert doc["closest_triangles"][0]["margin_mm"] == 0.0
