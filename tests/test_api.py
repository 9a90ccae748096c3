"""The Python API: its examples run, its results are the CLI's, its refusals come before work."""

from __future__ import annotations

import doctest
import json

import numpy as np
import pytest

import starforge.api as sf
from starforge.errors import StarforgeError
from starforge.stars.model import load_family
from starforge.stars.verify import check_family

SMALL = {"box_mm": (14, 10, 30), "delta_mm": 2.0}


@pytest.fixture(scope="module")
def small_family():
    return sf.make_family(sf.plan_family(**SMALL, count=4))


@pytest.mark.slow
def test_every_docstring_example_runs(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    import importlib

    tried = 0
    for name in ("", ".stars", ".bodies", ".check", ".place", ".place_batch", ".sweep"):
        result = doctest.testmod(importlib.import_module("starforge.api" + name), optionflags=doctest.ELLIPSIS)
        assert result.failed == 0, name
        tried += result.attempted
    assert tried >= 12


def test_written_family_reloads_and_passes_the_independent_check(small_family, tmp_path):
    folder = sf.write_family(small_family, tmp_path / "f")
    data = json.loads((folder / "family.json").read_text())
    assert check_family(data) == []
    again = load_family(folder)
    assert [s.id for s in again.stars] == [s.id for s in small_family.stars]
    for a, b in zip(again.stars, small_family.stars, strict=True):
        assert np.allclose(a.lengths, b.lengths, atol=1e-9)
        # the written coordinates reproduce the edge lengths they claim
        V = np.asarray(a.vertices)
        pairs = [(0, 1), (2, 3), (1, 2), (0, 3), (0, 2), (1, 3)]  # (u, U), (v, V), (w, W)
        assert np.allclose([np.linalg.norm(V[i] - V[j]) for i, j in pairs], a.lengths, atol=1e-6)


def test_write_refuses_existing_files_and_changes_nothing(small_family, tmp_path):
    folder = sf.write_family(small_family, tmp_path / "f")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(StarforgeError, match="--force"):
        sf.write_family(small_family, folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_the_cli_writes_what_the_api_makes(small_family, tmp_path):
    from typer.testing import CliRunner

    from starforge.cli import app, click_command

    click_command()  # every command module loaded into app
    out = tmp_path / "cli"
    res = CliRunner().invoke(
        app, ["stars", "--box", "14", "10", "30", "--delta", "2", "--count", "4", "--name", "custom", "--out", str(out), "-q"]
    )
    assert res.exit_code == 0, res.output
    api_dir = sf.write_family(small_family, tmp_path / "api")
    assert (out / "family.json").read_bytes() == (api_dir / "family.json").read_bytes()


def test_a_seat_without_a_mount_is_refused_before_any_work():
    with pytest.raises(StarforgeError, match="--mount"):
        sf.plan_family(seat="glue")


def test_a_mount_plan_keeps_only_stars_whose_body_fits():
    plan = sf.plan_family("finger", count=3, mount="flat")
    assert plan.star_filter is not None and plan.spec.reserve_mm is not None
    fam = sf.make_family(plan)
    V = np.array([s.vertices for s in fam.stars])
    assert plan.star_filter(V).all()


# -- markers on a prop ---------------------------------------------------------------------------

#: a placement small enough for a test: one position, six orientations, few sites
TINY = {"sites": 150, "resolution": 1, "orientations": 6}


def _without_timings(doc):
    if isinstance(doc, dict):
        return {k: _without_timings(v) for k, v in doc.items() if k != "timings"}
    if isinstance(doc, list):
        return [_without_timings(x) for x in doc]
    return doc


def test_a_placement_plan_applies_every_option_and_designs_the_tolerance():
    from starforge.props.spec import load_spec, with_overrides
    from starforge.tracking.presets import design_tolerance_mm

    plan = sf.plan_placement("box", markers=5, sites=300, cameras_lost=0.25, grip="none", noise_mm=0.5)
    given = with_overrides(load_spec("default"), markers=5, sites=300, cameras_lost=0.25, hand=False)
    tol = max(given.track.avoid_tolerance_mm, design_tolerance_mm(None, 0.5, n_markers=5))
    assert plan.spec == with_overrides(given, distinct_mm=tol)
    assert plan.spec.track.avoid_tolerance_mm == pytest.approx(tol) and plan.grip is None
    assert plan.prop.name == "box" and plan.avoid_m is None
    # --no-hand wins over a pinned grip; a given distinct_mm is kept as it is
    plan = sf.plan_placement("box", hand=False, grip="1", distinct_mm=7.5)
    assert plan.grip is None and not plan.spec.hand and plan.spec.track.avoid_tolerance_mm == 7.5


def test_a_placement_plan_refuses_missing_files_and_bad_options_before_any_work(tmp_path):
    with pytest.raises(StarforgeError, match="--forbid-mesh"):
        sf.plan_placement("box", forbid_mesh=tmp_path / "none.stl")
    with pytest.raises(StarforgeError, match="markers must be in"):
        sf.plan_placement("box", markers=99)
    with pytest.raises(StarforgeError, match="seed must be >= 0"):
        sf.run_place("box", out=tmp_path / "p", seed=-1)
    assert not (tmp_path / "p").exists()


def test_a_batch_plan_names_every_job_once_and_refuses_before_any_work(tmp_path):
    plan = sf.plan_place_batch(["hammer", "box", "hammer"], copies=2, out=tmp_path / "b")
    names = [n for folders, _ in plan.jobs for n in folders]
    assert len({n.casefold() for n in names}) == len(names) == 6
    assert all(job[5] == 2 and job[7] == plan.distinct_mm for _, job in plan.jobs)
    assert len(plan.task_bytes) == len(plan.jobs) and min(plan.task_bytes) > 0
    with pytest.raises(StarforgeError, match="--copies"):
        sf.plan_place_batch(["box"], copies=0, out=tmp_path / "c")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "batch.csv").write_text("kept\n")
    with pytest.raises(StarforgeError, match="--force"):
        sf.plan_place_batch(["box"], out=tmp_path / "d")
    assert (tmp_path / "d" / "batch.csv").read_text() == "kept\n"


@pytest.mark.slow
def test_run_place_writes_what_the_cli_writes_and_the_score_re_scores_it(tmp_path):
    from starforge.cli import main

    run = sf.run_place("box", out=tmp_path / "api", seed=2, **TINY)
    assert sorted(run.files) == sorted(p.name for p in run.folder.iterdir())
    flags = ["--sites", "150", "--resolution", "1", "--orientations", "6", "--seed", "2"]
    assert main(["place", "box", *flags, "--out", str(tmp_path / "cli"), "-q"]) == 0
    for name in ("markers.csv", "prop_markers.glb"):
        assert (tmp_path / "api" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()
    docs = [json.loads((tmp_path / d / "placement.json").read_text()) for d in ("api", "cli")]
    assert _without_timings(docs[0]) == _without_timings(docs[1])
    # the written markers, scored again: the same markers, each seated; from the CSV as from the points
    score = sf.score_markers("box", tmp_path / "api" / "markers.csv", seed=2, **TINY)
    assert score.cost.markers == len(run.result.marker_sites) == len(score.visibility)
    assert all(score.extra["seated"]) and ((score.visibility >= 0) & (score.visibility <= 1)).all()
    assert 0.0 <= score.extra["tracked_fraction"] <= 1.0 and 0.0 <= score.extra["evaluation"]["tracked"] <= 1.0
    again = sf.score_markers("box", run.result.marker_points, seed=2, **TINY)
    assert again.to_json()["marker_visibility"] == score.to_json()["marker_visibility"]
    lines = sf.describe_score(score)
    assert lines[0].startswith(f"box: {score.cost.markers} markers") and any("tracked in" in x for x in lines)
