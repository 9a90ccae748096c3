"""The exact ceiling on a scenario sample (starforge.props.ceiling), re-checked by brute force
with the objective's own rule (Problem.terms) on every spaced layout."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from starforge.props.ceiling import spaced_layouts, tracked_ceiling
from starforge.props.tracked import Problem, TrackSettings


def _brute_layouts(P, spacing, k):
    d = np.linalg.norm(P[:, None] - P[None], axis=2)
    out = set()
    for r in range(3, k + 1):
        for c in itertools.combinations(range(len(P)), r):
            if all(d[a, b] >= spacing for a, b in itertools.combinations(c, 2)):
                out.add(c)
    return out


@pytest.mark.parametrize("seed", range(4))
def test_spaced_layouts_are_every_clique(seed):
    rng = np.random.default_rng(seed)
    P = rng.random((14, 3)) * 0.08
    for spacing, k in ((0.02, 4), (0.035, 5), (0.06, 3)):
        got = spaced_layouts(P, spacing, k)
        rows = {tuple(int(i) for i in r if i >= 0) for r in got}
        assert len(rows) == len(got)  # no layout twice
        assert rows == _brute_layouts(P, spacing, k)


@pytest.mark.parametrize("seed", range(3))
def test_ceiling_is_the_best_layout_under_the_objectives_rule(seed):
    rng = np.random.default_rng(100 + seed)
    P = rng.random((12, 3)) * 0.1
    seen = rng.random((12, 300)) < 0.55
    spacing = 0.03
    prob = Problem(P, seen, seen.mean(axis=1), TrackSettings(), spacing, 0.03)
    got = tracked_ceiling(P, lambda: seen, spacing, prob.min_spread2, 5)
    brute = {c: 1.0 - prob.terms(list(c), symmetry=False)["untracked"] for c in _brute_layouts(P, spacing, 5)}
    assert got["layouts"] == len(brute)
    assert got["ceiling"] == pytest.approx(max(brute.values()), abs=1e-12)
    assert brute[tuple(got["best"])] == pytest.approx(got["ceiling"], abs=1e-12)


def test_no_ceiling_claimed_past_the_cap(monkeypatch):
    from starforge.props import ceiling

    P = np.random.default_rng(0).random((30, 3))
    monkeypatch.setattr(ceiling, "MAX_LAYOUTS", 5)
    assert spaced_layouts(P, 0.1, 4, cap=5) is None
    built = []
    assert tracked_ceiling(P, lambda: built.append(1), 0.1, 0.0, 4) is None
    assert not built  # the scenario table is never built when the count is past the cap
