"""How far a marker layout lies from mistaking itself: its subsets against each other, relabelled.

A tracker that sees only three markers of a body compares the triangle they span with the
triangles it knows (:mod:`starforge.tracking.identify`).  Two triangles of one layout whose
sorted sides all lie within the tracker's window are the same triangle to it (a wrong pose when
only those markers are seen), and so is a triangle with two sides within the window matched to
itself with two markers swapped.  The **self-margin** of a layout is the smallest such difference,
mm: the Chebyshev distance of the sorted sides of any two of its triangles (for triangles the
bottleneck over every vertex correspondence, exactly), and the smallest gap between two sides of
one triangle (the best relabelling of a triangle onto itself).  The sorted sides are those of
:func:`starforge.stars.avoid.body_triangles`, the home of the concept the ``--avoid`` rule uses
against other bodies.

Four-marker subsets follow: if a correspondence maps a 4-subset onto another (or onto itself,
not the identity) with every distance within ``w``, each of its triangles maps onto a triangle
within ``w``, a different triangle or the same one relabelled (a permutation of four markers that
keeps every 3-subset in place is the identity), so the 4-subset margin is at least the triangle
margin.  :func:`subset_margin` computes it directly for the report (every pair of 4-subsets,
every one of the 24 correspondences).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from starforge.runtime.kernels import numba
from starforge.stars.avoid import body_triangles


def own_triangles(points: np.ndarray, tol: float) -> tuple[int, float]:
    """``(conflicts, margin)`` of a layout's own triangles, in the units of ``points``.

    ``conflicts`` counts the pairs of triangles whose sorted sides all differ by less than
    ``tol`` and the triangles with two sides closer than ``tol``; ``margin`` is the self-margin
    (the smallest of those differences; ``inf`` for fewer than 3 points).

    >>> own_triangles(np.array([[0, 0, 0], [30, 0, 0], [0, 40, 0.0]]), 2.0)  # sides 30, 40, 50
    (0, 10.0)
    """
    F = body_triangles(np.asarray(points, dtype=float))
    if not len(F):
        return 0, math.inf
    conflicts, margin = _own_counts(np.ascontiguousarray(F[np.argsort(F[:, 0], kind="stable")]), float(tol))
    return int(conflicts), float(margin)


@numba.njit(cache=True, nogil=True)
def _own_counts(F, tol):
    """:func:`own_triangles` on sorted sides ``F`` ordered by the shortest side: a sweep that
    compares each triangle with those after it until the shortest sides alone differ by at least
    both ``tol`` and the margin found so far (the Chebyshev distance is at least that gap)."""
    T = F.shape[0]
    cnt = 0
    margin = np.inf
    for t in range(T):
        g = min(F[t, 1] - F[t, 0], F[t, 2] - F[t, 1])
        if g < tol:
            cnt += 1
        margin = min(margin, g)
    for t in range(T):
        for u in range(t + 1, T):
            d = F[u, 0] - F[t, 0]
            if d >= tol and d >= margin:
                break
            d = max(d, abs(F[u, 1] - F[t, 1]), abs(F[u, 2] - F[t, 2]))
            if d < tol:
                cnt += 1
            margin = min(margin, d)
    return cnt, margin


def tolerance_for(tolerances, n: int, fallback: float) -> float:
    """The triangle tolerance of a layout of ``n`` markers: entry ``n`` of ``tolerances`` (one per
    marker count, the last for any count beyond; the caller's design, e.g.
    :func:`starforge.api.place.distinct_tolerances_mm`), or ``fallback`` when there is none.

    >>> tolerance_for((2.0, 2.0, 2.0, 2.1, 2.2), 3, 9.0), tolerance_for((2.0, 2.1), 7, 9.0), tolerance_for(None, 7, 9.0)
    (2.1, 2.1, 9.0)
    """
    if tolerances is None or not len(tolerances):
        return float(fallback)
    return float(tolerances[min(int(n), len(tolerances) - 1)])


def face_tree(faces: np.ndarray | None):
    """A look-up tree of other bodies' triangles ((k, 3) sides, sorted here) for :func:`clashes`;
    None when there are none."""
    if faces is None or not len(faces):
        return None
    from scipy.spatial import cKDTree

    return cKDTree(np.sort(np.asarray(faces, dtype=float).reshape(-1, 3), axis=1))


def clashes(points: np.ndarray, tree, tol: float) -> int:
    """How many triangles of the layout ``points`` have sorted sides all within ``tol`` of one of
    the triangles in ``tree`` (:func:`face_tree`, the units of ``points``): the ``--avoid`` rule
    of :func:`starforge.stars.avoid.avoid_mask`, for a prop layout."""
    if tree is None or len(points) < 3:
        return 0
    d, _ = tree.query(
        body_triangles(np.asarray(points, dtype=float)), k=1, p=np.inf, distance_upper_bound=tol
    )
    return int((d < tol).sum())


def added_conflicts(points: np.ndarray, candidates: np.ndarray, tree, tol: float) -> np.ndarray:
    """(k,) for each candidate point c: how many conflicts the layout ``points + [c]`` has beyond
    those of ``points`` alone: its new triangles (two markers and c) within ``tol`` of one of
    ``tree``'s (:func:`clashes`), of one of the layout's triangles or of each other, or with two
    sides within ``tol`` (:func:`own_triangles`).  So ``own_triangles(points + [c])[0] +
    clashes(points + [c])`` is that of ``points`` plus this, for every candidate at once."""
    P = np.asarray(points, dtype=float)
    C = np.ascontiguousarray(np.asarray(candidates, dtype=float).reshape(-1, 3))
    if len(P) < 2 or not len(C):
        return np.zeros(len(C), dtype=np.int64)
    old = body_triangles(P)
    old = np.ascontiguousarray(old[np.argsort(old[:, 0], kind="stable")])
    out, F = _added_own(np.ascontiguousarray(P), C, old, float(tol))
    if tree is not None:
        d, _ = tree.query(F.reshape(-1, 3), k=1, p=np.inf, distance_upper_bound=tol)
        out += (d.reshape(F.shape[:2]) < tol).sum(axis=1)
    return out


@numba.njit(cache=True, nogil=True)
def _added_own(P, C, old, tol):
    """``(counts, F)``: for each candidate ``C[q]``, the conflicts among its new triangles (sorted
    sides ``F[q]``, one per marker pair of ``P``) and with the layout's own ``old`` triangles
    (sorted sides, ordered by the shortest): two sides of one triangle within ``tol``, two
    triangles with every sorted side within ``tol``.  Old triangles are met through a window on
    the shortest side, so each new triangle is compared with the few that can be within ``tol``."""
    n = P.shape[0]
    m = n * (n - 1) // 2
    nq = C.shape[0]
    out = np.zeros(nq, dtype=np.int64)
    F = np.empty((nq, m, 3))
    base = np.empty(m)
    ij = np.empty((m, 2), dtype=np.int64)
    k = 0
    for a in range(n):
        for b in range(a + 1, n):
            ij[k, 0], ij[k, 1] = a, b
            base[k] = math.sqrt((P[a, 0] - P[b, 0]) ** 2 + (P[a, 1] - P[b, 1]) ** 2 + (P[a, 2] - P[b, 2]) ** 2)
            k += 1
    first = old[:, 0]
    for q in range(nq):
        cnt = 0
        for k in range(m):
            a, b = ij[k, 0], ij[k, 1]
            x = base[k]
            y = math.sqrt((C[q, 0] - P[a, 0]) ** 2 + (C[q, 1] - P[a, 1]) ** 2 + (C[q, 2] - P[a, 2]) ** 2)
            z = math.sqrt((C[q, 0] - P[b, 0]) ** 2 + (C[q, 1] - P[b, 1]) ** 2 + (C[q, 2] - P[b, 2]) ** 2)
            if x > y:
                x, y = y, x
            if y > z:
                y, z = z, y
            if x > y:
                x, y = y, x
            F[q, k, 0], F[q, k, 1], F[q, k, 2] = x, y, z
            if min(y - x, z - y) < tol:
                cnt += 1
            # the window is widened a little, the test inside is exact
            lo = np.searchsorted(first, x - 2.0 * tol)
            for t in range(lo, len(first)):
                if first[t] > x + 2.0 * tol:
                    break
                if abs(old[t, 0] - x) < tol and abs(old[t, 1] - y) < tol and abs(old[t, 2] - z) < tol:
                    cnt += 1
        for k in range(m):
            for u in range(k + 1, m):
                if (
                    abs(F[q, k, 0] - F[q, u, 0]) < tol
                    and abs(F[q, k, 1] - F[q, u, 1]) < tol
                    and abs(F[q, k, 2] - F[q, u, 2]) < tol
                ):
                    cnt += 1
        out[q] = cnt
    return out, F


#: the 6 marker pairs of a 4-subset, in a fixed order
_PAIRS4 = list(itertools.combinations(range(4), 2))


def _pair_maps() -> np.ndarray:
    """(24, 6): for each relabelling of 4 markers, where each pair of the fixed order goes."""
    at = {p: i for i, p in enumerate(_PAIRS4)}
    rows = []
    for s in itertools.permutations(range(4)):
        rows.append([at[tuple(sorted((s[a], s[b])))] for a, b in _PAIRS4])
    return np.array(rows, dtype=np.intp)


def subset_margin(points: np.ndarray, k: int = 4, chunk: int = 64) -> float:
    """The smallest difference, in the units of ``points``, between the distances of two
    ``k``-marker subsets of a layout under any correspondence (a subset with itself: any but the
    identity); ``inf`` when there are fewer than ``k`` points.  ``k`` is 3 or 4."""
    P = np.asarray(points, dtype=float)
    if k == 3:
        return own_triangles(P, 0.0)[1]
    if k != 4:
        raise ValueError(f"k must be 3 or 4, got {k}")
    if len(P) < 4:
        return math.inf
    sub = np.array(list(itertools.combinations(range(len(P)), 4)), dtype=np.intp)
    ends = np.array(_PAIRS4, dtype=np.intp)
    D = np.linalg.norm(P[sub[:, ends[:, 0]]] - P[sub[:, ends[:, 1]]], axis=2)  # (m, 6)
    maps = _pair_maps()
    identity = 0  # itertools.permutations yields the identity first
    best = math.inf
    m = len(D)
    for a in range(0, m, chunk):
        A = D[a : a + chunk]
        for s, pm in enumerate(maps):
            d = np.abs(A[:, None, :] - D[None, :, pm]).max(axis=2)  # (chunk, m)
            if s == identity:
                d[np.arange(len(A)), np.arange(a, a + len(A))] = np.inf
            best = min(best, float(d.min()))
    return best
