"""The compiled selection (local search, iterated local search) against a plain Python
reference: the same family, the same swap and iteration counts, byte for byte, on many
instances, seeds, budgets and bounds.

The reference below is the same algorithm written without compiled loops (a Python loop around
small kernels, a heap and sets, numpy batches for the perturbation); it is test code only."""

from __future__ import annotations

import heapq

import numba
import numpy as np
import pytest

from starforge.stars.enumerate import enumerate_candidates
from starforge.stars.packing import Packing, rank_of
from starforge.stars.rules import internal_ok, key_points, window_rows
from starforge.stars.select import compactness_order, csr_rows, greedy, ils, local_search
from starforge.stars.spec import StarSpec


def ref_local_search(
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



class _RefPacking:
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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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


def ref_ils(
    chosen: np.ndarray,
    order: np.ndarray,
    ptr: np.ndarray,
    rows: np.ndarray,
    n_rows: int,
    iterations: int = 800,
    bound: int | None = None,
    seed: int = 0,
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
    P = _RefPacking(chosen, ptr, rows, n_rows, rank)
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



@pytest.fixture(scope="module")
def small():
    """Two small finger-like candidate sets: 681 and 7,290 stars."""
    return [enumerate_candidates(StarSpec(box_mm=(16, 12, 24), delta_mm=d)) for d in (2.0, 1.5)]


def instance(cands, rule: str, m: int, drop: float = 0.0):
    ok = internal_ok(cands.index, rule, m)
    index, volume = cands.index[ok], cands.box_volume[ok]
    star_of, row, n_rows = window_rows(index, rule, m, len(cands.pool_mm))
    if drop:  # varying row counts per star
        keep = np.random.default_rng(3).random(len(row)) >= drop
        star_of, row = star_of[keep], row[keep]
    ptr, rows = csr_rows(star_of, row, len(index))
    order = compactness_order(index, cands.pool_mm, volume)
    return ptr, rows, n_rows, order


CASES = [(0, "face", 1, 0.0), (0, "pair", 1, 0.0), (0, "face", 2, 0.0), (0, "pair", 2, 0.4),
         (1, "face", 1, 0.0), (1, "pair", 1, 0.0), pytest.param(1, "face", 2, 0.0, marks=pytest.mark.slow),
         (1, "pair", 1, 0.5)]


@pytest.mark.parametrize("which,rule,m,drop", CASES)
def test_compiled_search_is_the_reference(small, which, rule, m, drop):
    ptr, rows, n_rows, order = instance(small[which], rule, m, drop)
    g = greedy(order, ptr, rows, n_rows)
    ls, swaps = local_search(g, order, ptr, rows, n_rows)
    ref_ls, ref_swaps = ref_local_search(g, order, ptr, rows, n_rows)
    assert swaps == ref_swaps and np.array_equal(ls, ref_ls) and ls.dtype == ref_ls.dtype
    # a few rounds only: the round cap is the same too
    assert [local_search(g, order, ptr, rows, n_rows, rounds=r)[1] for r in (1, 2)] == [
        ref_local_search(g, order, ptr, rows, n_rows, rounds=r)[1] for r in (1, 2)
    ]
    top = len(ptr) - 1
    for seed, iterations, bound, start in [
        (0, 300, None, ls), (1, 57, None, g), (2, 1, None, ls), (5, 0, None, ls), (3, 400, len(ls) + 2, ls),
        (4, 300, len(ls), ls), (7, 300, None, np.zeros(0, dtype=np.intp)),
    ]:
        got, used = ils(start, order, ptr, rows, n_rows, iterations=iterations, bound=bound, seed=seed)
        want, ref_used = ref_ils(start, order, ptr, rows, n_rows, iterations=iterations, bound=bound, seed=seed)
        assert used == ref_used and np.array_equal(got, want), (seed, iterations, bound)
        assert 0 < len(got) <= top


def test_compiled_ils_many_seeds(small):
    """Budgets that cross the batch refills (256 per draw), on many seeds."""
    ptr, rows, n_rows, order = instance(small[0], "face", 1)
    ls, _ = local_search(greedy(order, ptr, rows, n_rows), order, ptr, rows, n_rows)
    for seed in range(12):
        iterations = [1, 255, 256, 257, 600][seed % 5]
        got = ils(ls, order, ptr, rows, n_rows, iterations=iterations, seed=seed)
        want = ref_ils(ls, order, ptr, rows, n_rows, iterations=iterations, seed=seed)
        assert got[1] == want[1] and np.array_equal(got[0], want[0]), seed


def test_no_draw_qualifies():
    """Every candidate in the family: the perturbation finds nothing in 64 batches and stops
    after the iteration it began (as the reference)."""
    ptr = np.arange(0, 7, 2, dtype=np.int64)
    rows = np.arange(6, dtype=np.int64)  # three disjoint stars
    order = np.arange(3)
    got = ils(np.arange(3), order, ptr, rows, 6, iterations=10)
    want = ref_ils(np.arange(3), order, ptr, rows, 6, iterations=10)
    assert got[1] == want[1] == 1 and np.array_equal(got[0], want[0])


# the compactness order as a lexsort of every key: the reference of the single volume sort


def ref_compactness_order(index: np.ndarray, pool: np.ndarray, volume: np.ndarray) -> np.ndarray:
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



def test_compactness_order_is_the_reference(small):
    c = small[1]
    for digits in (9, 2, 1, 0):  # coarser volumes: many ties, decided by the full key
        vol = np.round(c.box_volume, digits)
        assert np.array_equal(compactness_order(c.index, c.pool_mm, vol), ref_compactness_order(c.index, c.pool_mm, vol))


@pytest.mark.parametrize("rule,m,which", [("face", 1, 1), ("pair", 1, 1), ("face", 2, 0), ("pair", 2, 0), ("face", 3, 0),
                                          ("pair", 3, 1)])
def test_compiled_window_rows_are_numpys(small, rule, m, which):
    """Large inputs take the compiled window rows: the same entries and rows as numpy's path."""
    from starforge.stars import rules

    c = small[which]
    index = c.index if m < 3 else c.index[:3000]  # m = 3: stars with repeated windows too
    assert len(index) * rules.KEYS[rule] * m**3 < rules.WINDOW_KERNEL_ENTRIES  # numpy's path below
    got = rules._window_rows_compiled(index, rule, m, len(c.pool_mm))
    want = window_rows(index, rule, m, len(c.pool_mm))
    assert got[2] == want[2]
    for a, b in zip(got[:2], want[:2], strict=True):
        assert a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize("which,rule,m", [(0, "face", 1), (1, "pair", 1), (0, "face", 3), *(pytest.param(*c, marks=pytest.mark.slow) for c in ((0, "pair", 2), (1, "face", 2)))])
def test_search_by_key_points_is_the_reference(small, which, rule, m):
    """Neighbours found through the keys' grid points (what ``select_family`` uses) give the
    reference's families and counts: the same stars share a window either way."""
    cands = small[which]
    index = cands.index[internal_ok(cands.index, rule, m)]
    ptr, rows, n_rows, order = instance(cands, rule, m)
    points = key_points(index, rule, m, len(cands.pool_mm))
    assert points is not None
    g = greedy(order, ptr, rows, n_rows)
    P = Packing(g, ptr, rows, n_rows, rank_of(order), points)
    swaps = P.local_search(200)
    ref_ls, ref_swaps = ref_local_search(g, order, ptr, rows, n_rows)
    assert swaps == ref_swaps and np.array_equal(P.family, ref_ls)
    for seed, iterations in [(0, 300), (4, 257)]:
        P = Packing(ref_ls, ptr, rows, n_rows, rank_of(order), points)
        used = P.ils(iterations, None, seed)
        want, ref_used = ref_ils(ref_ls, order, ptr, rows, n_rows, iterations=iterations, seed=seed)
        assert used == ref_used and np.array_equal(P.family, want), (seed, iterations)
    # a record of the 1-tight found that overflows at once: the full rescan queues the same stars
    P = Packing(ref_ls, ptr, rows, n_rows, rank_of(order), points)
    hits = next(i for i, a in enumerate(P.arrays) if len(a) == 4 * P.n + 1)
    P.arrays = (*P.arrays[:hits], np.zeros(2, dtype=np.int64), *P.arrays[hits + 1 :])
    used = P.ils(300, None, 0)
    want, ref_used = ref_ils(ref_ls, order, ptr, rows, n_rows, iterations=300, seed=0)
    assert used == ref_used and np.array_equal(P.family, want)
    # a record of the candidates turned free that overflows at once: each fill scans the removed
    # star's neighbourhood instead, and inserts the same stars
    P = Packing(ref_ls, ptr, rows, n_rows, rank_of(order), points)
    freed = next(i for i, a in enumerate(P.arrays) if len(a) == P.n + 2)
    P.arrays = (*P.arrays[:freed], np.zeros(2, dtype=np.int64), *P.arrays[freed + 1 :])
    assert P.ils(300, None, 0) == ref_used and np.array_equal(P.family, want)


def test_key_points_neighbours_are_window_neighbours(small):
    """Two stars share a key window iff one of the other's keys is at one of a key's point
    offsets: checked pair by pair on a sample against the window rows."""
    cands = small[1]
    for rule, m in [("face", 2), ("pair", 2), ("face", 1)]:
        index = cands.index[internal_ok(cands.index, rule, m)]
        ptr, rows, _, _ = instance(cands, rule, m)
        codes, table, offsets = key_points(index, rule, m, len(cands.pool_mm))
        assert (table[codes] >= 0).all() and len(offsets) == (2 * m - 1) ** 3
        rng = np.random.default_rng(5)
        star_of = np.repeat(np.arange(len(index)), np.diff(ptr))
        pairs = rng.integers(0, len(index), size=(300, 2)).tolist()
        for a in rng.integers(0, len(index), size=300).tolist():  # and pairs that share a row
            on_row = np.flatnonzero(rows == rows[ptr[a] + rng.integers(ptr[a + 1] - ptr[a])])
            pairs.append([a, int(star_of[on_row[rng.integers(len(on_row))]])])
        shared = 0
        for a, b in pairs:
            by_rows = bool(np.intersect1d(rows[ptr[a] : ptr[a + 1]], rows[ptr[b] : ptr[b + 1]]).size)
            by_keys = bool(np.isin(codes[b], (codes[a][:, None] + offsets[None, :]).ravel()).any())
            assert by_rows == by_keys, (rule, m, a, b)
            shared += by_rows
        assert 300 <= shared < len(pairs)
