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

import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from starforge.runtime.kernels import numba
from starforge.stars.rules import key3, key_triples
from starforge.stars.spec import WORK, StarSpec

#: the kernels only ever called from other kernels: no Python or C-callback wrapper, and no
#: cache entry of their own (each is compiled into its one caller, whose cache entry holds it;
#: a warm run loads the caller and compiles nothing).  Each wrapper and cache write costs a
#: first run tens of milliseconds per kernel.
_inner = numba.njit(nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)


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


def count_blocks(faces: np.ndarray, m: int) -> int:
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


#: stars from which :func:`block_bound` counts blocks in compiled code (``--delta 1.0``'s 5.2 M
#: in 0.1 s instead of numpy's 1.7 s); below, numpy (the finger default's 0.36 M in 0.02 s, and
#: no kernel to compile on a first run)
BLOCK_KERNEL_STARS = 1_000_000


def block_bound(index: np.ndarray, m: int) -> int:
    """Proven upper bound: face keys in one block of side m (grid steps) conflict pairwise and a
    star's four faces lie in four different blocks, so a family has at most blocks // 4 stars.
    Every placement of the block grid gives a bound; the smallest of the m^3 is returned."""
    index = np.asarray(index)
    if not len(index):
        return 0
    if len(index) >= BLOCK_KERNEL_STARS:
        return _count_face_blocks_compiled(index, m) // 4
    faces = key_triples(index, "face")[:, :4].reshape(-1, 3)
    return count_blocks(faces, m) // 4


