"""Iterated local search for family selection: valid, deterministic, no worse than the local
search, within the bound, optimal on a small instance, incremental bookkeeping exact."""

from __future__ import annotations

import numpy as np
import pytest

import starforge.stars.select as sel
from starforge.stars.bounds import block_bound
from starforge.stars.enumerate import enumerate_candidates
from starforge.stars.packing import FAMILY_BIT, Packing
from starforge.stars.rules import grid_steps, internal_ok, key_points, window_rows
from starforge.stars.select import (
    compactness_order,
    csr_rows,
    greedy,
    ils,
    local_search,
    milp,
    select_family,
)
from starforge.stars.spec import StarSpec

SPEC = StarSpec(box_mm=(16, 12, 24), delta_mm=2.0)


@pytest.fixture(scope="module")
def cands():
    return enumerate_candidates(SPEC)


def instance(cands, rule: str, m: int = 1):
    ok = internal_ok(cands.index, rule, m)
    index, volume = cands.index[ok], cands.box_volume[ok]
    star_of, row, n_rows = window_rows(index, rule, m, len(cands.pool_mm))
    ptr, rows = csr_rows(star_of, row, len(index))
    order = compactness_order(index, cands.pool_mm, volume)
    return index, volume, star_of, row, n_rows, ptr, rows, order


def assert_packing(chosen, ptr, rows, n_rows):
    """Independent check: every chosen star's rows are disjoint from every other's."""
    chosen = np.asarray(chosen)
    assert len(np.unique(chosen)) == len(chosen)
    used = np.zeros(n_rows, dtype=int)
    for s in chosen.tolist():
        used[rows[ptr[s] : ptr[s + 1]]] += 1
    assert used.max(initial=0) <= 1


@pytest.mark.parametrize("rule,m", [("face", 1), ("pair", 1), ("face", 2), ("pair", 2)])
def test_ils_valid_deterministic_bounded(cands, rule, m):
    index, _, _, _, n_rows, ptr, rows, order = instance(cands, rule, m)
    g = greedy(order, ptr, rows, n_rows)
    ls, _ = local_search(g, order, ptr, rows, n_rows)
    bound = block_bound(index, m)
    a, ia = ils(ls, order, ptr, rows, n_rows, iterations=300, bound=bound)
    b, ib = ils(ls, order, ptr, rows, n_rows, iterations=300, bound=bound)
    assert_packing(a, ptr, rows, n_rows)
    assert len(a) >= len(ls)
    assert len(a) <= bound
    assert ia == ib and np.array_equal(a, b)
    # maximal: no free candidate left out
    used = np.zeros(n_rows, dtype=bool)
    for s in a.tolist():
        used[rows[ptr[s] : ptr[s + 1]]] = True
    free = [
        c
        for c in range(len(ptr) - 1)
        if c not in set(a.tolist()) and not used[rows[ptr[c] : ptr[c + 1]]].any()
    ]
    assert free == []


def test_ils_variable_row_counts(cands):
    """Any row counts (m > 1 gives varying ones): drop random entries of the pair incidence."""
    _, _, star_of, row, n_rows, _, _, order = instance(cands, "pair")
    keep = np.random.default_rng(3).random(len(row)) < 0.6
    ptr, rows = csr_rows(star_of[keep], row[keep], len(order))
    assert len(np.unique(np.diff(ptr))) > 3
    g = greedy(order, ptr, rows, n_rows)
    ls, _ = local_search(g, order, ptr, rows, n_rows)
    a, _ = ils(ls, order, ptr, rows, n_rows, iterations=300)
    b, _ = ils(ls, order, ptr, rows, n_rows, iterations=300)
    assert_packing(a, ptr, rows, n_rows)
    assert np.array_equal(a, b) and len(a) >= len(ls)


@pytest.mark.slow
def test_ils_reaches_milp_optimum(cands):
    """Face rule: HiGHS proves the optimum on this instance (the pair rule's MILP takes too long)."""
    rule = "face"
    index, _, _, _, n_rows, ptr, rows, order = instance(cands, rule)
    g = greedy(order, ptr, rows, n_rows)
    ls, _ = local_search(g, order, ptr, rows, n_rows)
    opt, dual, status, _ = milp(ptr, rows, n_rows, np.arange(len(index)), 60.0, node_limit=100000)
    assert status == "optimal"
    best, used = ils(ls, order, ptr, rows, n_rows, iterations=2000, bound=len(opt))
    assert_packing(best, ptr, rows, n_rows)
    assert len(best) == len(opt)
    assert used <= 2000
    assert len(best) > len(ls) or len(ls) == len(opt)


