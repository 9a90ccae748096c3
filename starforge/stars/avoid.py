"""Bodies a lab already owns, as the triangles new stars must stay distinguishable from.

A tracker tells bodies apart by the triangles their markers span; under the face rule a new star
may not have a face whose sorted sides all lie within the tolerance of any triangle of an
existing body (each body's every marker triple, since a tracker may see any three).
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from starforge.geometry.tetra import face_sides
from starforge.tol import tol


@functools.lru_cache(maxsize=64)
def _triples(n: int) -> np.ndarray:
    """(C(n, 3), 3) every marker triple of n markers (read-only; optimizers ask for it per layout)."""
    tri = np.array(list(itertools.combinations(range(n), 3)), dtype=np.intp).reshape(-1, 3)
    tri.setflags(write=False)
    return tri


def body_triangles(points_mm: np.ndarray) -> np.ndarray:
    """Sorted side lengths (t, 3), mm, of every marker triple of one body (n, 3)."""
    P = np.asarray(points_mm, dtype=float)
    tri = _triples(len(P))
    if not len(tri):
        return np.zeros((0, 3))
    a = np.linalg.norm(P[tri[:, 0]] - P[tri[:, 1]], axis=1)
    b = np.linalg.norm(P[tri[:, 1]] - P[tri[:, 2]], axis=1)
    c = np.linalg.norm(P[tri[:, 0]] - P[tri[:, 2]], axis=1)
    return np.sort(np.stack([a, b, c], axis=1), axis=1)


def avoid_mask(
    index: np.ndarray, pool: np.ndarray, avoid_faces_mm: np.ndarray | None, tol_mm: float
) -> np.ndarray:
    """Candidates none of whose faces is within ``tol_mm`` (every sorted side) of an avoided
    triangle (k, 3): the face rule against bodies a lab already owns.  (n,) bool."""
    if avoid_faces_mm is None or not len(avoid_faces_mm) or not len(index):
        return np.ones(len(index), dtype=bool)
    # scipy loads here, not with the module: the kernels' wheel build imports the props' kernels
    # (which take body_triangles from here) where only numba and numpy are installed
    from scipy.spatial import cKDTree

    tree = cKDTree(np.sort(np.asarray(avoid_faces_mm, dtype=float), axis=1))
    F = np.sort(face_sides(pool[index]), axis=2).reshape(-1, 3)
    # Chebyshev distance < tol  <=>  every sorted side within the tolerance: indistinguishable
    d, _ = tree.query(F, k=1, p=np.inf, distance_upper_bound=tol_mm)
    clash = (d < tol_mm - tol.length_mm).reshape(len(index), 4).any(axis=1)
    return ~clash

