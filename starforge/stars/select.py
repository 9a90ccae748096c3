"""Family selection: set packing over key windows (see :mod:`starforge.stars.rules`).

* ``greedy``: the paper's way, growing a family from the most compact star: take stars in
  order of box volume (then total length) and keep each one that conflicts with none taken.
* ``max``: as large a family as possible.  Greedy, then a deterministic (1,2)-swap local
  search (remove one star, insert two that only conflicted with it; the move that drives the
  best maximum-independent-set heuristics), then, when the candidates are few enough
  (``MILP_MAX_COLUMNS``), the exact MILP (HiGHS through ``scipy.optimize.milp``) under the time
  limit, whose optimum and dual bound are used only when it finishes.  The proven upper bound is
  the smaller of the block bound (each star needs 4 distinct face blocks of side m, so
  ``blocks // 4``) and the MILP's dual bound.

Everything is deterministic: the same spec gives the same family.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from starforge.stars.rules import key_triples
from starforge.stars.spec import StarSpec

#: largest candidate count handed whole to the MILP
MILP_MAX_COLUMNS = 20000


@dataclass(frozen=True)
class Selection:
    chosen: np.ndarray  # indices into the candidate arrays
    upper_bound: int | None
    info: dict = field(default_factory=dict)


def _csr(star_of: np.ndarray, row: np.ndarray, n: int):
    order = np.argsort(star_of, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(star_of, minlength=n))])
    return ptr, row[order]


def compactness_order(index: np.ndarray, pool: np.ndarray, volume: np.ndarray) -> np.ndarray:
    """Most compact first: box volume, then total edge length, then pool indices."""
    keys = [index[:, k] for k in range(5, -1, -1)]
    return np.lexsort((*keys, pool[index].sum(axis=1), np.round(volume, 9)))


def greedy(order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """Take stars in ``order``; keep each whose rows are all still free."""
    used = bytearray(n_rows)
    rl, pl = rows.tolist(), ptr.tolist()
    chosen = []
    for i in order.tolist():
        r = rl[pl[i] : pl[i + 1]]
        if not any(used[x] for x in r):
            for x in r:
                used[x] = 1
            chosen.append(i)
    return np.array(chosen, dtype=np.intp)


def block_bound(index: np.ndarray, m: int) -> int:
    """Proven upper bound: face keys in one block of side m (grid steps) conflict pairwise and a
    star's four faces lie in four different blocks, so a family has at most blocks // 4 stars."""
    faces = key_triples(index, "face")[:, :4] // m
    blocks = np.unique(faces.reshape(-1, 3), axis=0)
    return len(blocks) // 4


def local_search(
    chosen: np.ndarray, order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int, rounds: int = 200
) -> tuple[np.ndarray, int]:
    """(1,2)-swaps until none is left (or ``rounds``); returns the family and the swaps made."""
    n = len(ptr) - 1
    owner = np.full(n_rows, -1, dtype=np.intp)
    for s in chosen.tolist():
        owner[rows[ptr[s] : ptr[s + 1]]] = s
    in_fam = np.zeros(n, dtype=bool)
    in_fam[chosen] = True
    rank = np.empty(n, dtype=np.intp)
    rank[order] = np.arange(n)
    star_of_entry = np.repeat(np.arange(n), np.diff(ptr))
    swaps = 0
    for _ in range(rounds):
        own = owner[rows]
        # distinct owners per candidate: min and max over its entries (-1 = free)
        big = np.where(own < 0, np.iinfo(np.intp).max, own)
        lo = np.full(n, np.iinfo(np.intp).max, dtype=np.intp)
        hi = np.full(n, -1, dtype=np.intp)
        np.minimum.at(lo, star_of_entry, big)
        np.maximum.at(hi, star_of_entry, own)
        free = (hi < 0) & ~in_fam
        one = (lo == hi) & (hi >= 0) & ~in_fam  # conflicts with exactly one family star
        progress = False
        # insert free stars first (most compact first)
        for s in sorted(np.flatnonzero(free).tolist(), key=lambda i: rank[i]):
            r = rows[ptr[s] : ptr[s + 1]]
            if (owner[r] < 0).all():
                owner[r] = s
                in_fam[s] = True
                progress = True
        cand = np.flatnonzero(one)
        groups: dict[int, list[int]] = {}
        for s, t in zip(cand.tolist(), hi[cand].tolist(), strict=True):
            groups.setdefault(t, []).append(s)
        for t in sorted(groups):
            if not in_fam[t]:
                continue
            members = sorted(groups[t], key=lambda i: rank[i])
            tr = rows[ptr[t] : ptr[t + 1]]
            ok = [s for s in members if np.isin(owner[rows[ptr[s] : ptr[s + 1]]], (-1, t)).all()]
            done = False
            for a in range(len(ok)):
                ra = rows[ptr[ok[a]] : ptr[ok[a] + 1]]
                for b in range(a + 1, len(ok)):
                    rb = rows[ptr[ok[b]] : ptr[ok[b] + 1]]
                    if not np.intersect1d(ra, rb).size:
                        owner[tr] = -1
                        in_fam[t] = False
                        owner[ra] = ok[a]
                        owner[rb] = ok[b]
                        in_fam[ok[a]] = in_fam[ok[b]] = True
                        swaps += 1
                        progress = done = True
                        break
                if done:
                    break
        if not progress:
            break
    return np.flatnonzero(in_fam), swaps