def test_ils_stops_at_bound(cands):
    _, _, _, _, n_rows, ptr, rows, order = instance(cands, "face")
    g = greedy(order, ptr, rows, n_rows)
    out, used = ils(g, order, ptr, rows, n_rows, iterations=500, bound=len(g))
    assert used == 0 and len(out) >= len(g)


@pytest.mark.parametrize("by_keys", [False, True])
def test_packing_bookkeeping_matches_recount(cands, by_keys):
    """After random inserts/removes (and an undo), the incremental tallies equal a full recount
    (by rows; with neighbours found by key points, the 1-tight and free states do)."""
    index, _, _, _, n_rows, ptr, rows, order = instance(cands, "pair", 2)
    n = len(ptr) - 1
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    points = key_points(index, "pair", 2, len(cands.pool_mm)) if by_keys else None
    P = Packing(greedy(order, ptr, rows, n_rows), ptr, rows, n_rows, rank, points)
    rng = np.random.default_rng(1)

    def check():
        owner = P.owner[:n_rows]
        fam = np.flatnonzero(P.in_fam)
        assert_packing(fam, ptr, rows, n_rows)
        for s in fam.tolist():
            assert (owner[rows[ptr[s] : ptr[s + 1]]] == s).all()
        assert (owner >= 0).sum() == sum(ptr[s + 1] - ptr[s] for s in fam.tolist())
        tight = np.full(n, -1)
        for c in range(n):
            own = owner[rows[ptr[c] : ptr[c + 1]]]
            own = own[own >= 0]
            if not by_keys:
                assert P.cnt[c] == len(own)
                assert P.s1[c] == own.sum() and P.s2[c] == (own * own).sum()
            one = len(own) > 0 and len(np.unique(own)) == 1 and not P.in_fam[c]
            tight[c] = own[0] if one else (-2 if not len(own) and not P.in_fam[c] else -1)
        assert np.array_equal(P.tight, tight)
        assert np.array_equal(P.ntight, np.bincount(tight[tight >= 0], minlength=n))
        # the family flag kept beside the counts
        assert np.array_equal(P.tally[:, 0] >> FAMILY_BIT, P.in_fam)

    check()
    ops = []
    for _ in range(60):
        c = int(rng.integers(n))
        if P.in_fam[c]:
            P.remove(c)
        else:
            for t in np.unique(P.owner[rows[ptr[c] : ptr[c + 1]]]).tolist():
                if t >= 0:
                    P.remove(t)
            P.insert(c)
    check()
    before = P.in_fam.copy()
    for _ in range(10):
        fam = np.flatnonzero(P.in_fam)
        if len(fam):
            s = int(fam[rng.integers(len(fam))])
            P.remove(s)
            ops.append(-(s + 1))
        free = np.flatnonzero(~P.in_fam & (P.cnt == 0))
        if len(free):
            P.insert(int(free[0]))
            ops.append(int(free[0]) + 1)
    P.undo(np.array(ops))
    assert np.array_equal(P.in_fam, before)
    check()


def test_select_family_records_ils(cands, monkeypatch):
    index, volume, star_of, row, n_rows, ptr, rows, order = instance(cands, "face")
    monkeypatch.setattr(sel, "MILP_MAX_NONZEROS", 0)  # ILS result is final
    spec = StarSpec(box_mm=(16, 12, 24), delta_mm=2.0)
    a = select_family(index, cands.pool_mm, volume, star_of, row, n_rows, spec)
    b = select_family(index, cands.pool_mm, volume, star_of, row, n_rows, spec)
    assert np.array_equal(a.chosen, b.chosen)
    assert a.info["ils"] == len(a.chosen) >= a.info["local_search"]
    assert 0 <= a.info["ils_iterations"] <= sel.ILS_ITERATIONS
    assert "ils_s" in a.info
    assert all(not k.endswith("_s") or isinstance(v, float) for k, v in a.info.items())
    assert_packing(a.chosen, ptr, rows, n_rows)
    none = select_family(index, cands.pool_mm, volume, star_of, row, n_rows, spec, ils_iterations=0)
    assert none.info["ils_iterations"] == 0 and none.info["ils"] == none.info["local_search"]
    assert grid_steps(spec.tol_mm, spec.delta_mm) == 1


def test_packing_refuses_counts_its_tallies_cannot_hold():
    """A candidate that may meet the family more often than the packed count holds: a clear
    ValueError, before any search."""
    many = (1 << 22) + 1  # one star on more rows than the count's bits hold
    ptr = np.array([0, many, many + 1], dtype=np.int64)
    rows = np.arange(many + 1, dtype=np.int64)
    with pytest.raises(ValueError, match="tallies cannot hold"):
        Packing(np.zeros(0, dtype=np.int64), ptr, rows, many + 1, np.arange(2))
