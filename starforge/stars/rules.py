"""Uniqueness rules as set packing over triangle keys.

A *face key* is the sorted side-length triple of one face.  A *vertex key* is the sorted triple
of the three edges meeting at one vertex.  With lengths on the pool grid, "differ by at least
the tolerance" becomes "differ by at least ``m = ceil(tol / delta)`` grid steps".

* ``face`` rule: every face of the family, within one star too, differs from every other face
  in at least one sorted side by >= tol.  Two stars conflict iff they hold two face keys within
  ``m - 1`` steps in every side.
* ``pair`` rule (the paper): two stars are distinct iff, however the second is relabelled,
  both lengths of at least one opposite pair differ.  Choosing one edge from each of the three
  opposite pairs gives either a face or the three edges at a vertex (4 + 4 ways), and a
  relabelling maps faces to faces and vertex stars to vertex stars; so two stars conflict iff
  they share a face key or a vertex key (within tolerance).

Conflicts are therefore cliques: all keys inside one window ``[a, a + m - 1]^3`` of grid indices
conflict pairwise, and every conflicting pair lies in some window, so "each window used at
most once" is exactly the rule.  That makes maximum-family selection a set packing with one
row per window (a few thousand), not one per conflicting pair.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.geometry.tetra import FACE_EDGES
from starforge.runtime.kernels import numba

#: edges (indices into (u, U, v, V, w, W)) meeting at A, B, C, D
VERTEX_EDGES = np.array([(0, 4, 3), (0, 2, 5), (4, 2, 1), (3, 5, 1)], dtype=np.intp)


def grid_steps(tolerance_mm: float, delta_mm: float) -> int:
    """m: two pool lengths are distinguishable iff they differ by >= m grid steps."""
    return max(1, math.ceil(tolerance_mm / delta_mm - 1e-9))


def sort3(x: np.ndarray) -> np.ndarray:
    """Sort the last axis of size 3 (faster than np.sort on tiny axes)."""
    a, b, c = x[..., 0], x[..., 1], x[..., 2]
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    return np.stack([lo, a + b + c - lo - hi, hi], axis=-1)


def key_triples(index: np.ndarray, rule: str) -> np.ndarray:
    """Sorted index triples of each star's keys: (n, 6) -> (n, k, 3); k = 4 (face) or 8 (pair).

    For the pair rule the vertex keys come after the face keys; callers tag the type.
    """
    idx = np.asarray(index)
    groups = [FACE_EDGES] if rule == "face" else [FACE_EDGES, VERTEX_EDGES]
    return np.concatenate([sort3(idx[:, g]) for g in groups], axis=1)


@numba.njit(nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)
def key3(index, i, edges, j):
    """Star ``i``'s key ``j`` in compiled code: the pool indices on its edges ``edges[j]``
    sorted, as (lo, mid, hi) int64 (what :func:`key_triples` gives for every star at once)."""
    a = np.int64(index[i, edges[j, 0]])
    b = np.int64(index[i, edges[j, 1]])
    c = np.int64(index[i, edges[j, 2]])
    lo = min(a, b, c)
    hi = max(a, b, c)
    return lo, a + b + c - lo - hi, hi


def internal_ok(index: np.ndarray, rule: str, m: int) -> np.ndarray:
    """Stars whose own keys do not conflict with each other (n,) bool.

    All six lengths of a star are distinct pool values, so they differ by >= delta and every
    face is scalene; with ``m > 1`` no two of the star's own keys of one type may also lie
    within m - 1 steps in every side (the face rule holds within one star too).
    """
    idx = np.asarray(index)
    ok = np.ones(len(idx), dtype=bool)  # six distinct lengths: 15 column comparisons (no row sort)
    for a in range(6):
        for b in range(a + 1, 6):
            ok &= idx[:, a] != idx[:, b]
    if m > 1:
        keys = key_triples(idx, rule)
        nk = keys.shape[1]
        for a in range(nk):
            for b in range(a + 1, nk):
                if (a < 4) != (b < 4):
                    continue  # a face and a vertex star never conflict
                close = (np.abs(keys[:, a] - keys[:, b]) <= m - 1).all(axis=1)
                ok &= ~close
    return ok


#: keys per star: the 4 faces, and for the pair rule the 4 vertex triples too
KEYS = {"face": 4, "pair": 8}


#: largest code table of :func:`key_points` (entries, 8 bytes each)
POINT_TABLE_MAX = 1 << 24


def key_points(index: np.ndarray, rule: str, m: int, pool_size: int):
    """Each star's keys as points of the grid of pool indices, for finding the stars that share
    a window of :func:`window_rows` with a star through its keys' neighbourhoods: two keys share
    a window iff they are of one type and within ``m - 1`` steps in every side.

    Returns
    -------
    codes : (n, k) int64    the code of each key: type, then its three sides shifted by m - 1
    table : (T,) int64      code -> point id (0.. in code order), -1 where no key is
    offsets : ((2m-1)^3,) int64   the code offsets of the keys within m - 1 steps in every side

    or None when the table would hold more than :data:`POINT_TABLE_MAX` entries.
    """
    keys = key_triples(index, rule).astype(np.int64)  # (n, k, 3)
    k = keys.shape[1]
    sh = m - 1
    base = pool_size + 2 * sh
    span = (k // 4) * base**3
    if span > POINT_TABLE_MAX:
        return None
    tag = (np.arange(k) >= 4).astype(np.int64)  # 0 face, 1 vertex
    codes = ((tag * base + keys[..., 0] + sh) * base + keys[..., 1] + sh) * base + keys[..., 2] + sh
    used = np.zeros(span, dtype=bool)
    used[codes] = True
    table = np.where(used, np.cumsum(used) - 1, -1)
    d = np.arange(-sh, sh + 1)
    offsets = (d[:, None, None] * base**2 + d[None, :, None] * base + d[None, None, :]).ravel()
    return codes, table, offsets


def window_bytes(n_stars: float, rule: str, m: int) -> float:
    """Peak bytes of :func:`window_rows` for ``n_stars`` stars: per window entry the anchors
    (3 int64), the codes, the sort's copy, the keep mask and the star ids, plus a base."""
    return n_stars * KEYS[rule] * m**3 * 64.0 + 100e6


