"""The selection's proof budget is deterministic work (nonzeros x solver nodes), never the wall
clock: the same spec gives the same family, bound and verdict on a fast or a slow machine."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.stars import select as sel
from starforge.stars.family import make_family
from starforge.stars.spec import StarSpec, spec_from_mapping

SPEC = {"box_mm": (16.0, 12.0, 24.0), "delta_mm": 2.0}


def _without_timings(fam) -> str:
    doc = fam.to_json()
    doc.pop("timings", None)
    doc["summary"]["selection"] = {
        k: v for k, v in doc["summary"]["selection"].items() if not k.endswith("_s")
    }
    return json.dumps(doc, sort_keys=True)


def test_the_solver_gets_the_specs_node_budget_and_no_time_limit(monkeypatch):
    seen = []

    def fake(ptr, rows, n_rows, cols, time_limit, node_limit=sel.MILP_NODE_LIMIT):
        seen.append((time_limit, node_limit, len(rows)))
        return np.zeros(0, dtype=np.intp), None, "node limit", True

    monkeypatch.setattr(sel, "milp", fake)
    for work in (50_000, 5_000_000):
        seen.clear()
        make_family(StarSpec(**SPEC, work=work))
        assert seen, "the exact solver ran"
        for time_limit, nodes, nnz in seen:
            assert time_limit is None
            assert nodes == sel.node_budget(nnz, work)
    # more work, more nodes (the default's cap scales with it)
    assert sel.node_budget(1000, 80_000_000) == 10 * sel.node_budget(1000, 8_000_000)


@pytest.mark.slow
def test_a_slow_clock_changes_nothing(monkeypatch):
    """The same family when every clock reading jumps by 1000 s (a machine at any load)."""
    spec = StarSpec(**SPEC, work=200_000)  # a few dozen nodes: fast, and cut before the proof
    first = make_family(spec)
    import time

    ticks = itertools.count()
    real = time.perf_counter
    monkeypatch.setattr(time, "perf_counter", lambda: real() + 1000.0 * next(ticks))
    monkeypatch.setattr(time, "monotonic", lambda: real() + 1000.0 * next(ticks))
    second = make_family(spec)
    assert _without_timings(first) == _without_timings(second)
    assert first.summary["upper_bound"] >= len(first.stars)  # the bound stays certified


def test_work_is_validated_and_old_files_load():
    with pytest.raises(StarforgeError, match="work must be an integer"):
        StarSpec(**SPEC, work=0)
    old = {**SPEC, "time_limit_s": 60.0}  # family files written before the work budget
    assert spec_from_mapping(old).work == StarSpec(**SPEC).work


def test_count_builds_no_key_windows_larger_than_the_whole_familys(monkeypatch):
    """--count N raises the face separation only while its key windows take no more memory than
    selecting among every candidate at the tolerance itself."""
    from starforge.stars import family as fam_mod
    from starforge.stars.rules import window_bytes

    calls = []
    real = fam_mod.window_rows

    def spy(index, rule, m, pool_size):
        calls.append((len(index), rule, m))
        return real(index, rule, m, pool_size)

    monkeypatch.setattr(fam_mod, "window_rows", spy)
    spec = StarSpec(**SPEC, count=5, tolerance_mm=2.0)
    fam = make_family(spec)
    assert len(fam.stars) == 5
    n_all, rule, m = max(calls, key=lambda c: c[0])  # the whole candidate set at the tolerance
    assert m == spec.grid_steps
    for n, r, mm in calls:
        assert window_bytes(n, r, mm) <= window_bytes(n_all, rule, m)
