"""Family selection: set packing over key windows (see :mod:`starforge.stars.rules`).

* ``greedy``: the paper's way, growing a family from the most compact star: take stars in
  order of box volume (then total length) and keep each one that conflicts with none taken.
* ``max``: as large a family as possible.  Greedy, then a deterministic (1,2)-swap local
  search (remove one star, insert two that only conflicted with it), then an iterated local
  search (``ils``: Andrade-Resende-Werneck style, fixed seed, iteration budget
  ``ILS_ITERATIONS``; on small instances also ``ILS_RESTARTS`` short restarts with other fixed
  seeds), then, when the window matrix is small enough (``MILP_MAX_NONZEROS``), the
  exact MILP (HiGHS through ``scipy.optimize.milp``) under a deterministic node budget
  (:func:`node_budget`, from the spec's ``work``): no wall clock decides anything.

Upper bounds are certified: the caller's block bound over every star that may fit, tightened by
the solver's dual bound (plus the undecided stars it did not see) when it ran.

Everything is deterministic: the same spec gives the same family.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from starforge.runtime.kernels import numba
from starforge.stars.bounds import block_bound
from starforge.stars.packing import Packing, rank_of
from starforge.stars.rules import key_points
from starforge.stars.spec import WORK, StarSpec


@dataclass(frozen=True)
class Selection:
    chosen: np.ndarray  # indices into the candidate arrays
    upper_bound: int | None
    info: dict = field(default_factory=dict)


def csr_rows(star_of: np.ndarray, row: np.ndarray, n: int):
    """(ptr, rows): each star's rows, stars in order, in their given order within a star."""
    star_of = np.asarray(star_of)
    ptr = np.concatenate([[0], np.cumsum(np.bincount(star_of, minlength=n))])
    if len(star_of) < 2 or (star_of[1:] >= star_of[:-1]).all():  # already by star (window_rows)
        return ptr, np.asarray(row)
    return ptr, row[np.argsort(star_of, kind="stable")]


def compactness_order(index: np.ndarray, pool: np.ndarray, volume: np.ndarray) -> np.ndarray:
    """Most compact first: box volume (rounded to 1e-9 mm^3), then total edge length, then pool
    indices.  One sort by rounded volume, then the full key only among stars of equal rounded
    volume: the stars are distinct, so the order is total, and the sort by volume need not be
    stable (ties are ordered by the full key anyway)."""
    index = np.asarray(index)
    v = np.round(volume, 9)
    o = np.argsort(v)
    vs = v[o]
    same = vs[1:] == vs[:-1]
    if not same.any():
        return o
    grp = np.concatenate([[0], np.cumsum(~same)])
    pos = np.flatnonzero(np.bincount(grp)[grp] > 1)
    sub = o[pos]
    ix = index[sub]
    keys = [ix[:, k] for k in range(5, -1, -1)]
    o[pos] = sub[np.lexsort((*keys, pool[ix].sum(axis=1), grp[pos]))]
    return o