#: (star, window) entries from which :func:`window_rows` runs compiled (:func:`_window_codes`):
#: large windows (``--delta 1.0``) run several times faster compiled; below it numpy's passes
#: take hundredths of a second and a first run compiles nothing for them
WINDOW_KERNEL_ENTRIES = 4_000_000


def window_rows(index: np.ndarray, rule: str, m: int, pool_size: int):
    """The set-packing incidence: (star, row) pairs, one row per key window.

    Returns
    -------
    star : (z,) int   row r of the constraint matrix holds star ``star[z]`` ...
    row : (z,) int    ... in row ``row[z]`` (rows renumbered 0..R-1)
    n_rows : int
    """
    from starforge.runtime.budget import require_memory

    n_stars = len(index)
    require_memory(
        window_bytes(n_stars, rule, m),
        f"the selection's key windows ({n_stars:,} stars x {KEYS[rule]} keys x {m**3:,} tolerance offsets)",
        f"lower tolerance_mm or raise delta_mm (the tolerance spans {m} pool steps; each step cubes the windows)",
    )
    if n_stars * KEYS[rule] * m**3 >= WINDOW_KERNEL_ENTRIES:
        return _window_rows_compiled(np.asarray(index), rule, m, pool_size)
    keys = key_triples(index, rule)  # (n, k, 3)
    n, k, _ = keys.shape
    tag = (np.arange(k) >= 4).astype(np.int64)  # 0 face, 1 vertex
    base = pool_size + m  # room for negative anchors shifted by m
    offs = [(a, b, c) for a in range(m) for b in range(m) for c in range(m)]
    # codes are below 2 base^3: int32 where that fits (every pool stars use; half the memory)
    dt = np.int32 if 2 * base**3 < 2**31 else np.int64
    # code of the window anchored at key - offset (shifted by m), column key * m^3 + offset
    code = np.empty((n, k * len(offs)), dtype=dt)
    for j in range(k):
        k0, k1, k2 = (keys[:, j, i].astype(dt) for i in range(3))
        for o, (a, b, c) in enumerate(offs):
            col = code[:, j * len(offs) + o]
            np.add(k0, tag[j] * base + m - a, out=col)
            col *= base
            col += k1
            col += m - b
            col *= base
            col += k2
            col += m - c
    # one entry per (star, row), each star's rows in ascending code order: sort within the star
    # and drop repeats (two keys of one star in one window; none after internal_ok)
    if code.shape[1] == 4:  # the face rule at m = 1: a sorting network (many 4-element sorts are slow)
        a, b, c, d = (code[:, i] for i in range(4))
        a, b = np.minimum(a, b), np.maximum(a, b)
        c, d = np.minimum(c, d), np.maximum(c, d)
        a, c = np.minimum(a, c), np.maximum(a, c)
        b, d = np.minimum(b, d), np.maximum(b, d)
        b, c = np.minimum(b, c), np.maximum(b, c)
        code = np.stack([a, b, c, d], axis=1)
    else:
        code = np.sort(code, axis=1)
    keep = np.ones(code.shape, dtype=bool)
    keep[:, 1:] = code[:, 1:] != code[:, :-1]
    star, code = _entries(code, keep)
    # rows numbered by ascending code: a dense table when the code space is small (no sort;
    # at most 16 M entries, about 150 MB with the ranks)
    span = 2 * base**3
    if span <= 1 << 24:
        used = np.zeros(span, dtype=bool)
        used[code] = True
        rank = np.cumsum(used, dtype=np.intp) - 1
        return star, rank[code], int(rank[-1] + 1) if len(code) else 0
    uniq, row = np.unique(code, return_inverse=True)
    return star, row.astype(np.intp), len(uniq)


