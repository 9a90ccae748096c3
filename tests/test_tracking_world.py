"""Identification as trackers do it: open world by default, closed world as a named option,
bodies that come and go, vendor presets whose simulation agrees with their own rule check, and
bounded cost for every setting."""

from __future__ import annotations

import json

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.tracking import identify as ident
from starforge.tracking.presets import load_preset
from tests.conftest import run_cli

# two bodies sharing a triangle exactly (A, B, C), differing only in the fourth marker: a
# tracker that sees one of them with D hidden cannot know which it is
SHARED = [
    np.array([[0.0, 0, 0], [31.0, 0, 0], [9.0, 23.0, 0], [12.0, 7.0, 19.0]]),
    np.array([[0.0, 0, 0], [31.0, 0, 0], [9.0, 23.0, 0], [20.0, -6.0, 26.0]]),
]


def _rates(world, presence=1.0, frames=3000, drop=1, min_markers=3):
    lib = ident.build_library(SHARED, ["a", "b"])
    t = ident.run(
        lib,
        frames,
        0.05,
        drop,
        0,
        np.random.default_rng(4),
        1.0,
        0.5,
        drop_exact=True,
        world=world,
        presence=presence,
        min_markers=min_markers,
    )
    return t, t.rates()


def test_open_world_sees_the_confusion_the_closed_world_hides():
    """With one marker hidden the shared triangle is all each cluster shows.  The closed world
    resolves it by giving each label once per frame; an open-world tracker cannot."""
    _, closed = _rates("closed")
    _, opened = _rates("open")
    # D hidden in a quarter of the scenes leaves the shared triangle, a tie: about half go wrong
    assert 0.08 < opened["wrong_body_rate"] < 0.17
    assert opened["wrong_body_rate"] > 1.4 * closed["wrong_body_rate"]
    # bodies that come and go break the closed world's assumption too
    _, closed_coming = _rates("closed", presence=0.5)
    assert closed_coming["wrong_body_rate"] > closed["wrong_body_rate"]


def test_presence_counts_only_bodies_that_are_there():
    t, _ = _rates("open", presence=0.5, frames=2000)
    assert t.frames == 2000 and 0.4 * 4000 < t.instances < 0.6 * 4000
    M = t.confusion
    assert M.sum() + t.flips.sum() + t.missed.sum() == t.instances


def test_four_marker_identification_never_reports_three():
    """ART identifies from subsets of 4 markers: with a marker hidden nothing is reported."""
    t, r = _rates("open", min_markers=4)
    assert r["identification_rate"] == 0.0 and r["wrong_body_rate"] == 0.0 and r["missed_rate"] == 1.0


@pytest.mark.slow
def test_art_preset_simulation_agrees_with_its_rules(small_family, tmp_path):
    fam, _ = small_family
    out = tmp_path / "art"
    args = [
        "check",
        fam / "family.json",
        "--preset",
        "art",
        "--frames",
        200,
        "--curve",
        0,
        "--out",
        out,
        "-q",
    ]
    assert run_cli(args) == 0
    doc = json.loads((out / "check.json").read_text())
    assert doc["settings"]["identify_from_markers"] == 4
    # half the frames hide a marker (drop 0..1): ART cannot identify those from 3 markers
    assert doc["identification_rate"] < 0.6
    assert doc["rules"]["sources"]["rules.distinct_mm"].startswith("https://www.ar-tracking.com")


# two chiral bodies whose triangles differ by 6.4 mm (more than every preset's window), ART-clean
CLEAN = [
    np.array([[27.6, -31.3, -37.5], [-7.7, 9.3, -37.2], [17.6, 31.3, -44.5], [-21.2, 25.6, 31.8]]),
    np.array([[-35.5, -23.6, 28.7], [-19.5, 17.4, 27.9], [24.4, 38.3, -23.2], [-9.6, 41.7, -15.2]]),
]
# a body with a half-turn symmetry (A<->B, C<->D) beside a clean one
SYMMETRIC = [np.array([[30.0, 0.0, 5.0], [-30.0, 0.0, 5.0], [0.0, 20.0, -5.0], [0.0, -20.0, -5.0]]), CLEAN[0]]
CONFUSIONS = {"symmetric", "congruent", "mirror_images", "shared_triangle", "own_triangles", "shared_markers"}


