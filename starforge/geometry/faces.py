"""The face table: which triangles of pool lengths provably do not fit a box, a quick no-fit
proof for every point set that contains one (decided once per pool by the fit decision,
:mod:`starforge.geometry.fit`)."""

from __future__ import annotations

import numpy as np

from starforge.geometry.fit import MAX_CELLS, NO_FIT, SLACK_MM, decide_all
from starforge.tol import tol

#: added to ``lim + slack`` when faces are decided (:func:`face_table`): it covers the float
#: noise between a face placed from its three lengths and the same face inside a star (about
#: 1e-13 mm), and the search's own ``1e-9`` mm, many times over
FACE_HAIR_MM = 1e-7


#: pools up to this many lengths get a face table (n^3 bytes: 16 MB at 256)
FACE_TABLE_MAX_POOL = 256


def face_table(pool, min_steps: int, limit, slack: float = SLACK_MM, threads=None) -> np.ndarray:
    """Which triangles of pool lengths provably do not fit the limit widened by ``slack``: a
    quick no-fit proof for whole point sets that contain such a triangle.

    Returns ``(n, n, n)`` int8 (``n = len(pool)``): 1 at ``[i, j, k]`` (in every order of the
    three indices) when the triangle with sides ``pool[i], pool[j], pool[k]`` does not fit the
    box ``sorted(limit) + slack + FACE_HAIR_MM`` in any orientation, proven by the search
    (:func:`starforge.geometry.fit.decide_fit` on the triangle's three corners: its NO_FIT is a proof whatever its
    own slack); 0 where that is not proven, and for triples not pairwise ``min_steps`` pool
    steps apart or not strictly a triangle (no claim).  A pool longer than
    :data:`FACE_TABLE_MAX_POOL` gets an empty ``(0, 0, 0)`` table (no claims).

    Why a set with such a face can be rejected without the search, outcome for outcome: a
    subset of a set that fits a box fits it too.  A set the search calls FIT fits ``lim``; a
    set it leaves UNDECIDED (open cells at the smallest size) fits ``lim + slack`` up to the
    inner problem's ``1e-9`` mm (:mod:`starforge.geometry.fit`).  A face that does not fit
    ``lim + slack + FACE_HAIR_MM`` rules out both (the hair covers the float noise between the
    face's corners here and in the set), so the search could only have said NO_FIT.  (It may also settle a set that would have run into ``max_cells``: proven not to fit instead
    of undecided.)  The table is a pure
    function of its arguments (each triangle decided on its own, whatever the threads)."""
    pool = np.asarray(pool, dtype=float)
    n = len(pool)
    if n > FACE_TABLE_MAX_POOL:
        return np.zeros((0, 0, 0), dtype=np.int8)
    table = np.zeros((n, n, n), dtype=np.int8)
    m = max(1, int(min_steps))
    pi, pj = np.nonzero(np.subtract.outer(np.arange(n), np.arange(n)) <= -m)  # i < j, m apart
    parts = []
    for kk in range(2 * m, n):  # the longest side: strictly shorter than the other two together
        sel = (pj <= kk - m) & (pool[pi] + pool[pj] > pool[kk] * (1 + tol.length_mm))
        parts.append((pi[sel], pj[sel], np.full(int(sel.sum()), kk)))
    if not parts or not sum(len(x[0]) for x in parts):
        return table
    i, j, k = (np.concatenate([x[t] for x in parts]) for t in range(3))
    a, b, c = pool[i], pool[j], pool[k]  # a < b < c
    # the triangle's corners: 0, (c, 0, 0), and the corner at distance b from 0, a from (c, 0, 0)
    cx = (c * c + b * b - a * a) / (2 * c)
    P = np.zeros((len(i), 3, 3))
    P[:, 1, 0] = c
    P[:, 2, 0] = cx
    P[:, 2, 1] = np.sqrt(np.maximum(b * b - cx * cx, 0.0))
    lim = np.sort(np.asarray(limit, dtype=float)) + float(slack) + FACE_HAIR_MM
    status = np.zeros(len(P), dtype=np.int8)
    R = np.empty((len(P), 3, 3))
    work = np.zeros(len(P), dtype=np.int64)
    decide_all(P, lim, float(slack), 1, MAX_CELLS, status, R, work, threads)
    no = status == NO_FIT
    i, j, k = i[no], j[no], k[no]
    for x, y, z in ((i, j, k), (i, k, j), (j, i, k), (j, k, i), (k, i, j), (k, j, i)):
        table[x, y, z] = 1
    return table
