"""Flip-proof layouts and fleets: the margins re-checked by brute force over every pair of
subsets and every relabelling, the optimizer's conflicts, copies on one prop mutually distinct,
the batch repair, and ``place-batch``'s report and refusals."""

from __future__ import annotations

import csv
import itertools
import json
import math

import numpy as np
import pytest

from starforge.props.distinct import clashes, face_tree, own_triangles, subset_margin
from starforge.props.layout_search import untangle
from starforge.props.tracked import Problem, TrackSettings
from tests.conftest import run_cli


def _corr(P, A, Q, B, skip_identity=False):
    """Smallest, over every correspondence of subset ``A`` of P onto subset ``B`` of Q (all but
    the identity when asked), of the largest difference of corresponding distances; plain Python."""
    best = math.inf
    for perm in itertools.permutations(B):
        if skip_identity and perm == tuple(B):
            continue
        pairs = itertools.combinations(range(len(A)), 2)
        d = max(abs(math.dist(P[A[i]], P[A[j]]) - math.dist(Q[perm[i]], Q[perm[j]])) for i, j in pairs)
        best = min(best, d)
    return best


def _brute_margin(P, k):
    """The self-margin from any k markers by brute force: every pair of k-subsets, every
    correspondence (a subset with itself: every correspondence but the identity)."""
    subs = list(itertools.combinations(range(len(P)), k))
    return min(_corr(P, A, P, B, A == B) for A in subs for B in subs)


def _brute_conflicts(P, tol):
    """Own triangle conflicts by brute force: unordered pairs of triangles with a correspondence
    within ``tol``, and triangles with a relabelling onto themselves within ``tol``."""
    tris = list(itertools.combinations(range(len(P)), 3))
    pairs = sum(_corr(P, A, P, B) < tol for A, B in itertools.combinations(tris, 2))
    return pairs + sum(_corr(P, A, P, A, True) < tol for A in tris)


def _between(P, Q):
    """The smallest correspondence difference between a triangle of P and one of Q (brute force)."""
    trip, triq = itertools.combinations(range(len(P)), 3), list(itertools.combinations(range(len(Q)), 3))
    return min(_corr(P, A, Q, B) for A in trip for B in triq)


@pytest.mark.parametrize("seed", range(6))
def test_self_margins_and_conflicts_match_a_brute_force(seed):
    rng = np.random.default_rng(seed)
    P = rng.uniform(0, 60, size=(int(rng.integers(4, 7)), 3))
    if seed % 2:  # a near-isosceles triangle and a near-repeat, so that conflicts occur
        P[2] = P[0] + (P[1] - P[0]) * 0.5 + np.array([0.0, 0.0, 25.0]) + rng.normal(0, 0.3, 3)
    m3 = _brute_margin(P, 3)
    assert subset_margin(P, 3) == pytest.approx(m3, abs=1e-9)
    assert own_triangles(P, 0.0)[1] == pytest.approx(m3, abs=1e-9)
    m4 = _brute_margin(P, 4)
    assert subset_margin(P, 4) == pytest.approx(m4, abs=1e-9)
    assert m4 >= m3 - 1e-9  # flip-proof from 3 markers implies flip-proof from 4
    for tol in (0.5, 2.0, 5.0, m3 + 1e-6):
        assert own_triangles(P, tol)[0] == _brute_conflicts(P, tol)
    assert own_triangles(P, m3 - 1e-9)[0] == 0  # nothing is closer than the margin


def test_clashes_match_a_brute_force():
    rng = np.random.default_rng(4)
    P = rng.uniform(0, 50, size=(6, 3))
    Q = rng.uniform(0, 50, size=(6, 3))
    Q[:3] = P[:3] + rng.normal(0, 0.2, (3, 3))  # one shared triangle, nearly
    tq = list(itertools.combinations(range(6), 3))
    faces = np.array([sorted(math.dist(Q[x], Q[y]) for x, y in itertools.combinations(T, 2)) for T in tq])
    for tol in (0.3, 1.0, 3.0):  # a triangle clashes when some correspondence is within tol
        want = sum(any(_corr(P, T, Q, B) < tol for B in tq) for T in itertools.combinations(range(6), 3))
        assert clashes(P, face_tree(faces), tol) == want
    assert clashes(P, None, 1.0) == 0


def _problem(seed, avoid=None, tol_mm=3.0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.06, 0.06, size=(60, 3))
    seen = rng.random((60, 40)) < 0.5
    return Problem(pts, seen, rng.random(60), TrackSettings(avoid_tolerance_mm=tol_mm), 0.01, 0.03, avoid)