def _bodyset(points):
    from starforge.tracking.bodies import Body, BodySet

    return BodySet(
        "tracker", ("test",), tuple(Body(f"b{i}", i + 1, P, (0.0, 0.0, 0.0)) for i, P in enumerate(points))
    )


@pytest.mark.parametrize("preset", ["art", "ndi", "qualisys", "optitrack"])
@pytest.mark.parametrize("bodies", ["clean", "symmetric", "shared"])
def test_preset_simulation_agrees_with_its_own_rule_check(preset, bodies):
    """The rule check names a confusion exactly when the preset's simulated tracker makes one:
    both use the same window, marker count and mirror rule."""
    from starforge.tracking.check import CheckSettings, run_check

    points = {"clean": CLEAN, "symmetric": SYMMETRIC, "shared": SHARED}[bodies]
    p = load_preset(preset)
    exact = p.tracker.identify_markers == 3  # hide exactly one marker where three identify
    # the best-match tracker (nothing withheld as ambiguous): every confusion the geometry allows shows
    s = CheckSettings(
        noise_mm=0.02, drop=1, drop_exact=exact, frames=400, curve_points=0, preset=preset, seed=1, ambiguity=1.0
    )
    doc = run_check(_bodyset(points), s)
    listed = {v["rule"] for v in doc["rules"]["violations"]} & CONFUSIONS
    confused = doc["flip_rate"] + doc["wrong_body_rate"]
    assert doc["rules"]["window_mm"] == doc["settings"]["match_mm"]
    if listed:
        assert confused > 0.02, (listed, doc["identification_rate"])
    else:
        assert confused == 0.0 and doc["identification_rate"] > 0.45, doc["identification_rate"]


def test_qualisys_simulates_the_tolerances_its_files_carry(small_family, tmp_path):
    from starforge.tracking.export import write_rigid_bodies

    fam, _ = small_family
    summary = write_rigid_bodies(fam / "family.json", ["qtm"], tmp_path / "files")
    out = tmp_path / "check"
    args = [
        "check",
        fam / "family.json",
        "--preset",
        "qualisys",
        "--frames",
        50,
        "--curve",
        0,
        "--out",
        out,
        "-q",
    ]
    assert run_cli(args) == 0
    doc = json.loads((out / "check.json").read_text())
    assert doc["settings"]["match_mm"] == summary["qtm"]["bone_length_tolerance_mm"]
    assert doc["settings"]["residual_mm"] == summary["qtm"]["maximum_residual_mm"]
    assert doc["settings"]["choose"] == "fit"


def test_art_exact_drop_below_four_markers_is_refused(small_family, tmp_path, capsys):
    fam, _ = small_family
    args = ["check", fam, "--preset", "art", "--drop", 1, "--exact-drop", "--out", tmp_path / "o"]
    assert run_cli(args) == 2
    err = capsys.readouterr().err
    assert "fewer than the 4" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


def test_every_preset_cites_or_owns_its_numbers():
    from starforge.tracking.presets import preset_names

    for name in preset_names():
        p = load_preset(name)
        assert p.source
        for key, src in p.sources.items():
            section, field = key.split(".")
            assert hasattr(getattr(p, section), field), key
            assert src.startswith("http"), key


@pytest.mark.parametrize(
    "kw,needle",
    [
        ({"ghosts": 200}, "ghosts must be at most 20"),
        ({"frames": 10**12}, "frames must be at most"),
        ({"frames": 9_000_000, "ghosts": 20}, "would take about"),
    ],
)
def test_settings_have_bounded_cost(kw, needle):
    lib = ident.build_library(SHARED, ["a", "b"])
    args = {"noise_mm": 0.1, "drop": 1, "ghosts": 0, "frames": 10, "match_mm": 1.0, "residual_mm": 0.5, **kw}
    with pytest.raises(StarforgeError, match=needle):
        ident.check_settings(lib, **args)


def test_mirror_blind_tracker_tries_both_fits_of_three_points():
    """Three points fit their mirror image as well as themselves; a mirror-blind tracker that
    kept only one of the two would predict the fourth marker on the wrong side in about half
    the triangles and miss bodies it sees whole."""
    lib = ident.build_library(CLEAN, ["a", "b"])
    t = ident.run(
        lib, 500, 0.05, 0, 0, np.random.default_rng(2), 2.0, 1.0, reflect=True, min_markers=4, choose="fit"
    )
    assert t.correct == t.instances
