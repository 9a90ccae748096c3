"""Set packing's incremental state and the compiled searches on it.

The local search ((1,2)-swaps) and the iterated local search of family selection
(:func:`starforge.stars.select.local_search`, :func:`starforge.stars.select.ils`) run here, on
:class:`Packing`: which candidate holds which window row, and which outside candidates are free
or conflict with one family star only, kept up to date as stars go in and out.
"""

from __future__ import annotations

import numpy as np

from starforge.runtime.kernels import numba, prefetch

#: the kernels only ever called from other kernels: no Python or C-callback wrapper, and no
#: cache entry of their own (each is compiled into its one caller, whose cache entry holds it;
#: a warm run loads the caller and compiles nothing).  Each wrapper and cache write costs a
#: first run tens of milliseconds per kernel.
_inner = numba.njit(nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)


def rank_of(order: np.ndarray) -> np.ndarray:
    """Each candidate's position in ``order`` (int64)."""
    order = np.asarray(order)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank


class Packing:
    """Incremental set-packing state for the local and iterated local searches, as arrays its compiled kernels share.

    ``owner[r]`` is the family star holding row r (-1 free).  Per candidate c, over its meetings
    with family stars (a row held, or with ``points`` a pair of keys that share a window):
    ``cnt`` (how many), ``s1`` (sum of owner ids) and ``s2`` (sum of squares).
    c is free iff ``cnt == 0``; its held rows all belong to ONE star t iff
    ``cnt * s2 == s1**2`` (zero variance), and then ``t = s1 // cnt``.  ``tight[c]`` says which:
    -2 free, t when c is outside the family and 1-tight with t, else -1 (a small array of its
    own, int32: the searches read only it, and it stays in the CPU cache).  The counts sit in
    one 16-byte row per candidate, so that a meeting in :func:`_set` reads and writes one row
    and as many rows as possible stay in the CPU cache between the meetings' scattered
    accesses: ``tally[c, 0] = family << FAMILY_BIT | cnt << SUM_BITS | s1`` (``family``: c is
    in the family) and ``tally[c, 1] = s2``.  Inserting or removing
    a star only updates the candidates sharing a row with it, found through ``points`` (see
    :func:`starforge.stars.rules.key_points`): each star's keys as codes of grid points
    (``(n, k)``), the ``table`` from code to point id (-1: no key there) and the code offsets
    of the points whose keys share a window with a key at offset 0; the point -> candidates
    index (CSC) lists the candidates with a key there.  A candidate near several keys of a star
    is met once per key pair, not once per shared window.  Without ``points``, each row is a
    point of its own (offset 0 only).
    ``arrays`` is the tuple every kernel takes (:func:`_set`, :func:`_fill`, :func:`_descend`,
    :func:`_search`).
    """

    def __init__(self, chosen, ptr, rows, n_rows, rank, points=None):
        ptr = np.asarray(ptr, dtype=np.int64)
        rows = np.asarray(rows, dtype=np.int64)
        rank = np.asarray(rank, dtype=np.int64)
        self.rank = rank
        n = len(ptr) - 1
        self.n, self.n_rows = n, int(n_rows)
        if points is None:  # each row a point
            sptr, spts, table, offs = ptr, rows, np.arange(self.n_rows, dtype=np.int64), np.zeros(1, np.int64)
        else:
            codes, table, offs = (np.asarray(a, dtype=np.int64) for a in points)
            sptr = np.arange(0, codes.size + 1, max(1, codes.shape[1]), dtype=np.int64)
            spts = codes.ravel()
        # point -> candidates, ascending within a point
        rptr, cands = _csc(sptr, table[spts], int(table.max()) + 1 if len(table) else 0)
        order = np.empty(n, dtype=np.int64)
        order[rank] = np.arange(n)
        _check_tally_room(n, ptr, 1 if points is None else codes.shape[1])
        self.tally = np.zeros((n, 2), dtype=np.int64)
        self.tight = np.full(n, FREE, dtype=np.int32)
        self.ntight = np.zeros(n, dtype=np.int32)
        self.in_fam = np.zeros(n, dtype=np.bool_)
        self.owner = np.full(self.n_rows, -1, dtype=np.int64)
        self.arrays = (
            ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, self.tally, self.tight, self.ntight, self.in_fam, self.owner,
            np.empty(n + 1, dtype=np.int64),  # lst: a star's free or 1-tight neighbours
            np.zeros(n, dtype=np.bool_),  # seen (all False between calls)
            np.empty(n + 1, dtype=np.int64),  # heap of queued ranks
            np.zeros(n, dtype=np.bool_),  # queued
            np.zeros(4 * n + 1, dtype=np.int64),  # hits: the 1-tight found since a reset
            # ops: the changes of one ILS step (s + 1: s inserted, -(s + 1): removed).  Each swap
            # and each fill grows the family by one, so a step makes at most 3 x (the largest
            # family) + 3 changes; a family holds at most one star per row, plus stars without rows
            np.empty(3 * min(n, self.n_rows + int((np.diff(ptr) == 0).sum())) + 8, dtype=np.int64),
            np.zeros(self.n_rows, dtype=np.bool_),  # mark: a False per row between calls
            np.zeros(n, dtype=np.int64),  # ver: per star t, bumped as a candidate's tight turns t or leaves t
            np.full(n, -1, dtype=np.int64),  # tried: ver[t] when t last had no swap pair (-1: not since)
            # freed: the candidates turned free since a reset (see _set), each at most once per
            # run of removals: n of them at most, plus the count in freed[0]
            np.zeros(n + 2, dtype=np.int64),
        )
        chosen = np.asarray(chosen, dtype=np.int64)
        _search(self.arrays, 0, chosen.reshape(1, -1), _NO_CTR, len(chosen), -1)

    @property
    def cnt(self) -> np.ndarray:
        """Per candidate, its meetings with family stars (int64)."""
        return (self.tally[:, 0] >> SUM_BITS) & _COUNT_MASK

    @property
    def s1(self) -> np.ndarray:
        """Per candidate, the sum of the ids of the family stars it meets, once per meeting."""
        return self.tally[:, 0] & _SUM_MASK

    @property
    def s2(self) -> np.ndarray:
        """Per candidate, the sum of their squares."""
        return self.tally[:, 1].copy()

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

    @property
    def family(self) -> np.ndarray:
        """The candidates in the family, ascending."""
        return np.flatnonzero(self.in_fam)

    def local_search(self, rounds: int) -> int:
        """(1,2)-swaps until none is left or ``rounds`` rounds have run (see
        :func:`starforge.stars.select.local_search`); returns the swaps made.  Each round's view
        (the free and the 1-tight candidates, sorted) is taken here, the round itself is
        compiled (:func:`_search`, task 3)."""
        swaps = 0
        for _ in range(rounds):
            t = self.tight
            free = np.flatnonzero(t == FREE)
            one = np.flatnonzero(t >= 0)
            lists = np.zeros((3, max(len(free), len(one))), dtype=np.int64)
            lists[0, : len(free)] = free[np.argsort(self.rank[free])]
            one = one[np.lexsort((self.rank[one], t[one]))]
            lists[1, : len(one)], lists[2, : len(one)] = one, t[one]
            got = _search(self.arrays, 3, lists, np.array([len(free), len(one)], dtype=np.int64), 0, -1)
            if got < 0:
                break
            swaps += got
        return swaps

    def ils(self, iterations: int, bound: int | None, seed: int) -> int:
        """The iterated local search from the family held (see
        :func:`starforge.stars.select.ils`); returns the iterations used."""
        n = self.n
        # start from a local optimum w.r.t. free insertions and (1,2)-swaps
        _search(self.arrays, 1, _NO_BATCHES, _NO_CTR, 0, -1)
        rng = np.random.default_rng(seed)
        ctr = np.array([0, 0, 0, self.size, 0], dtype=np.int64)
        limit = -1 if bound is None else int(bound)
        while n:
            # at least one batch per iteration: draw for the iterations left (some may go unused;
            # integers(size=(k, B)) is the same stream as k calls of size B)
            k = max(1, min(256, int(iterations) - int(ctr[0]) + int(ctr[2])))
            _search(self.arrays, 2, rng.integers(0, n, size=(k, ILS_BATCH)), ctr, int(iterations), limit)
            if ctr[4]:
                break
        return int(ctr[0])


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


