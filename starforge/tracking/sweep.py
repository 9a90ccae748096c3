"""Capacity curves (the family paper's Fig. 8): how many stars fit a cubic box, against the
minimal length variation delta and the cube side, for both uniqueness rules.

Each (delta, cube) cell is computed one of two ways, and the CSV says which:

* ``exhaustive``: the pool is small enough (``pool_size <= exhaustive_pool``) to enumerate
  every fitting star (:func:`starforge.stars.enumerate.enumerate_candidates`), then the
  paper's greedy selection (:func:`starforge.stars.family.make_family`, ``select="greedy"``);
  ``upper_bound`` is the selection's proven bound.
* ``sampled lower bound``: larger pools (C(pool, 6) subsets explode) use a randomised
  constructive greedy: random tetrahedra inside random sub-cubes of the centre cube, their
  six distances snapped to the pool grid, alternating with random 6-sets of pool lengths below
  a random cap (compact stars), kept when realisable, distinct by the tolerance,
  free of conflicts with the stars kept so far (same window rule as the exhaustive engine,
  :mod:`starforge.stars.rules`), and fitting the cube (covariance or face-flush box, the
  enumeration's sufficient test); then the greedy over them, most compact first.  The family
  found is re-verified with :func:`starforge.stars.family.margins`, so the count is a sound
  lower bound on what fits (not an estimate of the maximum).  Each such cell draws a fixed
  number of samples (same seed, same count) unless ``cell_seconds`` runs out first.  A family
  that fits a cube fits every larger one, so a sampled cell is raised to the best count of any
  smaller cube of the same delta (its ``stop`` says so).
"""

from __future__ import annotations

import math
import time

import numpy as np

from starforge.errors import StarforgeError
from starforge.spec import positive, require

COLUMNS = (
    "marker_mm",
    "delta_mm",
    "cube_mm",
    "rule",
    "pool_size",
    "stars",
    "upper_bound",
    "method",
    "stop",
    "seconds",
)


def _num(tok: str, name: str, text: str) -> float:
    try:
        return float(tok)
    except ValueError:
        raise StarforgeError(f"{name} must be numbers like 0.5:3:0.5 or 1,2,5, got {text!r}") from None


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


def _conflicts(key: np.ndarray, chosen: np.ndarray, m: int) -> bool:
    """Any chosen key (k, 3) within m - 1 grid steps of ``key`` (3,) in every side."""
    if len(chosen) == 0:
        return False
    return bool((np.abs(chosen - key).max(axis=1) <= m - 1).any())


def fitting_box_volume(P: np.ndarray, limit: np.ndarray, box_method: str = "exact") -> np.ndarray:
    """Volume (mm^3) of the smallest candidate box that fits the sorted ``limit``, inf if none.

    Candidates: the covariance box, and (``exact``) O'Rourke's 24 face-flush boxes (the same
    sufficient test as the exhaustive enumeration).  ``P`` : (n, 4, 3) mm.
    """
    from starforge.stars.enumerate import face_flush_extents
    from starforge.tol import tol

    lim = np.sort(limit) * (1 + tol.box_rel) + tol.length_mm

    def fits(ext):
        return (np.sort(ext, axis=-1) <= lim).all(axis=-1)

    X = P - P.mean(axis=1, keepdims=True)
    _, evec = np.linalg.eigh(np.einsum("nki,nkj->nij", X, X))
    proj = X @ evec
    ext = proj.max(axis=1) - proj.min(axis=1)
    vol = np.where(fits(ext), np.prod(ext, axis=1), np.inf)
    if box_method == "exact" and len(P):
        ef = face_flush_extents(P)
        vf = np.where(fits(ef) & np.isfinite(ef).all(axis=-1), np.prod(ef, axis=-1), np.inf)
        vol = np.minimum(vol, vf.min(axis=1))
    return vol


def sampled_lower_bound(
    spec, rng: np.random.Generator, seconds: float = 20.0, samples: int = 1_000_000, batch: int = 8192
):
    """A verified family for ``spec`` found by a randomised constructive greedy (module docstring).

    Phase 1 draws up to ``samples`` random tetrahedra and keeps
    the distinct ones that fit (or until half of ``seconds``); phase 2 runs the paper's greedy over them, most compact first.
    Returns ``(lengths (n, 6) mm, stop reason)``; the stop reason is ``"samples"`` (the same
    seed gives the same family) or ``"time"``.
    """
    from starforge.geometry.tetra import is_realisable, lengths_from_vertices, vertices_from_lengths
    from starforge.stars.enumerate import edge_pool
    from starforge.stars.family import margins
    from starforge.stars.rules import grid_steps, internal_ok, key_triples

    pool = edge_pool(spec)
    p, lmin, d = len(pool), float(pool[0]), spec.delta_mm
    m = grid_steps(spec.tol_mm, d)
    limit = np.array(spec.centre_limit_mm)
    t0 = time.perf_counter()
    found_idx, found_vol = [], []
    drawn = 0
    stop = "samples"
    while drawn < samples:
        if time.perf_counter() - t0 > 0.5 * seconds:
            stop = "time"
            break
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
        return np.zeros((0, 6)), stop
    idx = np.concatenate(found_idx)
    vol = np.concatenate(found_vol)
    idx, first = np.unique(idx, axis=0, return_index=True)
    vol = vol[first]
    order = np.lexsort((pool[idx].sum(axis=1), vol))  # most compact first, like the exhaustive greedy
    keys = key_triples(idx[order], spec.rule)
    chosen = []
    kf = np.zeros((0, 3), dtype=np.int64)
    kv = np.zeros((0, 3), dtype=np.int64)
    for j, row in enumerate(order):
        if time.perf_counter() - t0 > seconds:
            stop = "time"
            break
        kk = keys[j]
        if any(_conflicts(q, kf, m) for q in kk[:4]):
            continue
        if spec.rule == "pair" and any(_conflicts(q, kv, m) for q in kk[4:]):
            continue
        chosen.append(row)
        kf = np.vstack([kf, kk[:4]])
        if spec.rule == "pair":
            kv = np.vstack([kv, kk[4:]])
    L = pool[idx[np.array(chosen, dtype=np.intp)]]
    # independent re-check of the uniqueness rule on the lengths themselves
    if len(L) > 1:
        marg = margins(L)
        key = "family_face_mm" if spec.rule == "face" else "family_pair_mm"
        bad = [i for i, mm in enumerate(marg) if mm[key] < spec.tol_mm - 1e-6]
        if bad:  # cannot happen when the window rule above is right; fail loudly, never overcount
            raise RuntimeError(
                f"internal error: sampled family breaks the {spec.rule} rule at stars {bad[:5]}"
            )
    return L, stop


