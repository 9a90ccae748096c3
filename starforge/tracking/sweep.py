"""Capacity curves (the family paper's Fig. 8): how many stars fit a cubic box, against the
minimal length variation delta and the cube side, for both uniqueness rules.

Every (delta, cube) cell is honest about what it knows, and the CSV says which:

* ``exhaustive``: the pool is small enough (at most ``exhaustive_labelled`` labelled candidates)
  to enumerate every star that fits (:func:`starforge.stars.enumerate.enumerate_candidates`, the
  exact fit decision) and select a maximum family (:func:`starforge.stars.family.make_family`);
  ``stars`` is that family, ``upper_bound`` its certified bound (equal when proven optimal).
  The exact solver there is stopped by a node budget alone (:data:`SWEEP_MILP_WORK`), never by
  the wall clock, so a cell reads the same on any machine; when the budget runs out before the
  proof, the cell keeps the best family and the certified bound, with ``optimal`` false.
* ``interval``: larger pools get a certified interval.  The lower end is a verified family from
  a randomised constructive greedy with a fixed number of samples (same seed, same family; no
  time cap): random tetrahedra inside random sub-cubes of the centre cube and random compact
  6-sets of pool lengths, kept when realisable, deep enough, distinct by the tolerance, free of
  conflicts with the stars kept so far (the window rule, :mod:`starforge.stars.rules`), and
  proven to fit by the exact fit decision; the family is re-checked by
  :func:`starforge.stars.family.margins`.  A family that fits a cube fits every larger one, so
  the lower end is raised to the best family of any smaller cube of the same delta.  The upper
  end is :func:`starforge.stars.bounds.pool_face_bound`: a block bound over every triangle a star
  could use, valid without enumerating.

The plot draws exhaustive cells as points and intervals as bars, never a sampled count as a
curve point.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from starforge.errors import NoStarError, StarforgeError
from starforge.markers import marker_diameter_mm
from starforge.spec import positive, require

COLUMNS = (
    "marker_mm",
    "delta_mm",
    "cube_mm",
    "rule",
    "pool_size",
    "labelled",
    "stars",
    "upper_bound",
    "optimal",
    "method",
    "note",
)
#: run time per cell stays in the rows (benchmarks read it) but not in the CSV: the same
#: inputs give the same CSV byte for byte, wherever and however fast the cells ran
#: labelled candidates up to which a cell is enumerated exhaustively (about 2-5 s on one core)
EXHAUSTIVE_LABELLED = 20_000_000
#: random candidates drawn per interval cell (fixed: the same seed gives the same family)
SAMPLES = 200_000
#: the largest delta and cube side a sweep takes, mm (the largest box side a star spec takes)
MAX_SIDE_MM = 10_000.0
#: the exact solver's work budget per exhaustive cell (a tenth of a stars run's); it is the only
#: limit there (no wall-clock limit: a cell's family, bound and "optimal" are the same on any
#: machine; a cell whose budget runs out before the proof is reported with optimal = false)
SWEEP_MILP_WORK = 800_000


def _num(tok: str, name: str, text: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise StarforgeError(f"{name} must be numbers like 0.5:3:0.5 or 1,2,5, got {text!r}") from None
    if not math.isfinite(v):
        raise StarforgeError(f"{name} must hold finite numbers, got {tok.strip()!r} in {text!r}")
    return v


def parse_range(text: str, name: str) -> list[float]:
    """``"0.5:3:0.5"`` (start:stop:step, stop included), ``"1,2,5"`` or ``"2"`` -> sorted values."""
    text = str(text).strip()
    if ":" in text:
        parts = [_num(x, name, text) for x in text.split(":")]
        require(len(parts) == 3, f"{name} range must be start:stop:step, got {text!r}")
        a, b, s = parts
        require(s > 0, f"{name} step must be > 0, got {text!r}")
        require(b >= a, f"{name} range stop must be >= start, got {text!r}")
        n = int(math.floor((b - a) / s + 1e-9)) + 1
        require(n <= 200, f"{name} has {n} values; at most 200")
        vals = [round(a + i * s, 9) for i in range(n)]
    else:
        vals = [_num(x, name, text) for x in text.split(",") if x.strip()]
    require(len(vals) >= 1, f"{name} is empty: {text!r}")
    require(len(vals) <= 200, f"{name} has {len(vals)} values; at most 200")
    for v in vals:
        positive(name, v)
    return sorted(set(vals))


def fitting_box_volume(P: np.ndarray, limit: np.ndarray, box_method: str = "exact") -> np.ndarray:
    """Volume (mm^3) of a box that fits the sorted ``limit`` (the exact fit decision's rotation,
    or the paper's covariance box), inf where none does.  ``P`` : (n, 4, 3) mm."""
    from starforge.geometry.fit import FIT, decide_fit, fits_limit
    from starforge.geometry.obb import covariance_box

    if not len(P):
        return np.zeros(0)
    if box_method == "covariance":
        _, _, ext = covariance_box(P)
        return np.where(fits_limit(ext, limit), np.prod(ext, axis=1), np.inf)
    status, R, _ = decide_fit(P, limit)
    q = np.einsum("nkj,nij->nki", P, np.nan_to_num(R))
    vol = np.prod(q.max(axis=1) - q.min(axis=1), axis=1)
    return np.where(status == FIT, vol, np.inf)


def sampled_lower_bound(spec, rng: np.random.Generator, samples: int = SAMPLES, batch: int = 8192):
    """A verified family for ``spec`` found by a randomised constructive greedy (module docstring).

    Phase 1 draws ``samples`` random tetrahedra and keeps the distinct ones that fit; phase 2
    runs the paper's greedy over them, most compact first.  Returns lengths (n, 6), mm.  The
    same seed gives the same family.
    """
    from starforge.geometry.tetra import (
        is_realisable,
        lengths_from_vertices,
        tetra_width,
        vertices_from_lengths,
    )
    from starforge.stars.classify import edge_pool
    from starforge.stars.family import margins
    from starforge.stars.rules import grid_steps, internal_ok
    from starforge.stars.stream import window_greedy

    pool = edge_pool(spec)
    p, lmin, d = len(pool), float(pool[0]), spec.delta_mm
    m = grid_steps(spec.tol_mm, d)
    limit = np.array(spec.centre_limit_mm)
    found_idx, found_vol = [], []
    drawn = 0
    while drawn < samples:
        k = min(batch, samples - drawn)
        drawn += k
        if (drawn // batch) % 2:
            # shapes that fit: random points in a random sub-box, distances snapped to the grid
            s = rng.uniform(0.25, 1.0, size=(k, 1, 1))
            X = rng.random((k, 4, 3)) * limit[None, None, :] * s
            idx = np.rint((lengths_from_vertices(X) - lmin) / d).astype(np.int64)
        else:
            # compact index sets: 6 distinct pool lengths below a random cap, in random order
            cap = rng.integers(5, p, size=k)
            r = np.where(np.arange(p)[None, :] <= cap[:, None], rng.random((k, p)), np.inf)
            idx = np.argsort(r, axis=1)[:, :6].astype(np.int64)
        idx = idx[(idx >= 0).all(axis=1) & (idx < p).all(axis=1)]
        idx = idx[internal_ok(idx, spec.rule, m) & is_realisable(pool[idx])]
        idx = idx[(np.diff(np.sort(idx, axis=1), axis=1) >= m).all(axis=1)]  # tolerance within a star
        idx = idx[tetra_width(pool[idx]) >= spec.depth_mm] if len(idx) else idx
        if len(idx) == 0:
            continue
        P = vertices_from_lengths(pool[idx])
        good = np.isfinite(P).all(axis=(1, 2))
        idx, P = idx[good], P[good]
        vol = fitting_box_volume(P, limit, spec.box_method)
        ok = np.isfinite(vol)
        found_idx.append(idx[ok])
        found_vol.append(vol[ok])
    if not found_idx or sum(len(x) for x in found_idx) == 0:
        return np.zeros((0, 6))
    idx = np.concatenate(found_idx)
    vol = np.concatenate(found_vol)
    idx, first = np.unique(idx, axis=0, return_index=True)
    vol = vol[first]
    order = np.lexsort((pool[idx].sum(axis=1), vol))  # most compact first, like the exhaustive greedy
    # the streamed greedy's: a star is kept when none of its keys' windows is used yet
    chosen = order[window_greedy(spec.rule, p, m)(idx, order)]
    L = pool[idx[chosen]]
    # independent re-check of the uniqueness rule on the lengths themselves
    if len(L) > 1:
        marg = margins(L, pair=spec.rule == "pair")
        key = "family_face_mm" if spec.rule == "face" else "family_pair_mm"
        bad = [i for i, mm in enumerate(marg) if mm[key] < spec.tol_mm - 1e-6]
        if bad:  # cannot happen when the window rule above is right; fail loudly, never overcount
            raise RuntimeError(
                f"internal error: sampled family breaks the {spec.rule} rule at stars {bad[:5]}"
            )
    return L


def run_cell(args: tuple) -> list[dict]:
    """One (marker, delta, cube) cell for every rule in ``rules``: rows for the CSV."""
    marker, delta, cube, rules, exhaustive_labelled, samples, seed, min_depth = args
    from dataclasses import replace

    from starforge.stars.bounds import pool_face_bound
    from starforge.stars.classify import edge_pool
    from starforge.stars.estimate import labelled_count
    from starforge.stars.spec import StarSpec

    rows = []
    base = {"marker_mm": marker, "delta_mm": delta, "cube_mm": cube}
    try:
        spec0 = StarSpec(box_mm=(cube, cube, cube), marker_mm=marker, delta_mm=delta, min_depth_mm=min_depth)
    except StarforgeError as exc:
        return [
            {
                **base,
                "rule": r,
                "pool_size": 0,
                "labelled": 0,
                "stars": 0,
                "upper_bound": 0,
                "optimal": True,
                "method": "none",
                "note": f"no star: {exc}",
                "seconds": 0.0,
            }
            for r in rules
        ]
    pool = spec0.pool_size
    labelled = labelled_count(spec0)
    if labelled <= exhaustive_labelled:
        from starforge.stars.enumerate import enumerate_candidates
        from starforge.stars.family import make_family

        t0 = time.perf_counter()
        cands = enumerate_candidates(spec0, workers=1)  # the sweep runs cells in parallel instead
        t_enum = time.perf_counter() - t0
        for r in rules:
            t1 = time.perf_counter()
            try:
                fam = make_family(
                    replace(spec0, rule=r), candidates=cands, milp_work=SWEEP_MILP_WORK
                )
                n, ub, opt = len(fam.stars), fam.summary["upper_bound"], bool(fam.summary["optimal"])
            except NoStarError:  # only "no star fits" is an answer; any other refusal fails the cell
                n, ub, opt = 0, 0, True
            rows.append(
                {
                    **base,
                    "rule": r,
                    "pool_size": pool,
                    "labelled": labelled,
                    "stars": n,
                    "upper_bound": ub,
                    "optimal": opt,
                    "method": "exhaustive",
                    "note": "",
                    "seconds": round(t_enum + time.perf_counter() - t1, 3),
                }
            )
        return rows
    ub = pool_face_bound(edge_pool(spec0), spec0.grid_steps, float(np.linalg.norm(spec0.centre_limit_mm)))
    for k, r in enumerate(rules):
        t1 = time.perf_counter()
        rng = np.random.default_rng([seed, int(round(delta * 1000)), int(round(cube * 1000)), k])
        L = sampled_lower_bound(replace(spec0, rule=r), rng, samples)
        rows.append(
            {
                **base,
                "rule": r,
                "pool_size": pool,
                "labelled": labelled,
                "stars": len(L),
                "upper_bound": ub,
                "optimal": len(L) >= ub,
                "method": "interval",
                "note": f"{samples:,} samples",
                "seconds": round(time.perf_counter() - t1, 3),
            }
        )
    return rows


#: bytes per pool triple while the face bound is built (a Python tuple, then index arrays)
BYTES_PER_TRIPLE = 150.0


#: CPU seconds per fitting star and rule of an exhaustive cell's selection (measured: 1.6-5.5 s
#: for 0.32-0.92 M fitting stars in cubes of 20 and 40 mm, the sweep's work budget, load 10-13)
SELECT_SECONDS_PER_FIT = 6e-6
#: an exhaustive cell whose fixed-rate guess exceeds this many seconds is timed by a pilot
PILOT_ABOVE_S = 2.0
#: the pilot's share of fitting stars, raised by this factor for the memory estimate (its sample
#: of 256 subsets is correlated within a subset; measured peaks: 0.565 GiB for delta 1.5 x cube 30
#: and 0.675 GiB for delta 2.0 x cube 40 against 0.62 and 0.70 GiB estimated without it)
FIT_SHARE_MARGIN = 1.2


@functools.lru_cache(maxsize=1024)
def _cell_pilot(marker_mm: float, delta: float, cube: float) -> tuple[float, float]:
    """(CPU seconds per labelled candidate on one core, share that fit) of a cube cell, from the
    enumeration's pilot sample (:func:`starforge.stars.estimate.pilot`, about 0.1-0.4 s): in a
    cube far more candidates reach the fit decision than in a finger box, and deciding them is
    harder (near-symmetric limits), so the fixed rate was up to 8x low there."""
    from starforge.stars.estimate import pilot
    from starforge.stars.spec import StarSpec

    return pilot(StarSpec(box_mm=(cube, cube, cube), marker_mm=marker_mm, delta_mm=delta), cpu=True)


def cell_estimate(
    marker_mm: float, delta: float, cube: float, rules, exhaustive_labelled: int, samples: int
) -> tuple[float, float]:
    """(single-core seconds, peak bytes) of one cell, rough (for the bounded-cost checks).  An
    exhaustive cell is its enumeration plus one selection per rule; past :data:`PILOT_ABOVE_S`
    at the fixed rate, both come from a pilot sample of the cell's own stars
    (:func:`_cell_pilot`)."""
    from starforge.stars.estimate import BYTES_PER_CANDIDATE, SECONDS_PER_LABELLED
    from starforge.stars.estimate import estimate as enum_estimate
    from starforge.stars.rules import window_bytes
    from starforge.stars.spec import StarSpec

    try:
        spec = StarSpec(box_mm=(cube, cube, cube), marker_mm=marker_mm, delta_mm=delta)
    except StarforgeError:
        return 0.0, 0.0
    est = enum_estimate(spec)
    n = est["labelled"]
    if n <= exhaustive_labelled:
        guess = n * SECONDS_PER_LABELLED * 4 + 1.0
        fits = n / 4  # the enumeration estimate's own generous share
        if guess > PILOT_ABOVE_S:
            rate, share = _cell_pilot(float(marker_mm), float(delta), float(cube))
            guess = n * rate + len(rules) * n * share * SELECT_SECONDS_PER_FIT + 1.0
            fits = n * share * FIT_SHARE_MARGIN
        # the selection holds the fitting stars and builds their key windows (the pair rule's
        # are twice the face rule's): in a cube that, not the enumeration, sets the peak
        select = (
            max(window_bytes(fits, r, spec.grid_steps) for r in rules) + fits * BYTES_PER_CANDIDATE + 200e6
        )
        return guess, max(est["bytes"], select)
    triples = math.comb(spec.pool_size, 3)
    return (
        len(rules) * samples * 2e-5 + triples * 2e-7 * spec.grid_steps**3,
        triples * BYTES_PER_TRIPLE + 100e6,
    )


#: the most labelled candidates a sweep cell enumerates exhaustively
MAX_EXHAUSTIVE = 300_000_000


def _auto_limit(marker_mm: float, delta: float, cube: float, rules, samples: int, share: float) -> int:
    """The cell's exhaustive threshold under ``--exhaustive auto``: its own labelled count when
    its enumeration fits ``share`` bytes (one worker's memory) and MAX_EXHAUSTIVE, else -1
    (an interval)."""
    from starforge.stars.estimate import labelled_count
    from starforge.stars.spec import StarSpec

    try:
        n = labelled_count(StarSpec(box_mm=(cube, cube, cube), marker_mm=marker_mm, delta_mm=delta))
    except StarforgeError:
        return 0
    _, nbytes = cell_estimate(marker_mm, delta, cube, rules, n, samples)
    return n if (n <= MAX_EXHAUSTIVE and nbytes <= share) else -1


def estimate_cells(
    marker_mm: float, deltas, cubes, rules, exhaustive_labelled: int, samples: int
) -> tuple[float, float]:
    """Rough single-core seconds for a whole sweep and the peak bytes of its largest cell
    (for the bounded-cost check)."""
    est = [cell_estimate(marker_mm, d, c, rules, exhaustive_labelled, samples) for d in deltas for c in cubes]
    return sum(e[0] for e in est), max((e[1] for e in est), default=0.0)


def sweep(
    marker_mm: float,
    deltas,
    cubes,
    rules=("face", "pair"),
    exhaustive_labelled: int | None = EXHAUSTIVE_LABELLED,
    samples: int = SAMPLES,
    workers: int | None = None,
    seed: int = 0,
    min_depth_mm: float | None = None,
    progress=None,
    scheduler: str | None = None,
    on_plan=None,
) -> list[dict]:
    """Every (delta, cube) cell, each one task of :func:`starforge.runtime.engine.map_tasks` (in
    process for small sweeps, else a local dask cluster of ``workers`` processes, default every
    core, or the cluster at ``scheduler`` / ``STARFORGE_SCHEDULER``); rows sorted, so they do
    not depend on where or in which order the cells ran.

    ``exhaustive_labelled=None`` ("auto"): every cell whose enumeration fits one worker's memory
    (and has at most :data:`MAX_EXHAUSTIVE` labelled candidates) is exhaustive, the others
    intervals.  ``progress(done, total)`` after each finished cell; ``on_plan(plan)`` once,
    before the first.
    """
    from starforge.runtime import engine
    from starforge.runtime.budget import require_time

    marker_mm = marker_diameter_mm(marker_mm)
    if min_depth_mm is not None:
        require(
            math.isfinite(min_depth_mm) and 0 <= min_depth_mm <= MAX_SIDE_MM,
            f"min_depth_mm must be in [0, {MAX_SIDE_MM:g}] mm, got {min_depth_mm}",
        )
    for name, values in (("delta", deltas), ("cube", cubes)):
        require(max(values) <= MAX_SIDE_MM, f"{name} must be at most {MAX_SIDE_MM:g} mm, got {max(values):g}")
    if exhaustive_labelled is not None:
        require(
            0 <= exhaustive_labelled <= MAX_EXHAUSTIVE,
            f"exhaustive must be from 0 to {MAX_EXHAUSTIVE:,} labelled candidates (or auto), got {exhaustive_labelled:,}",
        )
    require(100 <= samples <= 10_000_000, f"samples must be in [100, 10000000], got {samples}")
    for r in rules:
        require(r in ("face", "pair"), f"rule must be face or pair, got {r!r}")
    require(
        workers is None or 0 <= workers <= 256, f"workers must be in [0, 256] (0: every core), got {workers}"
    )
    pairs = [(float(d), float(c)) for d in deltas for c in cubes]
    if exhaustive_labelled is None:
        # a remote cluster's worker memory decides which cells it can hold: ask it first
        share = engine.plan_with_capacity(len(pairs), math.inf, workers or None, scheduler).usable_bytes
        limits = [_auto_limit(marker_mm, d, c, rules, samples, share) for d, c in pairs]
    else:
        limits = [int(exhaustive_labelled)] * len(pairs)
    cells = [
        (float(marker_mm), d, c, tuple(rules), lim, int(samples), int(seed), min_depth_mm)
        for (d, c), lim in zip(pairs, limits, strict=True)
    ]
    est = [cell_estimate(marker_mm, c[1], c[2], rules, c[4], samples) for c in cells]
    seconds = sum(e[0] for e in est)
    what = f"a sweep of {len(cells)} cells"
    advice = "use a larger --delta, smaller --cube values or fewer of them, or lower --exhaustive"
    # workers asked for by number get a local cluster whatever the estimate says
    plan_seconds = math.inf if (workers or 0) > 1 else seconds
    p = engine.plan(len(cells), plan_seconds, workers or None, scheduler)
    if p.mode != "remote":  # a remote cluster's size is known once connected; its memory is checked per task
        require_time(seconds / p.workers, what, advice)
    results = engine.map_tasks(
        run_cell,
        cells,
        task_bytes=[e[1] for e in est],
        seconds=plan_seconds,
        workers=workers or None,
        scheduler=scheduler,
        progress=progress,
        what=what,
        advice=advice,
        on_plan=on_plan,
    )
    rows: list[dict] = [row for cell_rows in results for row in cell_rows]
    rows.sort(key=lambda r: (r["rule"], r["delta_mm"], r["cube_mm"]))
    return carry_bounds(rows)


def carry_bounds(rows: list[dict]) -> list[dict]:
    """A family that fits a cube fits every larger cube (same marker and delta: the pool only
    grows), so a sampled lower bound is raised to the best count of any smaller cube."""
    best: dict = {}
    for r in sorted(rows, key=lambda r: (r["rule"], r["delta_mm"], r["cube_mm"])):
        key = (r["rule"], r["delta_mm"])
        prev = best.get(key)
        if r["method"] == "interval" and prev is not None and prev[0] > r["stars"]:
            r["stars"] = prev[0]
            r["note"] = f"{r['note']}; lower end carried from the {prev[1]:g} mm cube"
            r["optimal"] = r["stars"] >= (r["upper_bound"] or 0)
        if prev is None or r["stars"] > prev[0]:
            best[key] = (r["stars"], r["cube_mm"])
    return rows


def rows_csv(rows: list[dict]) -> str:
    import csv
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in COLUMNS})
    return buf.getvalue()
