"""The key-window formulation of both rules against brute-force definitions."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from starforge.geometry.tetra import RELABELLINGS, face_sides
from starforge.stars.bounds import block_bound
from starforge.stars.enumerate import enumerate_candidates
from starforge.stars.rules import grid_steps, internal_ok, window_rows
from starforge.stars.select import compactness_order, greedy, local_search, milp
from starforge.stars.spec import StarSpec

SPEC = StarSpec(box_mm=(16, 12, 24), delta_mm=2.0)


@pytest.fixture(scope="module")
def cands():
    return enumerate_candidates(SPEC)


@pytest.fixture(scope="module")
def fine_cands():
    return enumerate_candidates(StarSpec(box_mm=(16, 12, 24), delta_mm=1.0))


def brute_pair_conflict(a: np.ndarray, b: np.ndarray, steps: int) -> bool:
    """The paper's rule read literally: stars a and b (pool indices) are told apart iff under every
    relabelling of b some opposite pair has both lengths differing by >= steps."""
    for r in RELABELLINGS:
        bb = b[r]
        if not any(abs(a[2 * k] - bb[2 * k]) >= steps and abs(a[2 * k + 1] - bb[2 * k + 1]) >= steps for k in range(3)):
            return True
    return False


def brute_face_conflict(a: np.ndarray, b: np.ndarray, steps: int) -> bool:
    fa, fb = face_sides(a.astype(float)), face_sides(b.astype(float))
    return any((np.abs(x - y) < steps).all() for x in fa for y in fb)


def conflicts_from_rows(index, rule, m, pool_size):
    star, row, _ = window_rows(index, rule, m, pool_size)
    rows_of = [set() for _ in range(len(index))]
    for s, r in zip(star.tolist(), row.tolist(), strict=True):
        rows_of[s].add(r)
    return rows_of


@pytest.mark.parametrize("rule,m", [("face", 1), ("pair", 1), ("face", 2), ("pair", 2)])
def test_window_conflicts_equal_brute_force(cands, fine_cands, rule, m):
    if m > 1:
        cands = fine_cands
    rng = np.random.default_rng(7)
    idx = cands.index[rng.choice(len(cands), 160, replace=False)].astype(int)
    idx = idx[internal_ok(idx, rule, m)]
    rows_of = conflicts_from_rows(idx, rule, m, len(cands.pool_mm))
    brute = brute_pair_conflict if rule == "pair" else brute_face_conflict
    checked = 0
    for i, j in itertools.combinations(range(len(idx)), 2):
        assert bool(rows_of[i] & rows_of[j]) == brute(idx[i], idx[j], m), (idx[i], idx[j])
        checked += 1
    assert checked > 1000


def test_face_rule_is_implied_by_pair_rule(cands):
    # a pair-rule conflict-free family never shares a face key, so pair families are face families
    idx = cands.index[:300].astype(int)
    pair_rows = conflicts_from_rows(idx, "pair", 1, len(cands.pool_mm))
    face_rows = conflicts_from_rows(idx, "face", 1, len(cands.pool_mm))
    for i, j in itertools.combinations(range(len(idx)), 2):
        if face_rows[i] & face_rows[j]:
            assert pair_rows[i] & pair_rows[j]


def test_grid_steps():
    assert grid_steps(1.5, 1.5) == 1
    assert grid_steps(2.0, 1.5) == 2
    assert grid_steps(3.0, 1.5) == 2
    assert grid_steps(0.5, 1.5) == 1


def _packing_ok(chosen, star, row):
    used = {}
    for s, r in zip(star.tolist(), row.tolist(), strict=True):
        if s in set(chosen.tolist()):
            if r in used and used[r] != s:
                return False
            used[r] = s
    return True


@pytest.mark.parametrize("rule", ["face", "pair"])
@pytest.mark.parametrize("n", [100, pytest.param(200, marks=pytest.mark.slow)])
def test_selection_is_a_packing_and_milp_is_optimal(cands, rule, n):
    keep = np.random.default_rng(5).choice(len(cands), n, replace=False)
    idx = cands.index[np.sort(keep)]
    star, row, n_rows = window_rows(idx, rule, 1, len(cands.pool_mm))
    order_ = np.argsort(star, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(star, minlength=len(idx)))])
    rows = row[order_]
    order = compactness_order(idx, cands.pool_mm, cands.box_volume[np.sort(keep)])
    g = greedy(order, ptr, rows, n_rows)
    ls, _ = local_search(g, order, ptr, rows, n_rows)
    opt, dual, status, _ = milp(ptr, rows, n_rows, np.arange(len(idx)), 60, node_limit=100000)
    assert status == "optimal"
    for fam in (g, ls, opt):
        assert _packing_ok(fam, star, row)
    assert len(g) <= len(ls) <= len(opt) <= block_bound(idx, 1)
    assert dual is None or len(opt) <= dual


def test_milp_matches_exhaustive_search_on_a_tiny_instance(cands):
    # 14 candidates: try every subset
    idx = cands.index[::37][:14]
    star, row, n_rows = window_rows(idx, "face", 1, len(cands.pool_mm))
    ptr = np.concatenate([[0], np.cumsum(np.bincount(star, minlength=len(idx)))])
    rows = row[np.argsort(star, kind="stable")]
    sets = [set(rows[ptr[i] : ptr[i + 1]].tolist()) for i in range(len(idx))]
    best = 0
    for mask in range(1 << len(idx)):
        members = [i for i in range(len(idx)) if mask >> i & 1]
        if len(members) <= best:
            continue
        if all(not (sets[a] & sets[b]) for a, b in itertools.combinations(members, 2)):
            best = len(members)
    opt, _, status, _ = milp(ptr, rows, n_rows, np.arange(len(idx)), 60, node_limit=100000)
    assert status == "optimal" and len(opt) == best


def test_enumeration_is_sound_and_covers_every_covariance_fit(cands):
    """Brute force over every ordered 6-tuple of the pool: each realisable, deep enough star whose
    covariance box fits appears exactly once (canonically).  (The exact fit decision's own
    soundness and completeness are tested in test_stars_fit.py.)"""
    from starforge.geometry.obb import covariance_box
    from starforge.geometry.tetra import canonical_lengths, is_realisable, tetra_width, vertices_from_lengths

    pool = cands.pool_mm
    limit = np.array(SPEC.centre_limit_mm)
    got = {tuple(np.round(canonical_lengths(pool[i]), 9)) for i in cands.index}
    assert len(got) == len(cands)  # no star twice
    perms = np.array(list(itertools.permutations(range(len(pool)), 6)))
    L = pool[perms]
    L = L[is_realisable(L)]
    L = L[tetra_width(L) >= SPEC.depth_mm]  # deep enough (the default minimum depth)
    _, _, e = covariance_box(vertices_from_lengths(L))
    fits = (np.sort(e, axis=1) <= limit + 1e-9).all(axis=1)
    expected = {tuple(np.round(c, 9)) for c in canonical_lengths(L[fits])}
    assert expected <= got


@pytest.mark.parametrize("m", [1, 2, 3])
def test_block_count_equals_a_set_of_block_tuples(m):
    """The block count (coded in narrow integers) is the number of distinct blocks, counted as
    Python tuples, minimised over the m^3 grid placements; any integer type of the keys."""
    from starforge.stars.bounds import count_blocks

    rng = np.random.default_rng(m)
    for hi in (6, 60, 250):
        F = np.sort(rng.integers(0, hi, size=(3000, 3)), axis=1)
        want = min(
            len({tuple((x + o) // m for x, o in zip(row, off, strict=True)) for row in F.tolist()})
            for off in itertools.product(range(m), repeat=3)
        )
        for dt in (np.uint8, np.int16, np.int64):
            assert count_blocks(F.astype(dt), m) == want


def test_compiled_face_block_count_is_the_numpy_count():
    """block_bound's compiled count (large inputs) gives numpy's count of the face keys' blocks,
    for every block size and index type, and block_bound takes it from the threshold up."""
    import starforge.stars.bounds as sel

    rng = np.random.default_rng(11)
    for hi in (8, 40, 200):
        idx = np.array([rng.choice(hi, 6, replace=False) for _ in range(4000)])
        faces = sel.key_triples(idx, "face")[:, :4].reshape(-1, 3)
        for m in (1, 2, 3):
            want = sel.count_blocks(faces, m)
            for dt in (np.uint8, np.int16, np.int64):
                assert sel.count_face_blocks_compiled(idx.astype(dt), m) == want
    idx = np.array([rng.choice(30, 6, replace=False) for _ in range(500)]).astype(np.int16)
    old = sel.BLOCK_KERNEL_STARS
    try:
        sel.BLOCK_KERNEL_STARS = 1
        compiled = sel.block_bound(idx, 2)
    finally:
        sel.BLOCK_KERNEL_STARS = old
    assert compiled == sel.block_bound(idx, 2) == sel.count_blocks(sel.key_triples(idx, "face").reshape(-1, 3), 2) // 4


def test_fitting_box_volumes_are_the_plain_float_products():
    """The enumeration's box volumes are, bit for bit, the product of the extents along each
    row, each projection summed x0 r0 + x1 r1 + x2 r2 in Python floats, for centres placed as
    the enumeration places them (A at the origin, B on +x, C in the xy-plane): the selection
    orders stars by them, so the family depends on every bit."""
    from starforge.stars.classify import _box_volume

    rng = np.random.default_rng(5)
    P, R = rng.normal(size=(30, 4, 3)) * 7, rng.normal(size=(30, 3, 3))
    P[:, 0, :] = 0.0
    P[:, 1, 1:] = 0.0
    P[:, 2, 2] = 0.0
    want = []
    for p, r in zip(P.tolist(), R.tolist(), strict=True):
        vol = 1.0
        for row in r:
            proj = [row[0] * x[0] + row[1] * x[1] + row[2] * x[2] for x in p]
            vol = vol * (max(proj) - min(proj))
        want.append(vol)
    assert _box_volume(P, R).tobytes() == np.array(want).tobytes()