def run_cell(args: tuple) -> list[dict]:
    """One (marker, delta, cube) cell for every rule in ``rules``: rows for the CSV."""
    marker, delta, cube, rules, exhaustive_pool, cell_seconds, seed = args
    from starforge.stars.spec import StarSpec

    rows = []
    base = {"marker_mm": marker, "delta_mm": delta, "cube_mm": cube}
    try:
        spec0 = StarSpec(box_mm=(cube, cube, cube), marker_mm=marker, delta_mm=delta, select="greedy")
    except StarforgeError as exc:
        return [
            {
                **base,
                "rule": r,
                "pool_size": 0,
                "stars": 0,
                "upper_bound": 0,
                "method": "none",
                "stop": f"no star: {exc}",
                "seconds": 0.0,
            }
            for r in rules
        ]
    pool = spec0.pool_size
    if pool <= exhaustive_pool:
        from dataclasses import replace

        from starforge.stars.enumerate import enumerate_candidates
        from starforge.stars.family import make_family

        t0 = time.perf_counter()
        cands = enumerate_candidates(spec0, workers=1)  # the sweep runs cells in parallel instead
        t_enum = time.perf_counter() - t0
        for r in rules:
            t1 = time.perf_counter()
            spec = replace(spec0, rule=r)
            try:
                fam = make_family(spec, candidates=cands)
                n, ub = len(fam.stars), fam.summary.get("upper_bound")
            except StarforgeError:
                n, ub = 0, 0
            rows.append(
                {
                    **base,
                    "rule": r,
                    "pool_size": pool,
                    "stars": n,
                    "upper_bound": ub,
                    "method": "exhaustive",
                    "stop": "done",
                    "seconds": round(t_enum + time.perf_counter() - t1, 3),
                }
            )
        return rows
    from dataclasses import replace

    for k, r in enumerate(rules):
        t1 = time.perf_counter()
        rng = np.random.default_rng([seed, int(round(delta * 1000)), int(round(cube * 1000)), k])
        L, stop = sampled_lower_bound(replace(spec0, rule=r), rng, cell_seconds)
        rows.append(
            {
                **base,
                "rule": r,
                "pool_size": pool,
                "stars": len(L),
                "upper_bound": None,
                "method": "sampled lower bound",
                "stop": stop,
                "seconds": round(time.perf_counter() - t1, 3),
            }
        )
    return rows


def sweep(
    marker_mm: float,
    deltas,
    cubes,
    rules=("face", "pair"),
    exhaustive_pool: int = 26,
    cell_seconds: float = 20.0,
    workers: int | None = None,
    seed: int = 0,
    progress=None,
) -> list[dict]:
    """Every (delta, cube) cell on ``workers`` processes (default: every core); rows sorted.

    ``progress(done, total)`` after each finished cell.
    """
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed

    positive("marker_mm", marker_mm)
    positive("cell_seconds", cell_seconds)
    require(exhaustive_pool >= 6, f"exhaustive_pool must be >= 6, got {exhaustive_pool}")
    require(exhaustive_pool <= 40, f"exhaustive_pool must be <= 40 (C(40, 6) subsets), got {exhaustive_pool}")
    for r in rules:
        require(r in ("face", "pair"), f"rule must be face or pair, got {r!r}")
    cells = [
        (
            float(marker_mm),
            float(d),
            float(c),
            tuple(rules),
            int(exhaustive_pool),
            float(cell_seconds),
            int(seed),
        )
        for d in deltas
        for c in cubes
    ]
    workers = workers or os.cpu_count() or 1
    rows: list[dict] = []
    if workers == 1:
        for i, cell in enumerate(cells):
            rows.extend(run_cell(cell))
            if progress:
                progress(i + 1, len(cells))
    else:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
            futs = [ex.submit(run_cell, c) for c in cells]
            for i, f in enumerate(as_completed(futs)):
                rows.extend(f.result())
                if progress:
                    progress(i + 1, len(cells))
    rows.sort(key=lambda r: (r["rule"], r["delta_mm"], r["cube_mm"]))
    return carry_bounds(rows)


def carry_bounds(rows: list[dict]) -> list[dict]:
    """A family that fits a cube fits every larger cube (same marker and delta: the pool only
    grows), so a sampled lower bound is raised to the best count of any smaller cube."""
    best: dict = {}
    for r in sorted(rows, key=lambda r: (r["rule"], r["delta_mm"], r["cube_mm"])):
        key = (r["rule"], r["delta_mm"])
        prev = best.get(key)
        if r["method"] == "sampled lower bound" and prev is not None and prev[0] > r["stars"]:
            r["stars"] = prev[0]
            r["stop"] = f"{r['stop']}; carried from the {prev[1]:g} mm cube"
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
