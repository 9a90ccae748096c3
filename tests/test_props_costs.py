"""Cost terms against hand-computed values; symmetry of regular and scalene layouts."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starforge.errors import StarforgeError
from starforge.props.costs import (
    CostSettings,
    count_cost,
    coverage_cost,
    evaluate,
    lower_bound,
    overlap_cost,
    overlapping_pairs,
    visibility_cost,
)
from starforge.props.symmetry import is_symmetric, near_symmetry_margin, quick_reject


def test_count_cost_by_hand():
    assert count_cost(7, 7) == 0.0
    assert count_cost(8, 7) == pytest.approx(1 - math.exp(-0.5))
    assert count_cost(5, 7) == pytest.approx(1 - math.exp(-2.0))
    assert count_cost(9, 7, sigma=2.0) == pytest.approx(1 - math.exp(-0.5))


def test_visibility_cost_by_hand():
    assert visibility_cost(np.array([1.0, 0.5, 0.0]), 1.0) == pytest.approx(0.5)
    assert visibility_cost(np.array([0.25, 0.75]), 0.2) == pytest.approx(0.3)


def test_overlap_by_hand():
    d = 0.004  # marker diameter
    pts = np.array([[0, 0, 0], [0.003, 0, 0], [0.1, 0, 0]], dtype=float)
    assert overlapping_pairs(pts, d) == 1
    # ordered pairs: 2 of 3 * 2 = 6 overlap
    assert overlap_cost(pts, d) == pytest.approx(2 / 6)
    assert overlap_cost(pts, d, target=0.5) == pytest.approx(0.5 - 1 / 3)
    touching = np.array([[0, 0, 0], [0.004, 0, 0]], dtype=float)
    assert overlapping_pairs(touching, d) == 0  # touching spheres do not intersect
    same = np.zeros((3, 3))
    assert overlap_cost(same, d) == pytest.approx(1.0)


def test_evaluate_is_the_weighted_sum():
    cs = CostSettings(target_markers=5, w_visibility=2.0, w_count=0.5, w_overlap=3.0, w_symmetry=0.25)
    pts = np.array([[0, 0, 0], [0.002, 0, 0], [0.1, 0.03, 0.01], [0.05, 0.2, 0.07]])
    vis = np.array([0.5, 0.25, 1.0, 0.75])
    c = evaluate(pts, vis, cs)
    cv = abs(np.mean(vis) - 1.0)
    cn = 1 - math.exp(-((4 - 5) ** 2) / 2)
    co = 2 * 1 / (4 * 3)
    assert c.visibility == pytest.approx(cv)
    assert c.count == pytest.approx(cn)
    assert c.overlap == pytest.approx(co)
    assert c.symmetry == 0.0 and not c.symmetric
    assert c.total == pytest.approx(2 * cv + 0.5 * cn + 3 * co)


def test_settings_validation_names_the_parameter():
    with pytest.raises(StarforgeError, match="w_overlap must be >= 0"):
        CostSettings(w_overlap=-1)
    with pytest.raises(StarforgeError, match=r"markers \(target_markers\) must be in \[4, 20\]"):
        CostSettings(target_markers=21)
    with pytest.raises(StarforgeError, match="marker_diameter_m must be > 0"):
        CostSettings(marker_diameter_m=0)


def _polygon(k, radius, axis, centre, phase):
    ang = phase + 2 * math.pi * np.arange(k) / k
    ring = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(k)])
    # put the ring's normal along the chosen axis
    perm = {0: [2, 0, 1], 1: [1, 2, 0], 2: [0, 1, 2]}[axis]
    return ring[:, perm] + centre


@settings(max_examples=60, deadline=None)
@given(
    k=st.integers(2, 8),
    radius=st.floats(0.02, 0.5),
    axis=st.integers(0, 2),
    phase=st.floats(0, 2 * math.pi),
    centre=st.tuples(*[st.floats(-1, 1)] * 3),
    height=st.floats(-0.1, 0.1),
)
def test_regular_polygons_are_symmetric(k, radius, axis, phase, centre, height):
    pts = _polygon(k, radius, axis, np.array(centre), phase)
    if k == 2:  # a pair plus an apex on the axis is still 2-fold symmetric
        apex = np.array(centre) + height * np.eye(3)[axis]
        pts = np.vstack([pts, apex])
    assert not quick_reject(pts, 0.002)
    assert is_symmetric(pts, k=8, tol_m=0.002)
    assert near_symmetry_margin(pts) < 1e-9


def test_square_symmetric_scalene_not():
    square = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]) * 0.05 + [0.3, -0.2, 0.9]
    assert is_symmetric(square)
    scalene = np.array([[0, 0, 0], [0.1, 0, 0], [0.03, 0.05, 0.01], [0.2, 0.13, 0.07]])
    assert not is_symmetric(scalene)
    assert near_symmetry_margin(scalene) > 0.005
    # a triangle needs order 3, missed by rotations that are multiples of 45 degrees only
    tri = _polygon(3, 0.1, 2, np.zeros(3), 0.3)
    assert is_symmetric(tri, k=8) and not is_symmetric(tri, k=2)


def test_tolerance_is_a_distance():
    square = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]) * 0.05
    noisy = square + np.array([[0.0005, 0, 0], [0, -0.0004, 0], [0, 0, 0.0003], [0, 0, 0]])
    assert is_symmetric(noisy, tol_m=0.002)
    assert not is_symmetric(noisy, tol_m=0.0001)


def _exact_margin(p):
    """Brute force over every non-identity permutation (small n): min Kabsch RMS."""
    n = len(p)
    best = math.inf
    for perm in itertools.permutations(range(n)):
        if perm == tuple(range(n)):
            continue
        q = p[list(perm)]
        ca, cb = p.mean(0), q.mean(0)
        U, _, Vt = np.linalg.svd((p - ca).T @ (q - cb))
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1, 1, d]) @ U.T
        rms = math.sqrt(((p - ca) @ R.T + cb - q).__pow__(2).sum(1).mean())
        best = min(best, rms)
    return best


@pytest.mark.parametrize("seed", range(6))
def test_near_symmetry_margin_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = 4 + seed % 2
    p = rng.random((n, 3)) * 0.2
    exact = _exact_margin(p)
    got = near_symmetry_margin(p)
    assert got >= exact - 1e-12  # it is a residual of a real self-match
    assert got <= exact * 1.05 + 1e-12


def test_near_symmetry_margin_grows_with_noise():
    square = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]) * 0.05
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 1, square.shape)
    noise *= 0.001 / np.sqrt((noise**2).sum(1).mean())  # RMS 1 mm
    m = near_symmetry_margin(square + noise)
    assert 0 < m <= 2 * 0.001 + 1e-12  # the 90 degree self-match moves each point by at most twice the noise


def test_capped_margin_and_near_symmetry_cost():
    square = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]) * 0.05
    assert near_symmetry_margin(square, cap=0.005) < 1e-9
    scalene = np.array([[0, 0, 0], [0.1, 0, 0], [0.03, 0.05, 0.01], [0.2, 0.13, 0.07]])
    full = near_symmetry_margin(scalene)
    assert full > 0.005 and near_symmetry_margin(scalene, cap=0.005) == 0.005
    cs = CostSettings(w_near_symmetry=2.0, near_symmetry_target_m=0.005)
    c_sq = evaluate(square, np.ones(4), cs)
    c_sc = evaluate(scalene, np.ones(4), cs)
    assert c_sq.near_symmetry == pytest.approx(1.0) and c_sc.near_symmetry == 0.0
    assert c_sc.margin_m == pytest.approx(full)
    assert c_sq.total - c_sq.symmetry * cs.w_symmetry == pytest.approx(2.0 + cs.w_count * c_sq.count)


def test_coverage_cost_by_hand():
    seen = np.array([[1, 1, 0, 1], [1, 0, 0, 1], [1, 1, 1, 0]], dtype=bool)  # 3 markers x 4 poses
    # markers seen per pose: 3, 2, 1, 2 -> poses with fewer than 3: 3 of 4
    assert coverage_cost(seen, 3) == pytest.approx(0.75)
    assert coverage_cost(seen, 2) == pytest.approx(0.25)
    cs = CostSettings(w_coverage=0.5)
    pts = np.array([[0, 0, 0], [0.1, 0.02, 0], [0.03, 0.2, 0.05]])
    c = evaluate(pts, np.ones(3), cs, marker_pose_seen=seen)
    assert c.coverage == pytest.approx(0.75)
    assert c.total == pytest.approx(cs.w_count * c.count + 0.5 * 0.75)
    with pytest.raises(StarforgeError, match="coverage"):
        evaluate(pts, np.ones(3), cs)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(0, 1), min_size=1, max_size=9),
    st.floats(0, 1),
    st.integers(1, 6),
    st.integers(1, 4),
    st.integers(0, 5),
)
def test_lower_bound_against_every_subset(vis, target_vis, target_n, lo, extra):
    """Brute force over every subset of a few sites: no layout costs less than the bound, and with
    the layout-dependent terms switched off some subset attains it when the target is 1 (the paper's)."""
    v = np.array(vis)
    hi = lo + extra
    target_n = min(max(target_n, lo), hi)
    s = CostSettings(target_visibility=target_vis, target_markers=target_n, min_markers=lo, max_markers=hi,
                     w_overlap=0.0, w_symmetry=0.0)
    bound, n_at = lower_bound(v, s)
    costs = {}
    for n in range(lo, min(hi, len(v)) + 1):
        for sub in itertools.combinations(range(len(v)), n):
            c = s.w_visibility * visibility_cost(v[list(sub)], target_vis) + s.w_count * count_cost(n, target_n)
            costs[sub] = c
    if not costs:
        assert math.isinf(bound)
        return
    best = min(costs.values())
    assert bound <= best + 1e-12
    if target_vis == 1.0:
        assert bound == pytest.approx(best, abs=1e-12)
        assert lo <= n_at <= hi
