"""Families designed for a tracker: the key margin follows from its window and the noise, the
tolerances written into vendor files are ones the family is safe under, and the family made for
a preset and checked with it shows no wrong body and no wrong pose."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.stats import norm

from starforge.tracking import identify as ident
from starforge.tracking import library
from starforge.tracking.bodies import load_bodies
from starforge.tracking.presets import design_tolerance_mm, preset_names
from starforge.tracking.tolerances import bone_tolerance_noise_mm, design_margin_mm, export_tolerances
from tests.conftest import run_cli


@pytest.mark.parametrize("noise", [0.05, 0.2, 0.5])
@pytest.mark.parametrize("window", [None, 0.5, 2.0])
def test_the_design_margin_keeps_wrong_faces_out_and_right_ones_in(noise, window):
    m = design_margin_mm(noise, window)
    lower = bone_tolerance_noise_mm(noise, 4)
    w = lower if window is None else max(window, lower)
    # a wrong face, m away, measured at least m - lower away, stays outside the window
    assert m - lower >= w - 1e-12
    # the tolerance written (half the margin) keeps the right frames and is >= 3 sigma of a distance
    assert m / 2 >= lower >= 3 * noise * math.sqrt(2)
    # the noise tolerance re-derived by hand: every one of 6 distances within it w.p. 1 - 1e-4
    z = norm.isf(1e-4 / 6 / 2)
    assert lower == pytest.approx(noise * math.sqrt(2) * z, rel=1e-9)


def test_every_preset_designs_a_tolerance():
    assert {"vicon", "atracsys"} <= set(preset_names())
    for name in preset_names():
        t = design_tolerance_mm(name, 0.2)
        assert t >= design_margin_mm(0.2)  # never under what the noise alone asks
    assert design_tolerance_mm("art", 0.2, floor_mm=5.0) == 5.0  # ART's 5 mm distinct distances


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["qualisys", "vicon"])
def test_a_family_made_for_a_preset_is_safe_under_it(preset, tmp_path):
    fam = tmp_path / "fam"
    args = [
        "stars",
        "--box",
        18,
        14,
        28,
        "--delta",
        1.5,
        "--preset",
        preset,
        "--noise",
        0.2,
        "--out",
        fam,
        "-q",
    ]
    assert run_cli(args) == 0
    doc = json.loads((fam / "family.json").read_text())
    bodies = load_bodies(fam / "family.json")
    lib = ident.build_library([b.points_mm for b in bodies.bodies])
    margin = library.drop1_margin_mm(lib)
    # the key margin (faces, and faces relabelled) is at least the designed one
    assert (
        margin >= design_margin_mm(0.2) - 1e-6 and doc["spec"]["tolerance_mm"] >= design_margin_mm(0.2) - 1e-6
    )
    t = export_tolerances([b.points_mm for b in bodies.bodies], 0.2)
    assert "note" not in t
    assert 3 * 0.2 * math.sqrt(2) <= t["bone_length_tolerance_mm"] <= margin / 2 + 1e-9
    out = tmp_path / "chk"
    args = ["check", fam / "family.json", "--preset", preset, "--noise", 0.2, "--frames", 300, "--curve", 0]
    assert run_cli([*args, "--out", out, "-q"]) == 0
    chk = json.loads((out / "check.json").read_text())
    for rule in ident.HEADLINE_RULES:
        r = chk["by_rule"][rule]
        assert r["wrong_body_rate"] == 0 and r["flip_rate"] == 0
        assert r["identification_rate"] >= 0.999
    assert set(chk["safe_under"]) == set(ident.HEADLINE_RULES)
    assert np.isclose(chk["settings"]["match_mm"], t["bone_length_tolerance_mm"])


def test_a_family_closer_than_the_tracker_needs_is_warned_of():
    """A face-rule spec whose faces are closer than the design margin at its noise gets a warning
    naming the margin and the options that design for a tracker; a designed one and the paper's
    pair rule get none."""
    from starforge.api import plan_family
    from starforge.api.stars import tolerance_warning

    close = plan_family(box_mm=(18, 14, 28)).spec
    text = tolerance_warning(close)
    assert close.tol_mm < design_margin_mm(0.2)
    assert f"{design_margin_mm(0.2):.2f} mm" in text and "--noise" in text and "--preset" in text
    assert tolerance_warning(plan_family(box_mm=(18, 14, 28), noise_mm=0.2).spec) is None
    assert tolerance_warning(plan_family("finger").spec) is None
    assert tolerance_warning(plan_family("paper").spec) is None
    assert tolerance_warning(plan_family(box_mm=(18, 14, 28), tolerance_mm=design_margin_mm(0.2)).spec) is None
