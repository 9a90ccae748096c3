"""Bodies of any marker count in ``check`` (3-marker bodies: no hidden-marker case, valid JSON),
and identification under every ranking rule, headlined by the worst rule trackers document."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from starforge.tracking import identify as ident
from tests.conftest import run_cli

THREE = "[geometry]\ncount=3\nid=7\n[fiducial0]\nx=0\ny=0\nz=0\n[fiducial1]\nx=50\ny=0\nz=0\n[fiducial2]\nx=0\ny=35\nz=0\n"
FIVE = (
    "body,marker,x_mm,y_mm,z_mm\n"
    "probe,1,0,0,0\nprobe,2,61,0,0\nprobe,3,0,44,0\nprobe,4,0,0,29\nprobe,5,23,17,52\n"
)


def test_three_and_five_marker_bodies_beside_a_family(small_family, tmp_path):
    fam, _ = small_family
    (tmp_path / "three.ini").write_text(THREE)
    (tmp_path / "probe.csv").write_text(FIVE)
    out = tmp_path / "o"
    args = ["check", fam / "family.json", tmp_path / "three.ini", tmp_path / "probe.csv"]
    assert run_cli([*args, "--frames", 40, "--drop", 2, "--curve", 2, "--out", out, "-q"]) == 0
    doc = json.loads((out / "check.json").read_text())  # strict JSON: no inf, no NaN
    assert doc["input"]["markers_per_body"] == [3, 4, 5]
    # drop 2: only the 5-marker body can hide 2; the 3-marker body never hides one
    assert "three" in doc["input"]["bodies_never_hiding_a_marker"]
    rows = {r["body"]: r for r in doc["accuracy"]["bodies"]}
    assert rows["three"]["tip_tre_hidden_mm"] is None and rows["probe"]["tip_tre_hidden_mm"] > 0
    assert "three" in doc["accuracy"]["family"]["bodies_without_hidden_case"]
    # every rule reported, the headline is the worst of the headline rules (never a stress model)
    assert set(doc["by_rule"]) == set(ident.RULES)
    assert doc["headline_rule"] in ident.HEADLINE_RULES
    worst = min(doc["by_rule"][r]["identification_rate"] for r in ident.HEADLINE_RULES)
    assert doc["identification_rate"] == worst == doc["by_rule"][doc["headline_rule"]]["identification_rate"]
    assert {r for r, v in doc["by_rule"].items() if v["kind"] == "stress"} == set(ident.STRESS_RULES)
    # the plot's curve is the headline's rule
    assert doc["curve"]["rule"] == doc["headline_rule"]
    # the 3-marker body (far from every star) is always identified whole
    i = doc["confusion"]["labels"].index("three")
    assert doc["confusion"]["matrix"][i][i] == 40


def test_sides_key_is_the_sorted_distance_difference_and_blind_to_flips():
    rng = np.random.default_rng(5)
    P = rng.normal(0, 20, size=(4, 3))
    lib = ident.build_library([P])
    obs = P + rng.normal(0, 0.3, size=P.shape)
    pts = obs[None]
    right = np.arange(4)
    swapped = np.array([1, 0, 2, 3])
    h = ident.Hypotheses(
        np.zeros(2, dtype=int), np.zeros(2, dtype=int), np.stack([right, swapped]), np.full(2, 4), np.zeros(2)
    )
    key = ident.sides_key(lib, pts, h)
    pairs = list(itertools.combinations(range(4), 2))
    d_obs = sorted(np.linalg.norm(obs[a] - obs[b]) for a, b in pairs)
    d_mod = sorted(np.linalg.norm(P[a] - P[b]) for a, b in pairs)
    brute = max(abs(x - y) for x, y in zip(d_obs, d_mod, strict=True))
    assert np.allclose(key, brute)  # both: correspondence-blind


def test_the_qualisys_preset_simulates_the_tolerances_written_into_qtm_files(small_family, tmp_path):
    import xml.etree.ElementTree as ET

    fam, _ = small_family
    for noise in (0.1, 0.3):
        lab = tmp_path / f"n{noise}"
        assert (
            run_cli(["export", fam / "family.json", "--format", "qtm", "--noise", noise, "--out", lab, "-q"])
            == 0
        )
        body = ET.parse(sorted((lab / "qtm").glob("*.xml"))[0]).getroot().find("The_6D/Body")
        bone = float(body.findtext("BoneLengthTolerance"))
        resid = float(body.findtext("MaximumResidual"))
        summary = json.loads((lab / "trackers.json").read_text())
        assert summary["tolerances"]["noise_mm"] == noise
        out = tmp_path / f"c{noise}"
        args = ["check", fam / "family.json", "--preset", "qualisys", "--noise", noise, "--frames", 10]
        assert run_cli([*args, "--curve", 0, "--out", out, "-q"]) == 0
        s = json.loads((out / "check.json").read_text())["settings"]
        assert (s["match_mm"], s["residual_mm"]) == (bone, resid)
    # a noisier lab gets wider gates (the residual limit scales with the noise)
    assert resid == pytest.approx(3 * summary_resid_at(fam, 0.1), rel=1e-5)


def summary_resid_at(fam, noise):
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.tolerances import export_tolerances

    return export_tolerances([b.points_mm for b in load_bodies(fam / "family.json").bodies], noise)[
        "maximum_residual_mm"
    ]
