"""Family selection: set packing over key windows (see :mod:`starforge.stars.rules`).

* ``greedy``: the paper's way, growing a family from the most compact star: take stars in
  order of box volume (then total length) and keep each one that conflicts with none taken.
* ``max``: as large a family as possible.  Greedy, then a deterministic (1,2)-swap local
  search (remove one star, insert two that only conflicted with it), then an iterated local
  search (``ils``: Andrade-Resende-Werneck style, fixed seed, iteration budget
  ``ILS_ITERATIONS``; on small instances also ``ILS_RESTARTS`` short restarts with other fixed
  seeds), then, when the window matrix is small enough (``MILP_MAX_NONZEROS``), the
  exact MILP (HiGHS through ``scipy.optimize.milp``) under a deterministic node budget
  (:func:`node_budget`); a run cut by the wall-clock safety limit is not used.

Upper bounds are certified: the caller's block bound over every star that may fit, tightened by
the solver's dual bound (plus the undecided stars it did not see) when it ran.

Everything is deterministic: the same spec gives the same family.
"""

from __future__ import annotations

import heapq
import itertools
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from starforge.stars.rules import key_triples
from starforge.stars.spec import StarSpec


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
    index = np.asarray(index)
    base = int(index.max()) + 1 if index.size else 1
    if base**6 < 2**62:  # the six indices as one key: the same order as six keys, sorted once
        code = index[:, 0].astype(np.int64)
        for k in range(1, 6):
            code = code * base + index[:, k]
        return np.lexsort((code, pool[index].sum(axis=1), np.round(volume, 9)))
    keys = [index[:, k] for k in range(5, -1, -1)]
    return np.lexsort((*keys, pool[index].sum(axis=1), np.round(volume, 9)))


