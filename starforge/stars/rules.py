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


def window_bytes(n_stars: float, rule: str, m: int) -> float:
    """Peak bytes of :func:`window_rows` for ``n_stars`` stars: per window entry the anchors
    (3 int64), the codes, the sort's copy, the keep mask and the star ids, plus a base."""
    return n_stars * KEYS[rule] * m**3 * 64.0 + 100e6


def window_rows(index: np.ndarray, rule: str, m: int, pool_size: int):
    """The set-packing incidence: (star, row) pairs, one row per key window.

    Returns
    -------
    star : (z,) int   row r of the constraint matrix holds star ``star[z]`` ...
    row : (z,) int    ... in row ``row[z]`` (rows renumbered 0..R-1)
    n_rows : int
    """
    from starforge.budget import require_memory

    n_stars = len(index)
    require_memory(
        window_bytes(n_stars, rule, m),
        f"the selection's key windows ({n_stars:,} stars x {KEYS[rule]} keys x {m**3:,} tolerance offsets)",
        f"lower tolerance_mm or raise delta_mm (the tolerance spans {m} pool steps; each step cubes the windows)",
    )
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
    if keep.all():  # the usual case: no boolean indexing needed
        star = np.repeat(np.arange(n, dtype=np.intp), code.shape[1])
        code = code.ravel()
    else:
        star = np.broadcast_to(np.arange(n, dtype=np.intp)[:, None], code.shape)[keep]
        code = code[keep]
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
