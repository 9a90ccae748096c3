"""``starforge place-batch``: every job equals the single ``place`` run, in process and on a
2-worker local cluster; nothing is published on error."""

from __future__ import annotations

import json

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


def test_batch_equals_single_runs(tmp_path):
    spec = tmp_path / "quick.toml"
    spec.write_text(SPEC)
    out = tmp_path / "batch"
    rc = main(["place-batch", "hammer", "sword", "--spec", str(spec), "--workers", "2", "--out", str(out), "-q"])
    assert rc == 0
    assert (out / "batch.csv").read_text().splitlines()[0] == "job,prop,rig,markers,total_cost"
    for prop in ("hammer", "sword"):
        single = tmp_path / f"single-{prop}"
        assert main(["place", prop, "--spec", str(spec), "--out", str(single), "-q"]) == 0
        assert _markers(out / prop) == _markers(single)
        assert (out / prop / "markers.csv").read_bytes() == (single / "markers.csv").read_bytes()


def test_batch_bad_prop_publishes_nothing(tmp_path, capsys):
    out = tmp_path / "batch"
    rc = main(["place-batch", "hammer", "no-such-prop.stl", "--workers", "1", "--out", str(out), "-q"])
    assert rc == 2
    assert capsys.readouterr().err.startswith("error: ")
    assert not out.exists()
