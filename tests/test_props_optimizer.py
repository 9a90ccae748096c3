"""The annealing chain: acceptance ratios, detailed balance, incremental costs, reproducibility,
and a comparison with random search on every built-in prop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.props.costs import CostSettings, evaluate
from starforge.props.optimizer import (
    ADD,
    MODIFY,
    REMOVE,
    ChainSettings,
    acceptance_probability,
    overlap_neighbours,
    random_valid_layout,
    run_chain,
)

CH = ChainSettings()


def test_acceptance_ratios_by_hand():
    Z = 20
    # eq. 7: add from |M| = 7: p_r (Z - |M|) / (p_a |M'|) * exp(-dC / t) = 13/8 exp(-dC/t)
    assert acceptance_probability(ADD, 7, 0.5, 1.5, 0.5, CH, Z) == pytest.approx(13 / 8 * math.exp(-2))
    assert acceptance_probability(ADD, 7, 0.5, 0.6, 0.5, CH, Z) == 1.0  # 13/8 e^-0.2 > 1
    # eq. 8: remove from |M| = 8: p_a |M| / (p_r (Z - |M'|)) = 8 / 13
    assert acceptance_probability(REMOVE, 8, 0.5, 0.5, 1.0, CH, Z) == pytest.approx(8 / 13)
    assert acceptance_probability(REMOVE, 8, 0.5, 0.7, 0.25, CH, Z) == pytest.approx(8 / 13 * math.exp(-0.8))
    # eq. 9: modify: exp(-dC / t)
    assert acceptance_probability(MODIFY, 8, 0.2, 0.5, 0.75, CH, Z) == pytest.approx(math.exp(-0.4))
    # unequal move probabilities enter the ratio
    ch = ChainSettings(p_add=0.2, p_remove=0.4, p_modify=0.4)
    assert acceptance_probability(ADD, 5, 1, 1, 1.0, ch, Z) == 1.0  # 0.4 * 15 / (0.2 * 6) > 1
    assert acceptance_probability(REMOVE, 10, 1, 1, 1.0, ch, Z) == pytest.approx(0.2 * 10 / (0.4 * 11))
    # a full set cannot grow
    assert acceptance_probability(ADD, 20, 1.0, 0.0, 1.0, CH, Z) == 0.0
    # t = 0: better always, worse never, equal with the proposal ratio
    assert acceptance_probability(MODIFY, 7, 0.5, 0.49, 0.0, CH, Z) == 1.0
    assert acceptance_probability(MODIFY, 7, 0.5, 0.51, 0.0, CH, Z) == 0.0
    assert acceptance_probability(REMOVE, 8, 0.5, 0.5, 0.0, CH, Z) == pytest.approx(8 / 13)


def test_schedule_is_the_papers():
    t = [CH.temperature(i) for i in (0, 49, 50, 99, 100, 150, 199, 200, 5000)]
    assert t == [1.0, 1.0, 0.75, 0.75, 0.5, 0.25, 0.25, 0.0, 0.0]


def test_stationary_marker_count_is_binomial():
    """With a flat cost the chain must sample marker counts in proportion to C(Z, n) on [4, 20]."""
    rng = np.random.default_rng(0)
    pts = rng.random((500, 3))
    cs = CostSettings(w_visibility=0, w_count=0, w_overlap=0, w_symmetry=0)
    ch = ChainSettings(fixed_temperature=1.0, max_iterations=150_000)
    r = run_chain(pts, np.zeros(500), cs, ch, rng)
    counts = np.bincount(r.history_n[5000:], minlength=21)[4:21].astype(float)
    expected = np.array([math.comb(20, n) for n in range(4, 21)], dtype=float)
    emp, exp = counts / counts.sum(), expected / expected.sum()
    assert 0.5 * np.abs(emp - exp).sum() < 0.03  # total variation distance


@pytest.fixture(scope="module")
def hammer_case():
    from starforge.props.builtin import builtin_mesh
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.sites import sample_sites
    from starforge.props.visibility import compute_table

    rng = np.random.default_rng(3)
    mesh = builtin_mesh("hammer")
    sites = sample_sites(mesh, 400, rng)
    rig = load_rig("default")
    poses = make_poses(rig.volume, 2, 1, mesh.bounds.mean(axis=0), rng)
    table = compute_table(mesh, sites.points, sites.normals, rig, poses)
    return sites.points, table.site_visibility, table.seen.any(axis=2)


@pytest.mark.parametrize("w_coverage", [0.0, 2.0])
def test_incremental_cost_equals_full_evaluation(hammer_case, w_coverage):
    pts, vis, seen = hammer_case
    # large markers so that overlaps happen often, both symmetry terms on, optional coverage term
    cs = CostSettings(marker_diameter_m=0.03, w_near_symmetry=0.5, w_coverage=w_coverage)
    ch = ChainSettings(fixed_temperature=0.3, max_iterations=300)
    r = run_chain(pts, vis, cs, ch, np.random.default_rng(1), site_pose_seen=seen)
    idx = list(r.sites)
    full = evaluate(pts[idx], vis[idx], cs, marker_pose_seen=seen[idx])
    assert r.cost == pytest.approx(full.total, abs=1e-9)
    assert cs.min_markers <= len(idx) <= cs.max_markers
    assert r.history_best[-1] == pytest.approx(r.cost)
    assert np.all(np.diff(r.history_best) <= 1e-12)


def test_same_seed_same_result(hammer_case):
    pts, vis, _ = hammer_case
    cs, ch = CostSettings(), ChainSettings()
    a = run_chain(pts, vis, cs, ch, np.random.default_rng(11))
    b = run_chain(pts, vis, cs, ch, np.random.default_rng(11))
    c = run_chain(pts, vis, cs, ch, np.random.default_rng(12))
    assert a.sites == b.sites and a.cost == b.cost and np.array_equal(a.history_cost, b.history_cost)
    assert a.sites != c.sites or not np.array_equal(a.history_cost, c.history_cost)


def test_stops_by_the_three_percent_rule(hammer_case):
    pts, vis, _ = hammer_case
    r = run_chain(pts, vis, CostSettings(), ChainSettings(), np.random.default_rng(2))
    h = r.history_cost
    assert 250 < r.iterations < 20000
    i = r.iterations
    assert abs(h[i - 51] - h[i - 1]) <= 0.03 * abs(h[i - 51])
    assert np.all(np.diff(h[200:]) <= 1e-12)  # t = 0 from iteration 200: never worse


def test_chain_settings_validation():
    with pytest.raises(StarforgeError, match="must be 1"):
        ChainSettings(p_add=0.5, p_remove=0.5, p_modify=0.5)
    with pytest.raises(StarforgeError, match="restarts"):
        ChainSettings(restarts=0)


@pytest.mark.parametrize(
    "name",
    ["hammer", "umbrella", *(pytest.param(n, marks=pytest.mark.slow) for n in ("racket", "sword", "bottle", "box", "shield"))],
)
def test_beats_best_of_1000_random_layouts(name):
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place
    from starforge.props.spec import load_spec

    spec = load_spec("long")
    res = place(load_prop(name), spec, seed=1)
    cs = spec.costs
    n = len(res.marker_sites)
    assert res.cost.overlapping_pairs == 0
    assert not res.cost.symmetric
    # independent re-score of the result
    assert res.cost.total == pytest.approx(
        evaluate(res.marker_points, res.marker_visibility, cs, with_margin=False).total
    )
    rng = np.random.default_rng(99)
    pts, vis = res.sites.points, res.site_visibility
    nbr = overlap_neighbours(pts, cs.marker_diameter_m)
    best = math.inf
    for _ in range(1000):
        idx = random_valid_layout(n, len(pts), nbr, rng)
        best = min(best, evaluate(pts[idx], vis[idx], cs, with_margin=False).total)
    assert res.cost.total < best


def test_coverage_term_keeps_three_markers_in_view():
    """The optional coverage term (robust preset): re-checked from the visibility table."""
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place
    from starforge.props.spec import load_spec

    spec = load_spec("robust")
    res = place(load_prop("hammer"), spec, seed=2)
    counts = res.marker_pose_seen.sum(axis=0)
    assert res.cost.coverage == pytest.approx(float((counts < 3).mean()))
    assert res.cost.coverage == 0.0  # every pose sees at least 3 markers
    paper = place(load_prop("hammer"), load_spec("long"), seed=2)
    assert paper.cost.visibility <= res.cost.visibility + 1e-12  # coverage costs some mean visibility