def greedy(order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """Take stars in ``order``; keep each whose rows are all still free."""
    return _greedy(np.asarray(order, dtype=np.int64), np.asarray(ptr, dtype=np.int64),
                   np.asarray(rows, dtype=np.int64), int(n_rows)).astype(np.intp)


@numba.njit(cache=True)
def _greedy(order, ptr, rows, n_rows):
    used = np.zeros(n_rows, dtype=np.bool_)
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
                used[rows[j]] = True
            out[k] = i
            k += 1
    return out[:k]


def _count_blocks(faces: np.ndarray, m: int) -> int:
    """Fewest distinct face blocks of side m over the m^3 placements of the block grid.

    ``faces`` (k, 3): non-negative integer face keys of any integer type.  Each block is coded
    as one integer in the narrowest type that holds every code (int32 for the pools stars use),
    column by column: no (k, 3) int64 copy, and half the memory traffic."""
    faces = np.asarray(faces)
    if not len(faces):
        return 0
    top = int(faces.max()) + m  # bounds (x + o) // m + 1 over the placements, and so base
    dt = np.int32 if top**3 < 2**31 else np.int64
    cols = [faces[:, j].astype(dt) for j in range(3)]
    best = None
    for o in np.ndindex(m, m, m):
        # (integer floor division is slow in numpy, and with m = 1 the blocks are the keys)
        f = [(c + oj) // m for c, oj in zip(cols, o, strict=True)] if m > 1 else cols
        base = max(int(x.max()) for x in f) + 1
        code = (f[0] * base + f[1]) * base + f[2]  # one integer per block, < base**3
        if base**3 <= 1 << 26:
            used = np.zeros(base**3, dtype=bool)
            used[code] = True
            blocks = int(np.count_nonzero(used))
        else:
            blocks = len(np.unique(code))
        best = blocks if best is None else min(best, blocks)
    return int(best)


def block_bound(index: np.ndarray, m: int) -> int:
    """Proven upper bound: face keys in one block of side m (grid steps) conflict pairwise and a
    star's four faces lie in four different blocks, so a family has at most blocks // 4 stars.
    Every placement of the block grid gives a bound; the smallest of the m^3 is returned."""
    faces = key_triples(index, "face")[:, :4].reshape(-1, 3)
    if not len(faces):
        return 0
    return _count_blocks(faces, m) // 4


def pool_face_bound(pool_mm: np.ndarray, m: int, diagonal_mm: float) -> int:
    """Certified upper bound without enumerating stars: every face of a star is a triangle of
    pool lengths whose sides differ by >= m steps (the tolerance within a star), obeys the
    triangle inequality and is no longer than the centres' box diagonal; the block bound over all
    such triangles covers every family (it counts what any star could use, not what fits)."""
    n = len(pool_mm)
    i, j, k = np.array(list(itertools.combinations(range(n), 3)), dtype=np.int64).reshape(-1, 3).T
    ok = (
        (j - i >= m)
        & (k - j >= m)
        & (pool_mm[i] + pool_mm[j] > pool_mm[k] + 1e-9)
        & (pool_mm[k] <= diagonal_mm + 1e-9)
    )
    faces = np.stack([i[ok], j[ok], k[ok]], axis=1)
    if not len(faces):
        return 0
    return _count_blocks(faces, m) // 4


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


#: default iteration budget of the iterated local search (``ils``); the stopping rule is this
#: count, never wall time, so the same candidates always give the same family
ILS_ITERATIONS = 800
#: seed of the ILS random generator (fixed: nothing time-dependent)
ILS_SEED = 0
#: on instances small enough for the exact solver, restarts of the ILS from the local-search
#: family with seeds 1..ILS_RESTARTS, each ILS_RESTART_ITERATIONS long (stopped at the bound)
ILS_RESTARTS = 8
ILS_RESTART_ITERATIONS = 1000


class _Packing:
    """Incremental set-packing state for :func:`ils`.

    ``owner[r]`` is the family star holding row r (-1 free).  Per candidate c, over its rows held
    by family stars: ``cnt`` (how many), ``s1`` (sum of owner ids) and ``s2`` (sum of squares).
    c is free iff ``cnt == 0``; its held rows all belong to ONE star t iff
    ``cnt * s2 == s1**2`` (zero variance), and then ``t = s1 // cnt``.  Inserting or removing a
    star only updates the candidates sharing a row with it (row -> candidates index, CSC).
    """

    def __init__(self, chosen, ptr, rows, n_rows, rank):
        import scipy.sparse as sp

        n = len(ptr) - 1
        self.n, self.ptr, self.rows, self.rank = n, ptr, rows, rank
        # row -> candidates (CSC of the incidence), candidates ascending within a row
        inc = sp.csr_matrix((np.ones(len(rows), dtype=np.int8), rows, ptr), shape=(n, n_rows)).tocsc()
        self.cands, self.rptr = inc.indices.astype(np.int64), inc.indptr.astype(np.int64)
        self.ptr64, self.rows64 = np.asarray(ptr, dtype=np.int64), np.asarray(rows, dtype=np.int64)
        # touched() of one star is at most (its rows) x (the most candidates on a row) entries
        per_row = np.diff(self.rptr)
        most = int(np.diff(ptr).max()) * int(per_row.max()) if n and n_rows else 0
        self._buf = np.empty(max(most, 1), dtype=np.int64)
        self._lst = np.empty(max(most, 1), dtype=np.int64)
        self._seen = np.zeros(n, dtype=np.bool_)
        self.rank64 = np.asarray(rank, dtype=np.int64)
        # rows per candidate padded with the sentinel row n_rows (never owned), for batch checks
        counts = np.diff(ptr)
        width = int(counts.max()) if n else 0
        dtype = np.int32 if n_rows < 2**31 - 1 else np.int64
        if n and (counts == width).all():
            self.padded = rows.reshape(n, width).astype(dtype)
        else:
            star_of_entry = np.repeat(np.arange(n, dtype=np.int64), counts)
            self.padded = np.full((n, width), n_rows, dtype=dtype)
            self.padded[star_of_entry, np.arange(len(rows)) - np.repeat(ptr[:-1], counts)] = rows
        self.owner = np.full(n_rows + 1, -1, dtype=np.int64)
        self.in_fam = np.zeros(n, dtype=bool)
        # cnt, s1, s2, tight side by side: an update touches all four of a candidate (one cache line)
        self.state = np.zeros((n, 4), dtype=np.int64)
        self.state[:, 3] = -1
        self.cnt, self.s1, self.s2 = self.state[:, 0], self.state[:, 1], self.state[:, 2]
        self.tight = self.state[:, 3]  # t if 1-tight with family star t, else -1
        self.size = 0
        self.log: list[tuple[int, int]] | None = None  # (+1 insert / -1 remove, star)
        for s in np.asarray(chosen).tolist():
            self.insert(s)

    def rows_of(self, s: int) -> np.ndarray:
        return self.rows[self.ptr[s] : self.ptr[s + 1]]

    def touched(self, s: int) -> np.ndarray:
        """Candidates sharing a row with s, once per shared row."""
        k = _gather(s, self.ptr64, self.rows64, self.rptr, self.cands, self._buf)
        return self._buf[:k].copy()

    def _update(self, s: int, sign: int) -> np.ndarray:
        k = _update_kernel(
            s, sign, self.ptr64, self.rows64, self.rptr, self.cands,
            self.state, self.in_fam, self._buf,
        )
        return self._buf[:k].copy()

    def insert(self, s: int) -> np.ndarray:
        self.owner[self.rows_of(s)] = s
        self.in_fam[s] = True
        self.size += 1
        if self.log is not None:
            self.log.append((1, s))
        return self._update(s, 1)

    def remove(self, s: int) -> np.ndarray:
        self.owner[self.rows_of(s)] = -1
        self.in_fam[s] = False
        self.size -= 1
        if self.log is not None:
            self.log.append((-1, s))
        return self._update(s, -1)

    def undo(self) -> None:
        log, self.log = self.log, None
        for op, s in reversed(log):
            if op > 0:
                self.remove(s)
            else:
                self.insert(s)
        self.log = []

    def fill(self, aff: np.ndarray) -> list[np.ndarray]:
        """Insert the free candidates among ``aff``, most compact first; returns touched sets."""
        free = np.unique(aff[(self.cnt[aff] == 0) & ~self.in_fam[aff]])
        out = []
        if len(free):
            for c in free[np.argsort(self.rank[free], kind="stable")].tolist():
                if self.cnt[c] == 0 and not self.in_fam[c]:
                    out.append(self.insert(c))
        return out

    def tight_owners(self, aff: np.ndarray) -> np.ndarray:
        """Family stars t that some candidate in ``aff`` conflicts with alone (1-tight)."""
        t = self.tight[aff]
        return np.unique(t[t >= 0])

    def two_swap(self, t: int):
        """Best (1,2)-swap for family star t: two disjoint candidates whose only conflict is t,
        most compact first; None if none."""
        a, b = _two_swap(
            t, self.ptr64, self.rows64, self.rptr, self.cands, self.state, self.rank64, self._seen, self._buf,
            self._lst,
        )
        return None if a < 0 else (int(a), int(b))

    def descend(self, queue: set[int]) -> None:
        """(1,2)-swaps (and free insertions) until none is left for the queued stars, the most
        compact queued star first (a heap of ranks: ranks are distinct, so the order is the one
        of repeatedly taking the queue's minimum)."""
        rank = self.rank
        heap = [(int(rank[t]), t) for t in queue]
        heapq.heapify(heap)
        while heap:
            _, t = heapq.heappop(heap)
            queue.discard(t)
            if not self.in_fam[t]:
                continue
            pair = self.two_swap(t)
            if pair is None:
                continue
            touched = [self.remove(t), self.insert(pair[0]), self.insert(pair[1])]
            touched += self.fill(touched[0])
            for aff in touched:
                for x in self.tight_owners(aff).tolist():
                    if x not in queue:
                        queue.add(x)
                        heapq.heappush(heap, (int(rank[x]), x))


@numba.njit(cache=True, nogil=True)
def _gather(s, ptr, rows, rptr, cands, out):
    """Write the candidates sharing a row with star s (once per shared row, rows in order) into
    ``out``; returns how many."""
    k = 0
    for j in range(ptr[s], ptr[s + 1]):
        r = rows[j]
        for q in range(rptr[r], rptr[r + 1]):
            out[k] = cands[q]
            k += 1
    return k


@numba.njit(cache=True, nogil=True)
def _update_kernel(s, sign, ptr, rows, rptr, cands, state, in_fam, out):
    """:class:`_Packing`'s bookkeeping when star s enters (sign +1) or leaves (-1) the family:
    per candidate sharing rows with s, the count, sum and sum of squares of the family stars
    holding its rows (``state`` columns 0-2), then whether they all belong to one star
    (column 3, ``tight``).  Writes the touched
    entries into ``out`` (as :func:`_gather`) and returns how many."""
    k = _gather(s, ptr, rows, rptr, cands, out)
    ss = s * s
    for i in range(k):
        c = out[i]
        state[c, 0] += sign
        state[c, 1] += sign * s
        state[c, 2] += sign * ss
    for i in range(k):
        c = out[i]
        n, s1 = state[c, 0], state[c, 1]
        if n > 0 and n * state[c, 2] == s1 * s1 and not in_fam[c]:
            state[c, 3] = s1 // n
        else:
            state[c, 3] = -1
    return k


@numba.njit(cache=True, nogil=True)
def _two_swap(t, ptr, rows, rptr, cands, state, rank, seen, buf, lst):
    """The first pair, in rank order (most compact first), of distinct candidates 1-tight with
    family star t (``state[:, 3] == t``) whose rows are disjoint; (-1, -1) if none.  ``seen``
    (all False, left so), ``buf`` and ``lst`` are scratch space."""
    k = _gather(t, ptr, rows, rptr, cands, buf)
    m = 0
    for i in range(k):
        c = buf[i]
        if state[c, 3] == t and not seen[c]:
            seen[c] = True
            lst[m] = c
            m += 1
    for i in range(m):
        seen[lst[i]] = False
    # by rank (a permutation: no ties), insertion sort: these lists are short
    for i in range(1, m):
        c = lst[i]
        j = i
        while j > 0 and rank[lst[j - 1]] > rank[c]:
            lst[j] = lst[j - 1]
            j -= 1
        lst[j] = c
    for i in range(m - 1):
        a = lst[i]
        for j in range(i + 1, m):
            b = lst[j]
            apart = True
            for x in range(ptr[a], ptr[a + 1]):
                for y in range(ptr[b], ptr[b + 1]):
                    if rows[x] == rows[y]:
                        apart = False
                        break
                if not apart:
                    break
            if apart:
                return a, b
    return -1, -1


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
    Deterministic: the only randomness is ``np.random.default_rng(seed)`` and the budget is an
    iteration count.  Stops early at ``bound``.  Returns (family, iterations used).
    """
    n = len(ptr) - 1
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    P = _Packing(chosen, ptr, rows, n_rows, rank)
    # start from a local optimum w.r.t. free insertions and (1,2)-swaps
    P.fill(np.arange(n))
    P.descend(set(np.flatnonzero(P.in_fam).tolist()))
    rng = np.random.default_rng(seed)
    owner = P.owner
    it = 0
    while n and it < iterations and (bound is None or P.size < bound):
        it += 1
        # perturbation: a random outside candidate held by one or two family stars
        s = -1
        for _ in range(64):
            batch = rng.integers(0, n, size=1024)
            # the first such draw of the batch; its first 64 draws nearly always hold one, so
            # they are looked at first (the same draw either way)
            for part in (batch[:64], batch[64:]):
                own = np.sort(owner[P.padded[part]], axis=1)  # -1 = free row or pad
                new = np.concatenate([own[:, :1] >= 0, (own[:, 1:] != own[:, :-1]) & (own[:, 1:] >= 0)], axis=1)
                distinct = new.sum(axis=1)  # family stars holding the candidate's rows
                ok = np.flatnonzero((distinct >= 1) & (distinct <= 2) & ~P.in_fam[part])
                if len(ok):
                    s = int(part[ok[0]])
                    held = np.unique(own[ok[0]])
                    held = held[held >= 0]
                    break
            if s >= 0:
                break
        if s < 0:
            break
        before = P.size
        P.log = []
        touched = [P.remove(t) for t in held.tolist()]
        touched.append(P.insert(s))
        for aff in touched[: len(held)]:
            touched += P.fill(aff)
        queue: set[int] = set()
        for aff in touched:
            queue.update(P.tight_owners(aff).tolist())
        P.descend(queue)
        if P.size < before:
            P.undo()
        P.log = None
    return np.flatnonzero(P.in_fam), it


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
    ``STARFORGE_SCHEDULER``) they run at once on the cluster (:func:`starforge.engine.map_tasks`)
    and their results are then taken in seed order exactly as above (the ones past the stop are
    dropped): the same family and counts byte for byte, whatever the number of workers and the
    order they finish in.  Otherwise they run here one after another, stopping at the bound.
    """
    from starforge import engine

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


#: HiGHS branch-and-bound work budget, in nonzeros x nodes: a deterministic effort limit (the
#: wall-clock limit is only a safety net; a run it cuts is not used, so results stay reproducible)
MILP_WORK = 8_000_000
MILP_NODE_LIMIT = 6000
#: largest set packing (nonzeros of the window matrix) handed to the exact solver; past it the
#: root relaxation alone takes tens of seconds (measured: 83,544 nonzeros, 10 s)
MILP_MAX_NONZEROS = 40_000


def node_budget(nonzeros: int, work: int = MILP_WORK) -> int:
    """Nodes HiGHS may explore for a problem with ``nonzeros`` entries (at least 20)."""
    return int(max(20, min(MILP_NODE_LIMIT, work // max(1, nonzeros))))


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
    milp_work: int = MILP_WORK,
    deterministic: bool = False,
) -> Selection:
    """Choose the family among the candidates (see module docstring).

    ``ils_iterations``: iteration budget of the iterated local search (default
    :data:`ILS_ITERATIONS`; 0 skips it).  ``bound``: a certified upper bound computed by the
    caller over a superset of every fitting star (default: the block bound over ``index``).
    ``n_undecided``: stars left out of ``index`` that might fit; the solver's dual bound covers
    ``index`` only, so it certifies ``dual + n_undecided`` (an optimal family over a superset
    loses at most those stars when they are removed).
    ``deterministic``: the exact solver runs without its wall-clock safety limit
    (``spec.time_limit_s``), stopped by the node budget alone, so the family and bound are the
    same on any machine (the sweep's exhaustive cells).
    """
    n = len(index)
    ptr, rows = _csr(star_of, row, n)
    order = compactness_order(index, pool, volume)
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
    chosen, swaps = local_search(chosen, order, ptr, rows, n_rows)
    info.update(local_search=int(len(chosen)), swaps=swaps, local_search_s=round(time.perf_counter() - t1, 3))
    budget = ILS_ITERATIONS if ils_iterations is None else int(ils_iterations)
    nnz = int(len(rows))
    if budget > 0 and len(chosen) < bound:
        t3 = time.perf_counter()
        start = chosen
        chosen, used = ils(start, order, ptr, rows, n_rows, iterations=budget, bound=bound)
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
        # exact set packing over every candidate under a deterministic node budget; a run cut
        # by the wall-clock safety limit is not used, so the same spec gives the same family
        t2 = time.perf_counter()
        nodes = node_budget(nnz, milp_work)
        wall = None if deterministic else spec.time_limit_s
        m_chosen, dual, status, reproducible = milp(ptr, rows, n_rows, np.arange(n), wall, nodes)
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
            info["milp_note"] = (
                "stopped by --time-limit before its node budget: not used, so runs stay reproducible"
            )
    elif len(chosen) < bound:
        info["milp_skipped"] = (
            f"{nnz:,} nonzeros > {MILP_MAX_NONZEROS:,}: family from greedy + local search, bound from blocks"
        )
    info["proven_optimal"] = bool(len(chosen) >= bound)
    return Selection(np.sort(chosen), bound, info)