def test_crowding_of_every_addition_at_once_equals_one_at_a_time():
    rng = np.random.default_rng(3)
    avoid = np.sort(rng.uniform(0.01, 0.12, (300, 3)), axis=1)
    prob = _problem(2, avoid=avoid)
    for n in (0, 1, 2, 5):
        sites = rng.choice(60, n, replace=False).tolist()
        free = np.setdiff1d(np.arange(60), sites)
        got = prob.crowding_additions(sites, free)
        assert got.tolist() == [prob.crowding([*sites, int(c)]) for c in free]
    assert got.max() > 0  # conflicts occur, so the equality is not all zeros


def test_problem_counts_own_conflicts_at_its_tolerance_and_untangle_clears_them():
    prob = _problem(1)
    rng = np.random.default_rng(2)
    cleared = 0
    for _ in range(3):
        sites = rng.choice(60, 7, replace=False).tolist()
        t = prob.terms(sites)
        P = prob.points[sites] * 1000.0
        assert t["own_conflicts"] == _brute_conflicts(P, 3.0)
        assert t["self_margin_m"] * 1000.0 == pytest.approx(_brute_margin(P, 3), abs=1e-9)
        assert prob.crowding(sites) == t["close_pairs"] + t["avoid_conflicts"] + t["own_conflicts"]
        fixed = untangle(prob, sites)
        assert len(set(fixed)) == len(fixed) == 7
        assert prob.crowding(fixed) <= prob.crowding(sites)
        cleared += prob.crowding(fixed) == 0 < prob.crowding(sites)
    assert cleared  # the swap search does clear conflicts, not only never adds them


TINY = """
description = "tiny and quick"
objective = "tracked"
sites = 160
resolution = 1
orientations = 60          # as many poses as the hammer has grips: each holds it in one
rig = "default"
mesh_format = "stl"

[track]
iterations = 0
restarts = 0
random_layouts = 40
validation_poses = 0
target_markers = 6

[evaluation]
poses = 60
"""


@pytest.fixture(scope="module")
def tiny_spec(tmp_path_factory):
    p = tmp_path_factory.mktemp("spec") / "tiny.toml"
    p.write_text(TINY)
    return p


def test_copies_are_mutually_distinct_and_flip_proof(tiny_spec):
    from starforge.props.files import distinct_report
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place, place_copies
    from starforge.props.spec import load_spec

    spec = load_spec(str(tiny_spec))  # the default tolerance, 2.6 mm
    prop = load_prop("hammer", "m")
    res = place_copies(prop, spec, 3, seed=0)
    assert len(res) == 3
    assert res[0].marker_sites == place(prop, spec, seed=0).marker_sites  # the first is place's layout
    pts = [r.centres() * 1000.0 for r in res]
    for r, P in zip(res, pts, strict=True):
        rep = distinct_report(r)
        m3 = _brute_margin(P, 3)
        assert rep["self_margin_mm"] == pytest.approx(m3, abs=1e-5)
        assert rep["own_conflicts"] == _brute_conflicts(P, 2.6)
        assert m3 >= 2.6 and rep["own_conflicts"] == 0
        assert r.evaluation["default"]["tracked"] > 0.5  # still a layout that is tracked
    for i, j in itertools.combinations(range(3), 2):
        assert _between(pts[i], pts[j]) >= 2.6, (i, j)


def test_copies_refuse_the_paper_objective_and_bad_counts():
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place_copies
    from starforge.props.spec import load_spec

    prop = load_prop("box", "m")
    with pytest.raises(ValueError, match="tracked objective"):
        place_copies(prop, load_spec("paper"), 2)
    with pytest.raises(ValueError, match="copies must be an integer >= 1"):
        place_copies(prop, load_spec("default"), 0)


def test_make_distinct_repairs_every_clash_and_keeps_clear_layouts():
    from starforge.props.batch import make_distinct

    rng = np.random.default_rng(5)
    layouts = [rng.uniform(0, 0.2, (5, 3)) for _ in range(4)]
    layouts[2] = layouts[0] + rng.normal(0, 1e-4, (5, 3))  # a near copy of layout 0
    layouts[3] = layouts[1].copy()  # an exact copy of layout 1
    kept = [x.copy() for x in layouts]
    asked = []

    def replace(i, faces):
        asked.append(i)
        for _ in range(200):
            cand = rng.uniform(0, 0.2, (5, 3))
            if not clashes(cand, face_tree(faces), 0.002):
                return cand
        raise AssertionError("no clear layout drawn")

    redone = make_distinct(layouts, replace, 0.002)
    assert redone == asked
    for i, j in itertools.combinations(range(4), 2):
        assert _between(layouts[i] * 1000, layouts[j] * 1000) >= 2.0, (i, j)
    for i in range(4):
        if i not in redone:
            assert np.array_equal(layouts[i], kept[i])
    assert len(redone) == 2  # one of each clashing pair, not every layout


