"""Capacity sweep: ranges, sampled lower bounds re-verified by brute force, exhaustive cells vs
certified intervals (the upper end checked against exhaustive maxima), the CLI's CSV and plot."""

from __future__ import annotations

import csv
import itertools

import numpy as np
import pytest

from starforge.cli import main
from starforge.errors import StarforgeError
from starforge.geometry.tetra import FACE_EDGES, RELABELLINGS, lengths_from_vertices, vertices_from_lengths
from starforge.stars.boxes import place_stars
from starforge.stars.spec import StarSpec
from starforge.tracking.sweep import parse_range, run_cell, sampled_lower_bound, sweep


def test_parse_range():
    assert parse_range("0.5:3:0.5", "delta") == [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    assert parse_range("10:50:5", "cube")[-1] == 50.0
    assert parse_range("3,1,2", "cube") == [1.0, 2.0, 3.0]
    for bad, msg in [
        ("3:1:1", "stop must be >= start"),
        ("1:2", "start:stop:step"),
        ("a,b", "numbers"),
        ("0:2:1", "must be > 0"),
        ("1:2:0", "step must be > 0"),
    ]:
        with pytest.raises(StarforgeError, match=msg):
            parse_range(bad, "delta")


def face_rule_ok(L, tol):
    F = np.sort(L[:, FACE_EDGES], axis=2).reshape(-1, 3)
    for i, j in itertools.combinations(range(len(F)), 2):
        if np.abs(F[i] - F[j]).max() < tol - 1e-9:
            return False
    return True


def pair_rule_ok(L, tol):
    # the paper: however the second star is relabelled, both lengths of some opposite pair differ
    for a, b in itertools.combinations(range(len(L)), 2):
        worst = min(
            max(
                min(abs(L[a][2 * k] - L[b][r][2 * k]), abs(L[a][2 * k + 1] - L[b][r][2 * k + 1]))
                for k in range(3)
            )
            for r in RELABELLINGS
        )
        if worst < tol - 1e-9:
            return False
    return True


@pytest.mark.parametrize("rule", ["face", "pair"])
def test_sampled_lower_bound_is_a_valid_family(rule):
    spec = StarSpec(box_mm=(22.0, 22.0, 22.0), marker_mm=4.0, delta_mm=2.0, rule=rule, select="greedy")
    L = sampled_lower_bound(spec, np.random.default_rng(1), samples=60_000)
    assert len(L) >= 5
    again = sampled_lower_bound(spec, np.random.default_rng(1), samples=60_000)
    assert np.array_equal(L, again)  # a fixed sample count: same seed, same family
    limit = np.array(spec.centre_limit_mm)
    lo, hi = spec.pool_bounds_mm
    for row in L:
        assert len(set(row.round(9))) == 6 and row.min() >= lo - 1e-9 and row.max() <= hi + 1e-9
        P = vertices_from_lengths(row[None])[0]
        assert np.allclose(lengths_from_vertices(P), row, atol=1e-6)  # realisable
    assert all(item[4] for item in place_stars(vertices_from_lengths(L), limit, "exact"))  # all fit the cube
    assert (face_rule_ok if rule == "face" else pair_rule_ok)(L, spec.tol_mm)


@pytest.mark.slow
def test_interval_ends_bracket_the_exhaustive_maximum():
    """For cells small enough to solve exhaustively, the interval's certified upper end is at
    least the exhaustive family and the sampled lower end at most its certified bound."""
    from starforge.stars.bounds import pool_face_bound
    from starforge.stars.enumerate import edge_pool

    for cube in (16.0, 18.0):
        exhaustive = run_cell((4.0, 2.0, cube, ("face",), 10**9, 1000, 0, None))[0]
        assert exhaustive["method"] == "exhaustive" and exhaustive["stars"] <= exhaustive["upper_bound"]
        spec = StarSpec(box_mm=(cube, cube, cube), marker_mm=4.0, delta_mm=2.0)
        ub = pool_face_bound(edge_pool(spec), spec.grid_steps, float(np.linalg.norm(spec.centre_limit_mm)))
        assert ub >= exhaustive["stars"]
        L = sampled_lower_bound(spec, np.random.default_rng(2), samples=60_000)
        assert len(L) <= exhaustive["upper_bound"]
        interval = run_cell((4.0, 2.0, cube, ("face",), 0, 20_000, 0, None))[0]
        assert interval["method"] == "interval" and interval["upper_bound"] == ub
        assert interval["stars"] <= exhaustive["upper_bound"] and interval["stars"] <= ub


def test_cells_are_labelled_by_size():
    rows = sweep(
        4.0, [2.0], [12.0, 22.0], rules=("face",), exhaustive_labelled=10_000, samples=5_000, workers=1
    )
    by_cube = {r["cube_mm"]: r for r in rows}
    for r in rows:
        if r["pool_size"] == 0:
            assert r["method"] == "none" and r["stars"] == 0
        elif r["labelled"] <= 10_000:
            assert r["method"] == "exhaustive"
        else:
            assert r["method"] == "interval" and r["upper_bound"] >= r["stars"]
    assert by_cube[22.0]["method"] == "interval"


@pytest.mark.parametrize(
    "deltas, cubes, workers",
    [
        ("3", "18", "1"),  # one cell in this process
        pytest.param("2,3", "18,24", "2", marks=pytest.mark.slow),  # four cells on a local cluster
    ],
)
def test_sweep_cli_writes_csv_and_png(tmp_path, deltas, cubes, workers):
    out = tmp_path / "sw"
    rc = main(
        [
            "sweep",
            "--delta",
            deltas,
            "--cube",
            cubes,
            "--exhaustive",
            "200000",
            "--samples",
            "3000",
            "--workers",
            workers,
            "--out",
            str(out),
            "-q",
        ]
    )
    assert rc == 0
    with (out / "sweep.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(deltas.split(",")) * len(cubes.split(",")) * 2  # deltas x cubes x rules
    assert {r["rule"] for r in rows} == {"face", "pair"}
    assert {r["method"] for r in rows} <= {"exhaustive", "interval", "none"}
    for r in rows:
        if r["method"] != "none":
            assert int(r["stars"]) <= int(r["upper_bound"])
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG"


def test_sweep_cli_bad_range(tmp_path, capsys):
    rc = main(["sweep", "--delta", "3:1:0.5", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "delta range stop must be >= start" in err and err.count("\n") == 1


def test_interval_lower_ends_never_fall_below_a_smaller_cube():
    rows = [
        {
            "rule": "face",
            "delta_mm": 1.0,
            "cube_mm": 40.0,
            "stars": 800,
            "method": "interval",
            "upper_bound": 5000,
            "note": "",
        },
        {
            "rule": "face",
            "delta_mm": 1.0,
            "cube_mm": 45.0,
            "stars": 600,
            "method": "interval",
            "upper_bound": 5000,
            "note": "",
        },
        {
            "rule": "face",
            "delta_mm": 1.0,
            "cube_mm": 35.0,
            "stars": 400,
            "method": "exhaustive",
            "upper_bound": 400,
            "note": "",
        },
        {
            "rule": "pair",
            "delta_mm": 1.0,
            "cube_mm": 45.0,
            "stars": 10,
            "method": "interval",
            "upper_bound": 5000,
            "note": "",
        },
    ]
    from starforge.tracking.sweep import carry_bounds

    out = {(r["rule"], r["cube_mm"]): r for r in carry_bounds(rows)}
    assert out[("face", 45.0)]["stars"] == 800 and "40 mm cube" in out[("face", 45.0)]["note"]
    assert out[("face", 40.0)]["stars"] == 800 and out[("pair", 45.0)]["stars"] == 10


def test_exhaustive_auto_follows_a_workers_memory(monkeypatch):
    from starforge.runtime.budget import ENV_MEMORY

    kw = dict(rules=("face",), exhaustive_labelled=None, samples=1_000, workers=1)
    monkeypatch.setenv(ENV_MEMORY, "1G")  # every cell's enumeration fits
    rows = sweep(4.0, [3.0], [18.0, 22.0], **kw)
    assert [r["method"] for r in rows] == ["exhaustive", "exhaustive"]
    monkeypatch.setenv(ENV_MEMORY, "205M")  # below any enumeration's estimate (200 MB of base)
    rows = sweep(4.0, [3.0], [18.0, 22.0], **kw)
    assert [r["method"] for r in rows] == ["interval", "interval"]


@pytest.mark.slow
def test_exhaustive_cells_ignore_the_wall_clock(monkeypatch):
    """The exact path of an exhaustive cell is stopped by its node budget alone: a wall-clock
    limit that would cut the solver is never passed (same stars, bound and proof on any
    machine), whereas a cut run (the stars command's safety limit) is reported as not used."""
    import starforge.stars.select as sel
    from starforge.stars.enumerate import enumerate_candidates
    from starforge.stars.rules import internal_ok, window_rows
    from starforge.stars.spec import StarSpec

    c = enumerate_candidates(StarSpec(box_mm=(16, 12, 24), delta_mm=2.0))
    index = c.index[internal_ok(c.index, "face", 1)]
    star_of, row, n_rows = window_rows(index, "face", 1, len(c.pool_mm))
    ptr, rows = sel.csr_rows(star_of, row, len(index))
    cols = np.arange(len(index))
    a = sel.milp(ptr, rows, n_rows, cols, None, 40)  # the node budget alone
    b = sel.milp(ptr, rows, n_rows, cols, 1e3, 40)  # a wall-clock limit that does not cut
    cut = sel.milp(ptr, rows, n_rows, cols, 1e-3, 40)
    assert a[0].tobytes() == b[0].tobytes() and a[1:] == b[1:] and a[3]
    assert cut[2] == "time limit" and not cut[3]
    # and the sweep's cells ask for it: no wall-clock limit reaches the solver
    seen = []
    real = sel.milp

    def spy(ptr, rows, n_rows, cols, time_limit, node_limit=sel.MILP_NODE_LIMIT):
        seen.append(time_limit)
        return real(ptr, rows, n_rows, cols, time_limit, node_limit)

    monkeypatch.setattr(sel, "milp", spy)
    row = run_cell((4.0, 3.0, 18.0, ("face", "pair"), 10**9, 1000, 0, None))
    assert seen and all(t is None for t in seen) and all(r["method"] == "exhaustive" for r in row)


def test_large_exhaustive_cells_are_timed_by_their_own_pilot(monkeypatch):
    """A cube cell whose fixed-rate guess is past PILOT_ABOVE_S is estimated from its pilot's
    CPU rate and fit share (enumeration + one selection per rule); small cells never pay for a
    pilot.  The pilot itself is the enumeration's, classified exactly as the enumeration does."""
    from starforge.stars.estimate import labelled_count, pilot
    from starforge.tracking import sweep as S

    calls = []

    def fake(marker, delta, cube):
        calls.append((marker, delta, cube))
        return 1e-5, 0.1

    monkeypatch.setattr(S, "_cell_pilot", fake)
    small = S.cell_estimate(4.0, 2.0, 20.0, ("face",), 10**12, 1000)[0]
    assert not calls and small == pytest.approx(labelled_count(StarSpec(box_mm=(20,) * 3, marker_mm=4, delta_mm=2.0)) * 8e-7 + 1)
    n = labelled_count(StarSpec(box_mm=(25,) * 3, marker_mm=4, delta_mm=1.0))
    big = S.cell_estimate(4.0, 1.0, 25.0, ("face", "pair"), 10**12, 1000)[0]
    assert calls == [(4.0, 1.0, 25.0)]
    assert big == pytest.approx(n * 1e-5 + 2 * n * 0.1 * S.SELECT_SECONDS_PER_FIT + 1)
    # the real pilot on one thread: a CPU rate at least the fixed floor, a share in [0, 1]
    rate, share = pilot(StarSpec(box_mm=(20,) * 3, marker_mm=4, delta_mm=2.0), samples=16, cpu=True)
    assert rate >= 4e-7 and 0 <= share <= 1


def test_only_no_star_is_a_zero_row(monkeypatch):
    """A cell whose spec admits no star records 0 stars; any other refusal of its selection (a
    memory limit, say) fails the cell instead of writing a false 0."""
    from starforge.errors import NoStarError, StarforgeError
    from starforge.stars import family as F

    cell = (4.0, 2.0, 20.0, ("face",), 10**9, 1_000, 0, None)

    def refuse(*a, **k):
        raise StarforgeError("the selection's key windows need 9 GB, above the 4 GB limit")

    monkeypatch.setattr(F, "make_family", refuse)
    with pytest.raises(StarforgeError, match="key windows"):
        run_cell(cell)

    def none(spec, *a, **k):
        raise NoStarError("no star fits")

    monkeypatch.setattr(F, "make_family", none)
    [row] = run_cell(cell)
    assert row["stars"] == 0 and row["method"] == "exhaustive"


@pytest.mark.slow
def test_an_exhaustive_cells_memory_estimate_covers_its_selection():
    """The estimate holds the numpy memory an exhaustive cell really allocates (tracemalloc sees
    numpy's buffers), enumeration and both rules' selections included."""
    import tracemalloc

    from starforge.stars.enumerate import labelled_count
    from starforge.stars.spec import StarSpec
    from starforge.tracking.sweep import cell_estimate

    d, c = 2.0, 30.0
    n = labelled_count(StarSpec(box_mm=(c, c, c), marker_mm=4.0, delta_mm=d))
    _, est = cell_estimate(4.0, d, c, ("face", "pair"), n, 1_000)
    tracemalloc.start()
    try:
        rows = run_cell((4.0, d, c, ("face", "pair"), n, 1_000, 0, None))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert [r["method"] for r in rows] == ["exhaustive", "exhaustive"] and rows[0]["stars"] > 0
    assert peak <= est, (peak, est)
