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

    from starforge.cli import _load_commands, app

    _load_commands()
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