def test_closest_pairs_match_a_brute_force():
    from starforge.tracking.fleet import closest_pairs
    from starforge.tracking.library import build_library

    rng = np.random.default_rng(8)
    bodies = [rng.uniform(0, 80, (int(rng.integers(3, 6)), 3)) for _ in range(4)]
    got = closest_pairs(build_library(bodies), start_mm=0.5)
    for i, P in enumerate(bodies):
        best = min((_between(P, Q), j) for j, Q in enumerate(bodies) if j != i)
        assert got[i][0] == best[1] and got[i][1] == pytest.approx(best[0], abs=1e-9)


@pytest.mark.slow
def test_place_batch_copies_report_matches_the_files(tmp_path, tiny_spec, capsys):
    out = tmp_path / "fleet"
    assert (
        run_cli(
            [
                "place-batch",
                "hammer",
                "--copies",
                "2",
                "--spec",
                tiny_spec,
                "--workers",
                "1",
                "--frames",
                "300",
                "--out",
                out,
                "-q",
            ]
        )
        == 0
    )
    rows = list(csv.DictReader((out / "batch.csv").read_text().splitlines()))
    assert [r["job"] for r in rows] == ["hammer-01", "hammer-02"]
    pts = []
    for r in rows:
        doc = json.loads((out / r["job"] / "placement.json").read_text())
        P = np.array(doc["tracked"]["marker_centres_m"]) * 1000.0
        pts.append(P)
        assert float(r["self_margin_mm"]) == pytest.approx(_brute_margin(P, 3), abs=1e-3)
        assert doc["tracked"]["self_margin_mm"] == pytest.approx(_brute_margin(P, 3), abs=1e-5)
        assert 0.0 <= float(r["wrong_rate_3_seen"]) <= 1.0
    assert rows[0]["closest"] == "hammer-02" and rows[1]["closest"] == "hammer-01"
    d = float(rows[0]["closest_margin_mm"])
    assert _between(pts[0], pts[1]) == pytest.approx(d, abs=1e-3)
    tol = json.loads((out / "hammer-01" / "placement.json").read_text())["tracked"]["distinct_mm"]
    assert d >= tol
    capsys.readouterr()
    csv_path = out / "hammer-01" / "markers.csv"
    assert run_cli(["place", "score", "hammer", csv_path, "--spec", tiny_spec, "--json"]) == 0
    scored = json.loads(capsys.readouterr().out)  # the layout re-scored from its markers.csv
    assert scored["self_margin_mm"] == pytest.approx(_brute_margin(pts[0], 3), abs=0.01)
    assert scored["self_margin_4_mm"] == pytest.approx(_brute_margin(pts[0], 4), abs=0.01)


def test_place_batch_refusals(tmp_path, cli_error, tiny_spec):
    out = tmp_path / "o"
    assert "--copies must be in [1, 100]" in cli_error(
        ["place-batch", "hammer", "--copies", "0", "--out", out]
    )
    assert "--copies needs the tracked objective" in cli_error(
        ["place-batch", "hammer", "--copies", "2", "--spec", "paper", "--out", out]
    )
    assert "noise" in cli_error(["place-batch", "hammer", "--noise", "-1", "--out", out])
    assert "preset" in cli_error(["place-batch", "hammer", "--preset", "nosuch", "--out", out])
    assert not out.exists()
    (out / "hammer-02").mkdir(parents=True)  # an existing layout folder is not overwritten
    (out / "hammer-02" / "placement.json").write_text("{}")
    err = cli_error(["place-batch", "hammer", "--copies", "2", "--spec", tiny_spec, "--out", out])
    assert "--force" in err
    assert (out / "hammer-02" / "placement.json").read_text() == "{}"


def test_job_names_never_collide():
    from starforge.props.batch import jobs

    todo = jobs(["hammer-01", "hammer", "Hammer"], [], "m", "default", 0, copies=2)
    names = [n for folders, _ in todo for n in folders]
    assert len({n.casefold() for n in names}) == len(names) == 6