#: ``Packing.tight`` of a free candidate (no row held by the family)
FREE = -2
#: ``Packing.tally[c, 0]``: the sum of ids in the bits below SUM_BITS, the count of meetings
#: above them, and the family flag in bit FAMILY_BIT (see :func:`_check_tally_room`)
SUM_BITS = 40
FAMILY_BIT = 62
_SUM_MASK = (1 << SUM_BITS) - 1
_COUNT_MASK = (1 << (FAMILY_BIT - SUM_BITS)) - 1
_FAMILY = np.int64(1 << FAMILY_BIT)
_ONE_MEETING = np.int64(1 << SUM_BITS)


def _check_tally_room(n: int, ptr: np.ndarray, keys: int) -> None:
    """Raise ValueError unless the packed tallies of :class:`Packing` hold every count exactly.

    The family is a packing, so the family stars meeting a candidate hold distinct rows of it,
    and each meets it at most once per pair of keys (``keys`` per star; one, by rows): a
    candidate meets the family at most ``keys**2`` times its number of rows.  The count must stay below
    2**(FAMILY_BIT - SUM_BITS), the sum of ids below 2**SUM_BITS and the sum of squares below
    2**63."""
    most = keys * keys * int(np.diff(ptr).max(initial=0))
    top = max(n - 1, 0)
    if most > _COUNT_MASK or most * top > _SUM_MASK or most * top * top >= 1 << 63:
        raise ValueError(
            f"the packing's tallies cannot hold {n:,} candidates meeting up to {most:,} times; "
            "raise delta_mm or lower tolerance_mm for fewer candidates"
        )