def milp(ptr, rows, n_rows, cols: np.ndarray, time_limit: float):
    """Exact set packing over ``cols`` with HiGHS; returns (chosen, dual_bound, status, complete)."""
    import scipy.sparse as sp
    from scipy.optimize import Bounds, LinearConstraint
    from scipy.optimize import milp as _milp

    cols = np.asarray(cols)
    counts = ptr[cols + 1] - ptr[cols]
    col_idx = np.repeat(np.arange(len(cols)), counts)
    row_idx = np.concatenate([rows[ptr[c] : ptr[c + 1]] for c in cols.tolist()]) if len(cols) else np.zeros(0, int)
    A = sp.csr_matrix((np.ones(len(col_idx)), (row_idx, col_idx)), shape=(n_rows, len(cols)))
    res = _milp(
        -np.ones(len(cols)),
        constraints=LinearConstraint(A, -np.inf, 1),
        integrality=np.ones(len(cols)),
        bounds=Bounds(0, 1),
        options={"time_limit": float(time_limit), "disp": False},
    )
    chosen = cols[np.flatnonzero(res.x > 0.5)] if res.x is not None else np.zeros(0, dtype=np.intp)
    dual = getattr(res, "mip_dual_bound", None)
    dual = int(np.floor(-dual + 1e-6)) if dual is not None and np.isfinite(dual) else None
    return chosen, dual, res.message, res.status == 0


def select_family(index, pool, volume, star_of, row, n_rows, spec: StarSpec) -> Selection:
    """Choose the family among the candidates (see module docstring)."""
    from starforge.stars.rules import grid_steps

    n = len(index)
    ptr, rows = _csr(star_of, row, n)
    order = compactness_order(index, pool, volume)
    t0 = time.perf_counter()
    chosen = greedy(order, ptr, rows, n_rows)
    info: dict = {"greedy": int(len(chosen)), "greedy_s": round(time.perf_counter() - t0, 3)}
    bound = block_bound(index, grid_steps(spec.tol_mm, spec.delta_mm))
    info["block_bound"] = bound
    if spec.select == "greedy":
        return Selection(chosen, bound, info)
    t1 = time.perf_counter()
    chosen, swaps = local_search(chosen, order, ptr, rows, n_rows)
    info.update(local_search=int(len(chosen)), swaps=swaps, local_search_s=round(time.perf_counter() - t1, 3))
    if len(chosen) < bound and n <= MILP_MAX_COLUMNS:
        # exact set packing over every candidate; trusted only when HiGHS finishes, so that the
        # same spec always gives the same family (a time-limited incumbent depends on timing)
        t2 = time.perf_counter()
        m_chosen, dual, status, finished = milp(ptr, rows, n_rows, np.arange(n), spec.time_limit_s)
        info.update(milp_columns=int(n), milp_status=str(status), milp_finished=bool(finished))
        info["milp_s"] = round(time.perf_counter() - t2, 3)
        if finished:
            chosen = np.sort(m_chosen)
            if dual is not None:
                bound = min(bound, dual)
            bound = min(bound, len(chosen)) if finished else bound
    elif len(chosen) < bound:
        info["milp_skipped"] = f"{n} candidates > {MILP_MAX_COLUMNS}: family from greedy + local search"
    info["proven_optimal"] = bool(len(chosen) >= bound)
    return Selection(np.sort(chosen), bound, info)