def test_distinct_tolerance_follows_the_tracker():
    from pathlib import Path

    from starforge.api.place import distinct_tolerance_mm
    from starforge.catalog import read_toml
    from starforge.props.spec import load_spec
    from starforge.tracking.tolerances import bone_tolerance_noise_mm

    s = load_spec("default")
    n = s.track.target_markers
    design = 2 * bone_tolerance_noise_mm(0.2, n)  # twice the default tracker's window at 0.2 mm
    shipped = read_toml(Path(__file__).parents[1] / "templates" / "place" / "default.toml")["track"]
    for value in (TrackSettings().avoid_tolerance_mm, shipped["avoid_tolerance_mm"]):
        assert design <= value < design + 0.05  # the library's default: that, rounded up
    assert distinct_tolerance_mm(s, None, 0.2) == max(s.track.avoid_tolerance_mm, design)
    assert distinct_tolerance_mm(s, None, 0.5) == pytest.approx(2 * bone_tolerance_noise_mm(0.5, n))
    assert distinct_tolerance_mm(s, "art", 0.2) == pytest.approx(
        2 * max(2.0, bone_tolerance_noise_mm(0.2, n))
    )
    assert distinct_tolerance_mm(s, None, 0.0) == s.track.avoid_tolerance_mm  # the spec's floor


def _window_mm(noise_mm, n):
    """The default tracker's window for ``n`` markers from its definition (every one of the
    C(n, 2) distances within it but for a tenth of 0.1 % of frames, a union bound), computed
    here with scipy.stats."""
    from scipy.stats import norm

    return noise_mm * math.sqrt(2.0) * norm.isf(0.001 * 0.1 / math.comb(n, 2) / 2.0)


def test_distinct_tolerances_follow_the_marker_count():
    from starforge.api.place import distinct_tolerance_mm, distinct_tolerances_mm
    from starforge.props.spec import load_spec

    s = load_spec("default")
    for noise in (0.2, 0.5):
        table = distinct_tolerances_mm(s, None, noise)
        assert len(table) == max(s.track.max_markers, s.costs.max_markers) + 1
        for n in range(3, len(table)):
            assert table[n] == pytest.approx(max(s.track.avoid_tolerance_mm, 2 * _window_mm(noise, n)), rel=1e-9)
        assert all(a <= b for a, b in itertools.pairwise(table))  # more markers, a wider window
        assert distinct_tolerance_mm(s, None, noise) == table[s.track.target_markers]
    table = distinct_tolerances_mm(s, None, 0.2)
    assert table[7] == s.track.avoid_tolerance_mm < table[11]  # the spec's floor at 7, not at 11


def test_a_room_keeps_the_tolerance_of_its_largest_layout():
    from starforge.props.batch import make_distinct, room_tolerance_mm

    table = (2.0,) * 6 + (2.5, 3.0, 3.5)
    assert room_tolerance_mm([4, 5], 2.2, table) == 2.2  # the floor
    assert room_tolerance_mm([5, 8, 7], 2.2, table) == 3.5
    assert room_tolerance_mm([5, 20], 2.2, table) == 3.5  # past the table: its last entry
    assert room_tolerance_mm([5, 8], 2.2, None) == 2.2
    rng = np.random.default_rng(3)
    layouts = [rng.uniform(0, 0.1, (5, 3)) for _ in range(2)]
    gap = _between(layouts[0] * 1000, layouts[1] * 1000) / 1000  # m
    far = layouts[0] * 20.0  # triangles 20 times larger than any of layout 1's
    assert _between(far * 1000, layouts[1] * 1000) > 2 * gap * 1000
    for tol, redo in ((0.5 * gap, []), (1.5 * gap, [0])):
        asked = []

        def replace(i, faces, asked=asked):
            asked.append(i)
            return far

        got = make_distinct([x.copy() for x in layouts], replace, lambda i, tol=tol: tol)
        assert got == asked == redo


@pytest.mark.slow  # several optimizations
def test_a_grown_layout_keeps_the_tolerance_of_its_own_marker_count():
    """The hammer on the 4-camera rig (seed 2) grows past 7 markers; with a tolerance per marker count the
    layout's triangles keep the entry of its final count: re-checked by brute force over every
    pair of triangles and every relabelling, and the result says that tolerance."""
    from starforge.api.place import distinct_tolerances_mm
    from starforge.props.files import distinct_report
    from starforge.props.placement import run_placement
    from starforge.props.spec import load_spec

    table = distinct_tolerances_mm(load_spec("default"), None, 0.2)
    kw = {"rig": "small4", "sites": 250, "resolution": 2, "orientations": 6}
    res = run_placement("hammer", seed=2, tolerances_mm=table, **kw)
    P = res.centres() * 1000.0
    m = len(P)
    assert m > 7 and table[m] > table[7]
    assert res.spec.track.avoid_tolerance_mm == table[m]
    rep = distinct_report(res)
    assert rep["distinct_mm"] == table[m]
    assert _brute_conflicts(P, table[m]) == rep["own_conflicts"] == 0
    assert _brute_margin(P, 3) == pytest.approx(rep["self_margin_mm"], abs=1e-5)
    assert rep["self_margin_mm"] >= table[m]