@_inner
def _neighbours(t, want, most, sptr, spts, table, offs, rptr, cands, tight, rank, seen, lst):
    """The candidates sharing a row with star t whose ``tight`` is ``want`` (-2: free; t:
    1-tight with t; -3: 1-tight with any star), each once, most compact first, in ``lst[:m]``; returns m.  The scan of
    t's rows stops once ``most`` are found (``ntight[t]`` when ``want`` is t: there are no
    more).  ``seen`` (all False) is left so.  Sorted by :func:`_by_rank` (``m`` passed as an
    int64: typed as the literal 0 it would be compiled twice)."""
    m = 0
    for j in range(sptr[t], sptr[t + 1]):
        for o in offs:
            if m >= most:
                break
            g = table[spts[j] + o]
            if g < 0:
                continue
            for q in range(rptr[g], rptr[g + 1]):
                c = cands[q]
                if (tight[c] == want or (want == -3 and tight[c] >= 0)) and not seen[c]:
                    seen[c] = True
                    lst[m] = c
                    m += 1
    for i in range(m):
        seen[lst[i]] = False
    _by_rank(lst, np.int64(m), rank)
    return m


@_inner
def _by_rank(lst, m, rank):
    """Sort ``lst[:m]`` by rank, most compact first (ranks are a permutation: no ties, so an
    unstable sort does): Shell's sort, gaps ~m/2.2^k ending in 1 (insertion sort for short
    lists).  No numpy sort in the kernels: each costs seconds of compilation on a first run."""
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


