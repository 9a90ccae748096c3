"""``starforge place-batch``: every job not placed again to keep clear of another equals the single
``place`` run, in process and on a 2-worker local cluster; nothing is published on error."""

from __future__ import annotations

import csv
import json
import re

import pytest

from starforge.cli import main

SPEC = """
description = "small and quick"
objective = "tracked"
sites = 200
resolution = 2
orientations = 4
rig = "default"
mesh_format = "stl"

[track]
marker_mm = 9.5
iterations = 300
stall = 200
restarts = 1
"""


def _markers(folder):
    doc = json.loads((folder / "placement.json").read_text())
    return doc["markers"], doc["cost"]["total"]


@pytest.mark.parametrize(
    "props, workers, extra",
    [
        pytest.param(("hammer",), "1", (), marks=pytest.mark.slow),  # in this process
        pytest.param(("hammer", "sword"), "2", (), marks=pytest.mark.slow),  # on a 2-worker local cluster
        pytest.param(("hammer",), "1", ("--standoff", "15"), marks=pytest.mark.slow),  # markers on posts
    ],
)
def test_batch_equals_single_runs(tmp_path, props, workers, extra):
    spec = tmp_path / "quick.toml"
    spec.write_text(SPEC)
    out = tmp_path / "batch"
    rc = main(["place-batch", *props, "--spec", str(spec), *extra, "--workers", workers, "--out", str(out), "-q"])
    assert rc == 0
    rows = {r["job"]: r for r in csv.DictReader((out / "batch.csv").read_text().splitlines())}
    assert list(rows) == list(props)
    for prop in props:
        if rows[prop]["placed_again"] == "1":  # placed again to keep clear of another: not a single run
            continue
        single = tmp_path / f"single-{prop}"
        assert main(["place", prop, "--spec", str(spec), *extra, "--out", str(single), "-q"]) == 0
        assert _markers(out / prop) == _markers(single)
        for name in ("markers.csv", "standoff.stl"):
            assert (out / prop / name).exists() == (single / name).exists() == (name != "standoff.stl" or bool(extra))
            if (single / name).exists():
                assert (out / prop / name).read_bytes() == (single / name).read_bytes()


def test_batch_bad_prop_publishes_nothing(tmp_path, capsys):
    out = tmp_path / "batch"
    rc = main(["place-batch", "hammer", "no-such-prop.stl", "--workers", "1", "--out", str(out), "-q"])
    assert rc == 2
    # the plain progress line a slow machine may print first is not part of the refusal
    err = [line for line in capsys.readouterr().err.splitlines() if not re.match(r"^starforge [a-z-]+: \d+ s, ", line)]
    assert len(err) == 1 and err[0].startswith("error: ")
    assert not out.exists()
