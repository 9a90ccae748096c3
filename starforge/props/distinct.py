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

import functools
import itertools
import math

import numpy as np

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
    gaps = np.diff(F, axis=1).min(axis=1)
    conflicts = int((gaps < tol).sum())
    margin = float(gaps.min())
    if len(F) > 1:
        iu = _upper(len(F))
        d = np.abs(F[iu[0]] - F[iu[1]]).max(axis=1)
        conflicts += int((d < tol).sum())
        margin = min(margin, float(d.min()))
    return conflicts, margin


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


@functools.lru_cache(maxsize=64)
def _upper(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, 1)``, read-only (asked for once per layout the optimizers score)."""
    iu = np.triu_indices(n, 1)
    for a in iu:
        a.setflags(write=False)
    return iu


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> np.ndarray:
    """(C(n, 2), 2) every marker pair of n markers (read-only)."""
    ij = np.array(list(itertools.combinations(range(n), 2)), dtype=np.intp).reshape(-1, 2)
    ij.setflags(write=False)
    return ij


def added_conflicts(
    points: np.ndarray, candidates: np.ndarray, tree, tol: float, chunk: int = 64
) -> np.ndarray:
    """(k,) for each candidate point c: how many conflicts the layout ``points + [c]`` has beyond
    those of ``points`` alone: its new triangles (two markers and c) within ``tol`` of one of
    ``tree``'s (:func:`clashes`), of one of the layout's triangles or of each other, or with two
    sides within ``tol`` (:func:`own_triangles`).  So ``own_triangles(points + [c])[0] +
    clashes(points + [c])`` is that of ``points`` plus this, for every candidate at once."""
    P = np.asarray(points, dtype=float)
    C = np.asarray(candidates, dtype=float).reshape(-1, 3)
    out = np.zeros(len(C), dtype=np.int64)
    if len(P) < 2 or not len(C):
        return out
    ij = _pairs(len(P))
    base = np.linalg.norm(P[ij[:, 0]] - P[ij[:, 1]], axis=1)
    old = body_triangles(P)
    iu = _upper(len(ij))
    for a in range(0, len(C), chunk):
        Q = C[a : a + chunk]
        b = np.linalg.norm(Q[:, None] - P[None, ij[:, 0]], axis=2)
        c = np.linalg.norm(Q[:, None] - P[None, ij[:, 1]], axis=2)
        F = np.sort(np.stack([np.broadcast_to(base, b.shape), b, c], axis=2), axis=2)  # (q, m, 3)
        n = (np.diff(F, axis=2).min(axis=2) < tol).sum(axis=1)
        n += (np.abs(F[:, :, None] - F[:, None]).max(axis=3)[:, iu[0], iu[1]] < tol).sum(axis=1)
        if len(old):
            n += (np.abs(F[:, :, None] - old[None, None]).max(axis=3) < tol).sum(axis=(1, 2))
        if tree is not None:
            d, _ = tree.query(F.reshape(-1, 3), k=1, p=np.inf, distance_upper_bound=tol)
            n += (d.reshape(F.shape[:2]) < tol).sum(axis=1)
        out[a : a + len(Q)] = n
    return out


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