def _count_face_blocks_compiled(index: np.ndarray, m: int) -> int:
    """:func:`count_blocks` of the stars' face keys (the same count), straight from their pool
    indices (n, 6) in compiled code: no (4 n, 3) array of keys, one table of blocks."""
    from starforge.geometry.tetra import FACE_EDGES

    index = np.ascontiguousarray(index)
    base = (int(index.max()) + m - 1) // m + 1  # past every block coordinate (x + o) // m
    if base**3 > 1 << 26:  # a table that large: the general count
        return count_blocks(key_triples(index, "face")[:, :4].reshape(-1, 3), m)
    used = np.zeros(base**3, dtype=np.bool_)
    edges = np.ascontiguousarray(FACE_EDGES, dtype=np.int64)
    return min(
        int(_face_blocks(index, edges, int(m), int(a), int(b), int(c), int(base), used))
        for a, b, c in np.ndindex(m, m, m)
    )


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _face_blocks(index, edges, m, o0, o1, o2, base, used):
    """Distinct blocks ``((lo + o0) // m, (mid + o1) // m, (hi + o2) // m)`` of the stars' four
    face keys (each face's three pool indices sorted); ``used`` (base^3 bools) is scratch."""
    used[:] = False
    count = 0
    for i in range(index.shape[0]):
        for f in range(4):
            lo, mid, hi = key3(index, i, edges, f)
            code = (((lo + o0) // m) * base + (mid + o1) // m) * base + (hi + o2) // m
            if not used[code]:
                used[code] = True
                count += 1
    return count


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
    return count_blocks(faces, m) // 4


def local_search(
    chosen: np.ndarray, order: np.ndarray, ptr: np.ndarray, rows: np.ndarray, n_rows: int, rounds: int = 200
) -> tuple[np.ndarray, int]:
    """(1,2)-swaps until none is left (or ``rounds``); returns the family and the swaps made.

    Each round looks at the family as it stood when the round began: it first inserts the stars
    that were free then and still are, most compact first; then, per family star t (by id), it
    takes the outside stars whose held rows all belonged to t, most compact first, keeps those
    that still conflict with nothing but t, and the first two of them that are disjoint replace
    t.  Compiled (:func:`_search`, on :class:`_Packing`'s incremental state)."""
    P = _Packing(chosen, ptr, rows, n_rows, _rank(order))
    swaps = _local_search_on(P, int(rounds))
    return np.flatnonzero(P.in_fam), int(swaps)


def _local_search_on(P: _Packing, rounds: int) -> int:
    """:func:`local_search`'s rounds on the packing ``P`` (which they change); returns the swaps
    made.  Each round's view (the free and the 1-tight candidates, sorted) is taken here, the
    round itself is compiled (:func:`_search`, task 3)."""
    swaps = 0
    for _ in range(rounds):
        t = P.tight
        free = np.flatnonzero(t == FREE)
        one = np.flatnonzero(t >= 0)
        lists = np.zeros((3, max(len(free), len(one))), dtype=np.int64)
        lists[0, : len(free)] = free[np.argsort(P.rank[free])]
        one = one[np.lexsort((P.rank[one], t[one]))]
        lists[1, : len(one)], lists[2, : len(one)] = one, t[one]
        got = _search(P.arrays, 3, lists, np.array([len(free), len(one)], dtype=np.int64), 0, -1)
        if got < 0:
            break
        swaps += got
    return swaps


def _rank(order: np.ndarray) -> np.ndarray:
    """Each candidate's position in ``order`` (int64)."""
    order = np.asarray(order)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank


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
    """Incremental set-packing state for :func:`ils`, as arrays its compiled kernels share.

    ``owner[r]`` is the family star holding row r (-1 free).  Per candidate c, over its rows held
    by family stars: ``cnt`` (how many), ``s1`` (sum of owner ids) and ``s2`` (sum of squares).
    c is free iff ``cnt == 0``; its held rows all belong to ONE star t iff
    ``cnt * s2 == s1**2`` (zero variance), and then ``t = s1 // cnt``.  ``tight[c]`` says which:
    -2 free, t when c is outside the family and 1-tight with t, else -1 (a small array of its
    own, int32: the searches read only it, and it stays in the CPU cache).  Inserting or removing
    a star only updates the candidates sharing a row with it (row -> candidates index, CSC).
    ``arrays`` is the tuple every kernel takes (:func:`_set`, :func:`_fill`, :func:`_descend`,
    :func:`_search`).
    """

    def __init__(self, chosen, ptr, rows, n_rows, rank):
        ptr = np.asarray(ptr, dtype=np.int64)
        rows = np.asarray(rows, dtype=np.int64)
        rank = np.asarray(rank, dtype=np.int64)
        self.rank = rank
        n = len(ptr) - 1
        self.n, self.n_rows = n, int(n_rows)
        rptr, cands = _csc(ptr, rows, self.n_rows)  # row -> candidates, ascending within a row
        # the candidates sharing rows with one star: at most (its rows) x (the most on a row)
        most = int(np.diff(ptr).max()) * int(np.diff(rptr).max()) if n and n_rows else 0
        order = np.empty(n, dtype=np.int64)
        order[rank] = np.arange(n)
        # cnt, s1, s2 side by side: an update touches all three of a candidate
        self.tally = np.zeros((n, 3), dtype=np.int64)
        self.cnt, self.s1, self.s2 = self.tally[:, 0], self.tally[:, 1], self.tally[:, 2]
        self.tight = np.full(n, FREE, dtype=np.int32)
        self.ntight = np.zeros(n, dtype=np.int32)
        self.in_fam = np.zeros(n, dtype=np.bool_)
        self.owner = np.full(self.n_rows, -1, dtype=np.int64)
        self.arrays = (
            ptr, rows, rptr, cands, rank, order, self.tally, self.tight, self.ntight, self.in_fam, self.owner,
            np.empty(max(most, 1), dtype=np.int64),  # buf: touched candidates
            np.empty(max(most, 1), dtype=np.int64),  # lst: a star's free or 1-tight neighbours
            np.zeros(n, dtype=np.bool_),  # seen (all False between calls)
            np.empty(n + 1, dtype=np.int64),  # heap of queued ranks
            np.zeros(n, dtype=np.bool_),  # queued
            np.zeros(4 * max(most, 1) + 1, dtype=np.int64),  # hits: the 1-tight found since a reset
            # ops: the changes of one ILS step (s + 1: s inserted, -(s + 1): removed).  Each swap
            # and each fill grows the family by one, so a step makes at most 3 x (the largest
            # family) + 3 changes; a family holds at most one star per row, plus stars without rows
            np.empty(3 * min(n, self.n_rows + int((np.diff(ptr) == 0).sum())) + 8, dtype=np.int64),
            np.zeros(self.n_rows, dtype=np.bool_),  # mark: a False per row between calls
        )
        chosen = np.asarray(chosen, dtype=np.int64)
        _search(self.arrays, 0, chosen.reshape(1, -1), _NO_CTR, len(chosen), -1)

    @property
    def size(self) -> int:
        return int(self.in_fam.sum())

    def insert(self, s: int) -> None:
        _set(int(s), 1, self.arrays)

    def remove(self, s: int) -> None:
        _set(int(s), -1, self.arrays)

    def undo(self, ops: np.ndarray) -> None:
        """Revert ``ops`` (s + 1 for an insertion of s, -(s + 1) for a removal), last first."""
        _undo(np.asarray(ops, dtype=np.int64), 0, len(ops), self.arrays)


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _csc(ptr, rows, n_rows):
    """The row -> candidates index of the incidence (candidates ascending within a row)."""
    rptr = np.empty(n_rows + 1, dtype=np.int64)  # int64 np.empty only: see _greedy
    for r in range(n_rows + 1):
        rptr[r] = 0
    for j in range(len(rows)):
        rptr[rows[j] + 1] += 1
    for r in range(n_rows):
        rptr[r + 1] += rptr[r]
    at = np.empty(n_rows, dtype=np.int64)
    for r in range(n_rows):
        at[r] = rptr[r]
    cands = np.empty(len(rows), dtype=np.int64)
    for c in range(len(ptr) - 1):
        for j in range(ptr[c], ptr[c + 1]):
            r = rows[j]
            cands[at[r]] = c
            at[r] += 1
    return rptr, cands


#: ``_Packing.tight`` of a free candidate (no row held by the family)
FREE = -2


@_inner
def _neighbours(t, want, ptr, rows, rptr, cands, tight, rank, seen, lst):
    """The candidates sharing a row with star t whose ``tight`` is ``want`` (-2: free; t:
    1-tight with t), each once, most compact first, in ``lst[:m]``; returns m.  ``seen`` (all
    False) is left so.  The sort by rank (a permutation: no ties, so an unstable sort does) is
    Shell's sort, gaps ~m/2.2^k ending in 1 (insertion sort for short lists), written here, its
    one caller: no numpy sort in the kernels (each costs seconds of compilation on a first run),
    and as a kernel of its own it was compiled twice (``m`` typed once as the literal 0)."""
    m = 0
    for j in range(ptr[t], ptr[t + 1]):
        r = rows[j]
        for q in range(rptr[r], rptr[r + 1]):
            c = cands[q]
            if tight[c] == want and not seen[c]:
                seen[c] = True
                lst[m] = c
                m += 1
    for i in range(m):
        seen[lst[i]] = False
    gap = m // 2
    while gap > 0:
        for i in range(gap, m):
            v = lst[i]
            rv = rank[v]
            j = i
            while j >= gap and rank[lst[j - gap]] > rv:
                lst[j] = lst[j - gap]
                j -= gap
            lst[j] = v
        gap = 0 if gap == 1 else max(1, int(gap / 2.2))
    return m


#: the signs :func:`_set` takes, as int64 (a literal argument would compile a kernel again)
_ONE = np.int64(1)
_MINUS = np.int64(-1)


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _set(s, sign, P):
    """Star s enters (sign +1) or leaves (-1) the family: its rows' owner and membership, then
    per candidate sharing rows with s (``buf``: once per shared row) the count, sum and sum of
    squares of the family stars holding its rows (``tally``), ``tight`` (-2 when no family star
    holds a row of c, t when c is outside the family and all its held rows belong to t, else
    -1; s's own too) and ``ntight`` (per family star, the candidates 1-tight with it).  The
    candidates found 1-tight are appended to ``hits`` (``hits[0]`` entries follow; -1: it
    overflowed).  (No kernel calls in here: a call per candidate costs more than the
    arithmetic, and each callee is compiled again into every caller on a first run.)"""
    ptr, rows, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, buf, lst, seen, heap, queued, hits, ops, mark = P
    v = s if sign > 0 else np.int64(-1)
    k = 0
    for j in range(ptr[s], ptr[s + 1]):
        r = rows[j]
        owner[r] = v
        for q in range(rptr[r], rptr[r + 1]):
            buf[k] = cands[q]
            k += 1
    in_fam[s] = sign > 0
    ss = s * s
    for i in range(k):
        c = buf[i]
        tally[c, 0] += sign
        tally[c, 1] += sign * s
        tally[c, 2] += sign * ss
    h = hits[0]
    for i in range(k + 1):
        # s last too: a star without rows is not among its own neighbours
        c = s if i == k else buf[i]
        n, s1 = tally[c, 0], tally[c, 1]
        if n > 0 and n * tally[c, 2] == s1 * s1 and not in_fam[c]:
            new = s1 // n
        elif n == 0 and not in_fam[c]:
            new = -2
        else:
            new = -1
        old = tight[c]
        if new != old:
            if old >= 0:
                ntight[old] -= 1
            if new >= 0:
                ntight[new] += 1
            tight[c] = new
        if new >= 0 and h >= 0 and i < k:
            if h + 1 < len(hits):
                h += 1
                hits[h] = c
            else:
                h = -1
    hits[0] = h


#: ``_Packing.tight`` of a free candidate (no row held by the family)
FREE = -2


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _undo(ops, k0, k1, P):
    """Revert ``ops[k0:k1]`` (s + 1: s was inserted; -(s + 1): removed), last first."""
    for i in range(k1 - 1, k0 - 1, -1):
        v = ops[i]
        if v > 0:
            _set(np.int64(v - 1), _MINUS, P)
        else:
            _set(np.int64(-v - 1), _ONE, P)


@_inner
def _fill(t, P, k):
    """Insert the candidates sharing a row with star t that are free (nothing of the family
    holds their rows), most compact first; each is logged in ``ops`` from ``k`` on.  (Only
    insertions happen here, so a candidate free now was free when the fill began.)
    Returns the next free place in ``ops``."""
    ptr, rows, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, buf, lst, seen, heap, queued, hits, ops, mark = P
    m = _neighbours(t, np.int64(-2), ptr, rows, rptr, cands, tight, rank, seen, lst)
    for i in range(m):
        c = lst[i]
        if tight[c] == -2:
            _set(np.int64(c), _ONE, P)
            ops[k] = c + 1
            k += 1
    return k


@_inner
def _push(heap, hn, v):
    heap[hn] = v
    i = hn
    while i > 0:
        p = (i - 1) >> 1
        if heap[p] <= heap[i]:
            break
        heap[p], heap[i] = heap[i], heap[p]
        i = p
    return hn + 1


@_inner
def _enqueue(P, k0, k1, hn):
    """Queue (once) every family star that a candidate sharing rows with the stars of
    ``ops[k0:k1]`` now conflicts with alone (1-tight); returns the heap's size.  Those
    candidates are the ones found 1-tight since ``hits`` was reset before ``ops[k0]`` (their
    ``tight`` was last set by these changes), looked at again now; when ``hits`` overflowed,
    every candidate sharing rows with the stars of ``ops[k0:k1]``."""
    ptr, rows, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, buf, lst, seen, heap, queued, hits, ops, mark = P
    if hits[0] >= 0:
        for i in range(1, hits[0] + 1):
            x = tight[hits[i]]
            if x >= 0 and not queued[x]:
                queued[x] = True
                hn = _push(heap, hn, rank[x])
        return hn
    for i in range(k0, k1):
        s = abs(ops[i]) - 1
        for j in range(ptr[s], ptr[s + 1]):
            r = rows[j]
            for q in range(rptr[r], rptr[r + 1]):
                x = tight[cands[q]]
                if x >= 0 and not queued[x]:
                    queued[x] = True
                    hn = _push(heap, hn, rank[x])
    return hn


@_inner
def _descend(P, hn, k):
    """(1,2)-swaps (and free insertions) until none is left for the queued stars, the most
    compact queued star first (a heap of ranks: ranks are distinct, so the order is the one of
    repeatedly taking the queue's minimum).  Logs the changes in ``ops`` from ``k`` on;
    returns the next free place in ``ops``.  (The heap's pop and the search for a pair are
    written in here, their one caller: as kernels of their own each was compiled, optimised and
    turned into machine code once more on a first run.)"""
    ptr, rows, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, buf, lst, seen, heap, queued, hits, ops, mark = P
    while hn > 0:
        # pop the heap's minimum rank
        r = heap[0]
        hn -= 1
        heap[0] = heap[hn]
        i = 0
        while True:
            ch = 2 * i + 1
            if ch >= hn:
                break
            if ch + 1 < hn and heap[ch + 1] < heap[ch]:
                ch += 1
            if heap[i] <= heap[ch]:
                break
            heap[ch], heap[i] = heap[i], heap[ch]
            i = ch
        t = order[r]
        queued[t] = False
        if not in_fam[t] or ntight[t] < 2:
            continue
        # the first pair, in rank order (most compact first), of distinct candidates 1-tight
        # with t (``tight == t``; ``ntight[t]`` of them) whose rows are disjoint
        m = _neighbours(t, t, ptr, rows, rptr, cands, tight, rank, seen, lst)
        a = np.int64(-1)
        b = np.int64(-1)
        for i in range(m - 1):
            for j in range(i + 1, m):
                apart = True
                for x in range(ptr[lst[i]], ptr[lst[i] + 1]):
                    for y in range(ptr[lst[j]], ptr[lst[j] + 1]):
                        if rows[x] == rows[y]:
                            apart = False
                            break
                    if not apart:
                        break
                if apart:
                    a, b = lst[i], lst[j]
                    break
            if a >= 0:
                break
        if a < 0:
            continue
        k0 = k
        hits[0] = 0
        _set(np.int64(t), _MINUS, P)
        ops[k] = -(t + 1)
        _set(np.int64(a), _ONE, P)
        ops[k + 1] = a + 1
        _set(np.int64(b), _ONE, P)
        ops[k + 2] = b + 1
        k += 3
        k = _fill(t, P, k)
        hn = _enqueue(P, k0, k, hn)
    return k


#: draws per batch of the ILS perturbation
ILS_BATCH = 1024


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _search(P, task, batches, ctr, limit, bound):
    """The searches on the packing ``P``, in one compiled entry (so that the kernels its tasks
    share are compiled and optimised once on a first run: each entry compiles its callees
    again).

    ``task`` 0: insert the stars ``batches[0, :limit]`` (a packing) into an empty state.

    ``task`` 3: one round of :func:`local_search`, whose view of the family is the one when it
    began: ``batches[0, :ctr[0]]``, the candidates free then, most compact first;
    ``batches[1, :ctr[1]]``, those then 1-tight with family star ``batches[2, :ctr[1]]``,
    grouped by it (ascending), most compact first.  A candidate's rows are held by nothing but
    t now iff its ``tight`` is t or -2 now.  Returns the swaps made, -1 when the round changed
    nothing.

    ``task`` 1: the ILS start: insert every free candidate (most compact first), then
    (1,2)-swaps around every family star.

    ``task`` 2: :func:`ils`'s iterations (``limit`` in all, stopping at ``bound`` when >= 0),
    resumable: ``ctr`` = (iterations begun, batches drawn in the current iteration's search,
    searching?, family size, done?).  Each iteration's perturbation takes the first draw, batch
    after batch of ``batches`` (at most 64), of a candidate outside the family whose held rows
    belong to one or two family stars.  Returns when done (``ctr[4] = 1``) or when it needs a
    batch past ``batches`` (``ctr[4] = 0``: call again with the next ones).
    """
    ptr, rows, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, buf, lst, seen, heap, queued, hits, ops, mark = P
    if task == 0:
        for i in range(limit):
            _set(batches[0, i], _ONE, P)
        return 0
    if task == 3:
        # one round of the local search (see _local_search_on); lst is the scratch "ok" list
        free, one, grp, ok = batches[0, : ctr[0]], batches[1, : ctr[1]], batches[2, : ctr[1]], lst
        no = len(one)
        swaps = 0
        progress = False
        # insert the free stars first (most compact first)
        for c in free:
            if tight[c] == -2:
                _set(np.int64(c), _ONE, P)
                progress = True
        i = 0
        while i < no:
            t = grp[i]
            e = i
            while e < no and grp[e] == t:
                e += 1
            if in_fam[t]:
                q = 0
                for g in range(i, e):
                    s = one[g]
                    if tight[s] == t or tight[s] == -2:
                        ok[q] = s
                        q += 1
                sa = sb = -1
                for a in range(q):
                    for j in range(ptr[ok[a]], ptr[ok[a] + 1]):
                        mark[rows[j]] = True
                    for b in range(a + 1, q):
                        apart = True
                        for j in range(ptr[ok[b]], ptr[ok[b] + 1]):
                            if mark[rows[j]]:
                                apart = False
                                break
                        if apart:
                            sa, sb = ok[a], ok[b]
                            break
                    for j in range(ptr[ok[a]], ptr[ok[a] + 1]):
                        mark[rows[j]] = False
                    if sa >= 0:
                        break
                if sa >= 0:
                    _set(np.int64(t), _MINUS, P)
                    _set(np.int64(sa), _ONE, P)
                    _set(np.int64(sb), _ONE, P)
                    swaps += 1
                    progress = True
            i = e
        return swaps if progress else -1
    if task == 1:
        for r in range(len(order)):
            c = order[r]
            if tight[c] == -2:
                _set(np.int64(c), _ONE, P)
        hn = np.int64(0)
        for t in range(len(in_fam)):
            if in_fam[t]:
                queued[t] = True
                hn = _push(heap, hn, rank[t])
        _descend(P, hn, np.int64(0))
        return 0
    # task 2: the ILS iterations
    n = len(in_fam)
    it, tries, searching, size = ctr[0], ctr[1], ctr[2], ctr[3]
    pos = 0
    while True:
        if not searching:
            if n == 0 or it >= limit or (bound >= 0 and size >= bound):
                ctr[4] = 1
                break
            it += 1
            searching = 1
            tries = 0
        s = h1 = h2 = -1
        while tries < 64 and s < 0:
            if pos == len(batches):
                ctr[0], ctr[1], ctr[2], ctr[3], ctr[4] = it, tries, searching, size, 0
                return 0
            batch = batches[pos]
            pos += 1
            tries += 1
            for i in range(len(batch)):
                c = batch[i]
                if in_fam[c]:
                    continue
                o1 = o2 = -1
                many = False
                for j in range(ptr[c], ptr[c + 1]):
                    o = owner[rows[j]]
                    if o < 0 or o == o1 or o == o2:
                        continue
                    if o1 < 0:
                        o1 = o
                    elif o2 < 0:
                        o2 = o
                    else:
                        many = True
                        break
                if o1 >= 0 and not many:
                    s = c
                    h1, h2 = (o1, o2) if o2 < 0 or o1 < o2 else (o2, o1)
                    break
        searching = 0
        if s < 0:
            ctr[4] = 1
            break
        # force s in (removing the one or two stars holding its rows, lowest id first), refill
        # around them, then (1,2)-swaps around every change
        hits[0] = 0
        _set(np.int64(h1), _MINUS, P)
        ops[0] = -(h1 + 1)
        k = 1
        if h2 >= 0:
            _set(np.int64(h2), _MINUS, P)
            ops[1] = -(h2 + 1)
            k = 2
        _set(np.int64(s), _ONE, P)
        ops[k] = s + 1
        k += 1
        k = _fill(np.int64(h1), P, k)
        if h2 >= 0:
            k = _fill(np.int64(h2), P, k)
        hn = _enqueue(P, np.int64(0), k, np.int64(0))
        k = _descend(P, hn, k)
        new = size
        for i in range(k):
            new += 1 if ops[i] > 0 else -1
        if new < size:  # smaller: revert (plateau moves are kept: they walk)
            for i in range(k - 1, -1, -1):
                v = ops[i]
                if v > 0:
                    _set(np.int64(v - 1), _MINUS, P)
                else:
                    _set(np.int64(-v - 1), _ONE, P)
        else:
            size = new
    ctr[0], ctr[1], ctr[2], ctr[3] = it, tries, searching, size
    return 0


#: ``batches``/``ctr`` of :func:`_search` for the tasks that take none
_NO_BATCHES = np.zeros((0, ILS_BATCH), dtype=np.int64)
_NO_CTR = np.zeros(5, dtype=np.int64)


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
    :data:`ILS_BATCH` (``integers(0, n)``), and the budget is an iteration count.  Stops early
    at ``bound``.  Returns (family, iterations used).  The loop is compiled
    (:func:`_search`); the batches are drawn here ahead of it, in the same stream.
    """
    return _ils_on(_Packing(chosen, ptr, rows, n_rows, _rank(order)), iterations, bound, seed)


def _ils_on(P: _Packing, iterations: int, bound: int | None, seed: int) -> tuple[np.ndarray, int]:
    """:func:`ils` from the family in the packing ``P`` (which it changes)."""
    n = P.n
    # start from a local optimum w.r.t. free insertions and (1,2)-swaps
    _search(P.arrays, 1, _NO_BATCHES, _NO_CTR, 0, -1)
    size = P.size
    rng = np.random.default_rng(seed)
    ctr = np.array([0, 0, 0, size, 0], dtype=np.int64)
    limit = -1 if bound is None else int(bound)
    while n:
        # at least one batch per iteration: draw for the iterations left (some may go unused;
        # integers(size=(k, B)) is the same stream as k calls of size B)
        k = max(1, min(256, int(iterations) - int(ctr[0]) + int(ctr[2])))
        _search(P.arrays, 2, rng.integers(0, n, size=(k, ILS_BATCH)), ctr, int(iterations), limit)
        if ctr[4]:
            break
    return np.flatnonzero(P.in_fam), int(ctr[0])


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
    # local search and ILS on one packing state (local_search and ils, without building it twice)
    packing = _Packing(chosen, ptr, rows, n_rows, _rank(order))
    swaps = _local_search_on(packing, 200)
    chosen = np.flatnonzero(packing.in_fam)
    info.update(local_search=int(len(chosen)), swaps=swaps, local_search_s=round(time.perf_counter() - t1, 3))
    budget = ILS_ITERATIONS if ils_iterations is None else int(ils_iterations)
    nnz = int(len(rows))
    if budget > 0 and len(chosen) < bound:
        t3 = time.perf_counter()
        start = chosen
        chosen, used = _ils_on(packing, budget, bound, ILS_SEED)
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