def greedy(order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """Take stars in ``order``; keep each whose rows are all still free."""
    return _greedy(np.asarray(order, dtype=np.int64), np.asarray(ptr, dtype=np.int64),
                   np.asarray(rows, dtype=np.int64), int(n_rows)).astype(np.intp)


@numba.njit(cache=True, no_cfunc_wrapper=True)
def _greedy(order, ptr, rows, n_rows):
    # np.empty of int64 only, filled by loops: each other allocation (np.zeros, a bool array,
    # .copy()) compiles numba's implementation of it once more in every process on a first run
    used = np.empty(n_rows, dtype=np.int64)
    for r in range(n_rows):
        used[r] = 0
    out = np.empty(len(order), dtype=np.int64)
    k = 0
    for i in order:
        free = True
        for j in range(ptr[i], ptr[i + 1]):
            if used[rows[j]]:
                free = False
                break
        if free:
            for j in range(ptr[i], ptr[i + 1]):
                used[rows[j]] = 1
            out[k] = i
            k += 1
    return out[:k]


def local_search(
    chosen: np.ndarray, order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int, rounds: int = 200
) -> tuple[np.ndarray, int]:
    """(1,2)-swaps until none is left (or ``rounds``); returns the family and the swaps made.

    Each round looks at the family as it stood when the round began: it first inserts the stars
    that were free then and still are, most compact first; then, per family star t (by id), it
    takes the outside stars whose held rows all belonged to t, most compact first, keeps those
    that still conflict with nothing but t, and the first two of them that are disjoint replace
    t.  Compiled (on :class:`starforge.stars.packing.Packing`'s incremental state)."""
    P = Packing(chosen, ptr, rows, n_rows, rank_of(order))
    swaps = P.local_search(int(rounds))
    return P.family, int(swaps)


#: default iteration budget of the iterated local search (``ils``); the stopping rule is this
#: count, never wall time, so the same candidates always give the same family
ILS_ITERATIONS = 800
#: seed of the ILS random generator (fixed: nothing time-dependent)
ILS_SEED = 0
#: on instances small enough for the exact solver, restarts of the ILS from the local-search
#: family with seeds 1..ILS_RESTARTS, each ILS_RESTART_ITERATIONS long (stopped at the bound)
ILS_RESTARTS = 8
ILS_RESTART_ITERATIONS = 1000


def ils(
    chosen: np.ndarray,
    order: np.ndarray,
    ptr: np.ndarray,
    rows: np.ndarray,
    n_rows: int,
    iterations: int = ILS_ITERATIONS,
    bound: int | None = None,
    seed: int = ILS_SEED,
) -> tuple[np.ndarray, int]:
    """Iterated local search for set packing (Andrade, Resende & Werneck style).

    Each iteration force-inserts a random candidate whose held rows belong to one or two family
    stars (removing those), refills free candidates, runs (1,2)-swaps around the change, and
    keeps the result if the family is no smaller (plateau moves walk), else reverts it.
    Deterministic: the only randomness is ``np.random.default_rng(seed)``, drawn in batches of
    :data:`starforge.stars.packing.ILS_BATCH` (``integers(0, n)``), and the budget is an iteration count.  Stops early
    at ``bound``.  Returns (family, iterations used).  The loop is compiled
    (:meth:`starforge.stars.packing.Packing.ils`); the batches are drawn ahead of it, in the same stream.
    """
    P = Packing(chosen, ptr, rows, n_rows, rank_of(order))
    used = P.ils(iterations, bound, seed)
    return P.family, used


def _restart_task(args: tuple) -> tuple[np.ndarray, int]:
    """One ILS restart (a task of :func:`ils_restarts`): ``(start, order, ptr, rows, n_rows,
    bound, seed, iterations)`` -> (family, iterations used).  A pure function of its input."""
    start, order, ptr, rows, n_rows, bound, seed, iterations = args
    return ils(start, order, ptr, rows, n_rows, iterations=iterations, bound=bound, seed=seed)


def ils_restarts(
    chosen, start, order, ptr, rows, n_rows, bound: int, restarts: int = ILS_RESTARTS,
    iterations: int = ILS_RESTART_ITERATIONS,
):
    """The ILS restarts (``iterations`` each) with seeds 1..``restarts`` from ``start``, after the first walk found
    ``chosen``: in seed order, a restart's family replaces the best so far when it is larger, and
    the restarts stop once the best reaches ``bound``.  Returns (best, iterations, restarts run).

    The restarts are independent, so with a dask scheduler (``--scheduler`` /
    ``STARFORGE_SCHEDULER``) they run at once on the cluster (:func:`starforge.runtime.engine.map_tasks`)
    and their results are then taken in seed order exactly as above (the ones past the stop are
    dropped): the same family and counts byte for byte, whatever the number of workers and the
    order they finish in.  Otherwise they run here one after another, stopping at the bound.
    """
    from starforge.runtime import engine

    seeds = list(range(1, restarts + 1))
    if len(chosen) >= bound or not seeds:
        return chosen, 0, 0
    if engine.plan(len(seeds), 0.0).mode == "serial":  # no scheduler: lazily, so the stop saves work
        results = (_restart_task((start, order, ptr, rows, n_rows, bound, s, iterations)) for s in seeds)
    else:
        results = iter(
            engine.map_tasks(
                _restart_task,
                [(start, order, ptr, rows, n_rows, bound, s, iterations) for s in seeds],
                what=f"{len(seeds)} ILS restarts",
            )
        )
    used = ran = 0
    for got, k in results:
        used += k
        ran += 1
        if len(got) > len(chosen):
            chosen = got
        if len(chosen) >= bound:
            break
    return chosen, used, ran


#: HiGHS branch-and-bound work budget, in nonzeros x nodes: a deterministic effort limit, so
#: results are the same at any load (the spec's ``work`` sets it for ``stars``)
MILP_WORK = WORK
MILP_NODE_LIMIT = 6000
#: largest set packing (nonzeros of the window matrix) handed to the exact solver; past it the
#: root relaxation alone takes tens of seconds
MILP_MAX_NONZEROS = 40_000


def node_budget(nonzeros: int, work: int = MILP_WORK) -> int:
    """Nodes HiGHS may explore for a problem with ``nonzeros`` entries: ``work / nonzeros``, at
    least 20 and at most :data:`MILP_NODE_LIMIT` scaled by ``work / MILP_WORK``."""
    cap = MILP_NODE_LIMIT * max(1.0, work / MILP_WORK)
    return int(max(20, min(cap, work // max(1, nonzeros))))


def milp(ptr, rows, n_rows, cols: np.ndarray, time_limit: float | None, node_limit: int = MILP_NODE_LIMIT):
    """Exact set packing over ``cols`` with HiGHS.

    ``time_limit`` (s): a wall-clock safety limit; None: none, the node limit alone stops the
    solver (deterministic: the same answer on any machine, however fast).

    Returns (chosen, dual_bound, status, reproducible): ``reproducible`` is True when HiGHS
    stopped at optimality or at the node limit (the same input gives the same answer), False
    when the wall-clock time limit stopped it (the incumbent and bound then depend on timing).
    """
    import scipy.sparse as sp
    from scipy.optimize import Bounds, LinearConstraint
    from scipy.optimize import milp as _milp

    cols = np.asarray(cols)
    counts = ptr[cols + 1] - ptr[cols]
    col_idx = np.repeat(np.arange(len(cols)), counts)
    row_idx = (
        np.concatenate([rows[ptr[c] : ptr[c + 1]] for c in cols.tolist()]) if len(cols) else np.zeros(0, int)
    )
    A = sp.csr_matrix((np.ones(len(col_idx)), (row_idx, col_idx)), shape=(n_rows, len(cols)))
    res = _milp(
        -np.ones(len(cols)),
        constraints=LinearConstraint(A, -np.inf, 1),
        integrality=np.ones(len(cols)),
        bounds=Bounds(0, 1),
        options={"node_limit": int(node_limit), "disp": False}
        | ({} if time_limit is None else {"time_limit": float(time_limit)}),
    )
    chosen = cols[np.flatnonzero(res.x > 0.5)] if res.x is not None else np.zeros(0, dtype=np.intp)
    dual = getattr(res, "mip_dual_bound", None)
    dual = int(np.floor(-dual + 1e-6)) if dual is not None and np.isfinite(dual) else None
    timed_out = "time limit" in str(res.message).lower()
    reproducible = res.x is not None and (res.status == 0 or not timed_out)
    status = "optimal" if res.status == 0 else ("time limit" if timed_out else "node limit")
    return chosen, dual, status, reproducible


def select_family(
    index,
    pool,
    volume,
    star_of,
    row,
    n_rows,
    spec: StarSpec,
    ils_iterations: int | None = None,
    bound: int | None = None,
    n_undecided: int = 0,
    milp_work: int | None = None,
    order: np.ndarray | None = None,
) -> Selection:
    """Choose the family among the candidates (see module docstring).

    ``ils_iterations``: iteration budget of the iterated local search (default
    :data:`ILS_ITERATIONS`; 0 skips it).  ``bound``: a certified upper bound computed by the
    caller over a superset of every fitting star (default: the block bound over ``index``).
    ``n_undecided``: stars left out of ``index`` that might fit; the solver's dual bound covers
    ``index`` only, so it certifies ``dual + n_undecided`` (an optimal family over a superset
    loses at most those stars when they are removed).
    ``milp_work``: the exact solver's work budget (nonzeros x nodes; default ``spec.work``): its
    node limit alone stops it, never the wall clock, so the family and bound are the same on any
    machine and at any load.  ``order``: :func:`compactness_order` of the candidates when the
    caller has it already.
    """
    n = len(index)
    ptr, rows = csr_rows(star_of, row, n)
    order = compactness_order(index, pool, volume) if order is None else order
    t0 = time.perf_counter()
    chosen = greedy(order, ptr, rows, n_rows)
    info: dict = {"greedy": int(len(chosen)), "greedy_s": round(time.perf_counter() - t0, 3)}
    if bound is None:
        bound = block_bound(index, spec.grid_steps)
    info["block_bound"] = bound
    info["bound_from"] = "blocks"
    if spec.select == "greedy":
        return Selection(chosen, bound, info)
    t1 = time.perf_counter()
    # local search and ILS on one packing state (local_search and ils, without building it twice);
    # neighbours found by key (the same as by shared window, with fewer repeats)
    points = key_points(index, spec.rule, spec.grid_steps, len(pool))
    packing = Packing(chosen, ptr, rows, n_rows, rank_of(order), points)
    swaps = packing.local_search(200)
    chosen = packing.family
    info.update(local_search=int(len(chosen)), swaps=swaps, local_search_s=round(time.perf_counter() - t1, 3))
    budget = ILS_ITERATIONS if ils_iterations is None else int(ils_iterations)
    nnz = int(len(rows))
    if budget > 0 and len(chosen) < bound:
        t3 = time.perf_counter()
        start = chosen
        used = packing.ils(budget, bound, ILS_SEED)
        chosen = packing.family
        restarts = 0
        if nnz <= MILP_MAX_NONZEROS:
            # small instances: a few short restarts with other fixed seeds before the exact solver
            # (a tight packing that one walk misses is often found by another within ~1 s, and a
            # family that reaches the certified bound is proven optimal without the solver)
            chosen, k, restarts = ils_restarts(chosen, start, order, ptr, rows, n_rows, bound)
            used += k
        info.update(
            ils=int(len(chosen)),
            ils_iterations=int(used),
            ils_restarts=restarts,
            ils_s=round(time.perf_counter() - t3, 3),
        )
    else:
        info.update(ils=int(len(chosen)), ils_iterations=0)
    if len(chosen) < bound and nnz <= MILP_MAX_NONZEROS:
        # exact set packing over every candidate under a deterministic node budget (no wall
        # clock), so the same spec gives the same family and bound at any load
        t2 = time.perf_counter()
        nodes = node_budget(nnz, spec.work if milp_work is None else int(milp_work))
        m_chosen, dual, status, reproducible = milp(ptr, rows, n_rows, np.arange(n), None, nodes)
        info.update(
            milp_columns=int(n), milp_node_budget=nodes, milp_status=status, milp_used=bool(reproducible)
        )
        info["milp_s"] = round(time.perf_counter() - t2, 3)
        if reproducible:
            if len(m_chosen) > len(chosen):
                chosen = np.sort(m_chosen)
            solver_bound = None
            if dual is not None:
                solver_bound = dual + n_undecided
            if status == "optimal":
                solver_bound = min(solver_bound or len(m_chosen) + n_undecided, len(m_chosen) + n_undecided)
            if solver_bound is not None and solver_bound < bound:
                bound = solver_bound
                info["bound_from"] = "solver"
        else:
            info["milp_note"] = "the solver returned no solution: its result is not used"
    elif len(chosen) < bound:
        info["milp_skipped"] = (
            f"{nnz:,} nonzeros > {MILP_MAX_NONZEROS:,}: family from greedy + local search, bound from blocks"
        )
    info["proven_optimal"] = bool(len(chosen) >= bound)
    return Selection(np.sort(chosen), bound, info)