def _entries(code: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (star, code) entries of ``code`` (n, w), one star's per row, where ``keep`` (n, w)
    is True, in row-major order."""
    if keep.all():  # the usual case: no boolean indexing needed
        return np.repeat(np.arange(len(code), dtype=np.intp), code.shape[1]), code.ravel()
    return np.broadcast_to(np.arange(len(code), dtype=np.intp)[:, None], code.shape)[keep], code[keep]


def _window_rows_compiled(index: np.ndarray, rule: str, m: int, pool_size: int):
    """:func:`window_rows` through :func:`_window_codes` and :func:`_dense_rows`: the same
    (star, row) pairs and row numbers."""
    base = pool_size + m  # room for negative anchors shifted by m
    edges = np.concatenate([FACE_EDGES] if rule == "face" else [FACE_EDGES, VERTEX_EDGES]).astype(np.int64)
    code, count = _window_codes(index.astype(np.int32), edges, int(m), int(base))
    star, code = _counted_entries(code, count)
    span = 2 * base**3
    if span <= 1 << 24:
        row, n_rows = _dense_rows(code, span)
        return star, row, int(n_rows)
    uniq, row = np.unique(code, return_inverse=True)
    return star, row.astype(np.intp), len(uniq)


@numba.njit(cache=True, nogil=True)
def _window_codes(index, edges, m, base):
    """The key windows of each star (``index`` (n, 6) pool indices; ``edges`` (k, 3): the
    edges of its k keys, faces first): window code of key (a <= b <= c) of type tag (0 face,
    1 vertex) at offset (x, y, z) in [0, m)^3 is ``((tag * base + a + m - x) * base + b + m -
    y) * base + c + m - z`` (anchors shifted by m, so never negative).  Returns ``code`` (n,
    k m^3): each star's codes ascending without repeats in ``code[i, :count[i]]``, and
    ``count``."""
    n, k = index.shape[0], edges.shape[0]
    width = k * m * m * m
    code = np.empty((n, width), dtype=np.int64)
    count = np.empty(n, dtype=np.int64)
    tmp = np.empty(width, dtype=np.int64)
    for i in range(n):
        q = 0
        for j in range(k):
            lo, mid, hi = key3(index, i, edges, j)
            t0 = lo + m + (base if j >= 4 else 0)
            for x in range(m):
                for y in range(m):
                    for z in range(m):
                        tmp[q] = ((t0 - x) * base + mid + m - y) * base + hi + m - z
                        q += 1
        # Shell's sort (gaps ~width/2.2^k, then 1; no numpy sort: it costs seconds to compile)
        gap = width // 2
        while True:
            for p in range(gap, width):
                v = tmp[p]
                r = p
                while r >= gap and tmp[r - gap] > v:
                    tmp[r] = tmp[r - gap]
                    r -= gap
                tmp[r] = v
            if gap <= 1:
                break
            gap = max(1, int(gap / 2.2))
        d = 0
        for p in range(width):
            if d == 0 or tmp[p] != code[i, d - 1]:
                code[i, d] = tmp[p]
                d += 1
        count[i] = d
    return code, count


@numba.njit(cache=True, nogil=True)
def _counted_entries(code, count):
    """The (star, code) entries of ``code[i, :count[i]]`` for each star ``i``, in row-major
    order (what :func:`_entries` gives for that mask), without holding Python's lock: the
    progress display keeps drawing while millions of entries are gathered."""
    total = 0
    for i in range(len(count)):
        total += count[i]
    star = np.empty(total, dtype=np.intp)
    flat = np.empty(total, dtype=code.dtype)
    q = 0
    for i in range(len(count)):
        for j in range(count[i]):
            star[q] = i
            flat[q] = code[i, j]
            q += 1
    return star, flat


@numba.njit(cache=True, nogil=True)
def _dense_rows(code, span):
    """Rows numbered by ascending code through a table of the ``span`` possible codes: (row of
    each entry, number of rows)."""
    rank = np.zeros(span, dtype=np.int64)
    for c in code:
        rank[c] = 1
    k = 0
    for c in range(span):
        if rank[c]:
            rank[c] = k
            k += 1
    row = np.empty(len(code), dtype=np.intp)
    for i in range(len(code)):
        row[i] = rank[code[i]]
    return row, k