#: how many meetings ahead :func:`_set` prefetches a candidate's tallies
_AHEAD = 32
#: the signs :func:`_set` takes, as int64 (a literal argument would compile a kernel again)
_ONE = np.int64(1)
_MINUS = np.int64(-1)


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _set(s, sign, P):
    """Star s enters (sign +1) or leaves (-1) the family: its rows' owner and membership, then
    per meeting of a candidate c with s (see :class:`Packing`) c's count, sum and sum of
    squares (``tally``), and from them ``tight`` (-2 when no family star holds a row of c, t
    when c is outside the family and all its held rows belong to t, else -1), ``ntight`` (per
    family star, the candidates 1-tight with it) and ``ver``; then s's own ``tight`` (a star
    without rows meets nothing).  A candidate met more than once passes through states that
    its last meeting corrects: ``ntight`` ends the same, and ``ver`` only counts up.  The
    candidates found 1-tight are appended to ``hits`` (``hits[0]`` entries follow; -1: it
    overflowed; a candidate may be there more than once), those turned free to ``freed`` (the
    same way).  The tallies of the candidate met ``_AHEAD`` meetings later are prefetched.
    (No kernel calls in here: a call per candidate costs more than the arithmetic, and each
    callee is compiled again into every caller on a first run.)"""
    ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, lst, seen, heap, queued, hits, ops, mark, ver, tried, freed = P
    v = s if sign > 0 else np.int64(-1)
    in_fam[s] = sign > 0
    # s's own state is settled by the last pass (its meetings with itself skip it once flagged)
    if sign > 0:
        tally[s, 0] += _FAMILY
    else:
        tally[s, 0] -= _FAMILY
    d0 = sign * (_ONE_MEETING + s)
    s2s = sign * s * s
    for j in range(ptr[s], ptr[s + 1]):
        owner[rows[j]] = v
    h = hits[0]
    f = freed[0]
    end = sptr[s + 1]
    for j in range(sptr[s], end + 1):
        for o in offs:
            if j == end:  # s itself, once, after its meetings
                q0, q1 = np.int64(-1), np.int64(0)
            else:
                g = table[spts[j] + o]
                if g < 0:
                    continue
                q0, q1 = rptr[g], rptr[g + 1]
            for q in range(q0, q1):
                if q + _AHEAD < q1:
                    prefetch(tally, cands[q + _AHEAD])
                if q < 0:
                    c = s
                    w, s2 = tally[s, 0], tally[s, 1]
                    if sign > 0:
                        new = np.int64(-1)
                else:
                    c = cands[q]
                    w = tally[c, 0] + d0
                    tally[c, 0] = w
                    s2 = tally[c, 1] + s2s
                    tally[c, 1] = s2
                    if w >= _FAMILY:  # a family star: its tight stays -1
                        continue
                old = np.int64(tight[c])
                if q >= 0 or sign < 0:
                    n, s1 = w >> SUM_BITS, w & _SUM_MASK
                    if n == 0:
                        new = np.int64(-2)
                    elif n * s2 == s1 * s1:
                        new = s1 // n
                    else:
                        new = np.int64(-1)
                if new != old:
                    if old >= 0:
                        ntight[old] -= 1
                        ver[old] += 1
                    if new >= 0:
                        ntight[new] += 1
                        ver[new] += 1
                    tight[c] = new
                    if new == -2 and f >= 0:
                        if f + 1 < len(freed):
                            f += 1
                            freed[f] = c
                        else:
                            f = -1
                if new >= 0 and h >= 0 and q >= 0:
                    if h + 1 < len(hits):
                        h += 1
                        hits[h] = c
                    else:
                        h = -1
            if j == end:
                break
    hits[0] = h
    freed[0] = f


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
    Returns the next free place in ``ops``.

    The callers reset ``freed`` before removing t: a candidate sharing a row with t held a row
    of the family until then (t's), so it is free now only if it turned free since, and is in
    ``freed``; those sharing a row with t are kept (t's rows marked, theirs looked up).  When
    ``freed`` overflowed, t's neighbourhood is scanned (:func:`_neighbours`)."""
    ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, lst, seen, heap, queued, hits, ops, mark, ver, tried, freed = P
    if freed[0] < 0:
        m = _neighbours(t, np.int64(-2), np.int64(len(tight)), sptr, spts, table, offs, rptr, cands, tight, rank, seen, lst)
    else:
        for j in range(ptr[t], ptr[t + 1]):
            mark[rows[j]] = True
        m = 0
        for i in range(1, freed[0] + 1):
            c = freed[i]
            if tight[c] != -2 or seen[c]:
                continue
            for j in range(ptr[c], ptr[c + 1]):
                if mark[rows[j]]:
                    seen[c] = True
                    lst[m] = c
                    m += 1
                    break
        for j in range(ptr[t], ptr[t + 1]):
            mark[rows[j]] = False
        for i in range(m):
            seen[lst[i]] = False
        _by_rank(lst, np.int64(m), rank)
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
    ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, lst, seen, heap, queued, hits, ops, mark, ver, tried, freed = P
    if hits[0] >= 0:
        for i in range(1, hits[0] + 1):
            x = tight[hits[i]]
            if x >= 0 and not queued[x]:
                queued[x] = True
                hn = _push(heap, hn, rank[x])
        return hn
    for i in range(k0, k1):
        s = abs(ops[i]) - 1
        m = _neighbours(s, np.int64(-3), np.int64(len(tight)), sptr, spts, table, offs, rptr, cands, tight, rank, seen, lst)
        for j in range(m):
            x = tight[lst[j]]
            if not queued[x]:
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
    ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, lst, seen, heap, queued, hits, ops, mark, ver, tried, freed = P
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
        if not in_fam[t] or ntight[t] < 2 or tried[t] == ver[t]:
            # (tried == ver: the candidates 1-tight with t are those that held no pair last time)
            continue
        # the first pair, in rank order (most compact first), of distinct candidates 1-tight
        # with t (``tight == t``; ``ntight[t]`` of them) whose rows are disjoint; the rows of
        # the first of a pair are marked, the second's looked up
        m = _neighbours(t, t, np.int64(ntight[t]), sptr, spts, table, offs, rptr, cands, tight, rank, seen, lst)
        a = np.int64(-1)
        b = np.int64(-1)
        for i in range(m - 1):
            x = lst[i]
            for j in range(ptr[x], ptr[x + 1]):
                mark[rows[j]] = True
            for y in range(i + 1, m):
                apart = True
                for j in range(ptr[lst[y]], ptr[lst[y] + 1]):
                    if mark[rows[j]]:
                        apart = False
                        break
                if apart:
                    a, b = x, lst[y]
                    break
            for j in range(ptr[x], ptr[x + 1]):
                mark[rows[j]] = False
            if a >= 0:
                break
        if a < 0:
            tried[t] = ver[t]
            continue
        k0 = k
        hits[0] = 0
        freed[0] = 0
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
#: how many draws ahead the perturbation prefetches a draw's first rows (and twice as far, where
#: they start)
_DRAWS_AHEAD = 4


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
    ptr, rows, sptr, spts, table, offs, rptr, cands, rank, order, tally, tight, ntight, in_fam, owner, lst, seen, heap, queued, hits, ops, mark, ver, tried, freed = P
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
            nb = len(batch)
            for i in range(nb):
                # the draws' rows lie anywhere in memory: ask for those of the draws ahead
                if i + 2 * _DRAWS_AHEAD < nb:
                    prefetch(ptr, batch[i + 2 * _DRAWS_AHEAD])
                if i + _DRAWS_AHEAD < nb:
                    prefetch(rows, ptr[batch[i + _DRAWS_AHEAD]])
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
        freed[0] = 0
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
