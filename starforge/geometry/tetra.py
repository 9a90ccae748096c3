"""Tetrahedra from six edge lengths and back; realisability; relabelling; faces.

Conventions (the paper's Fig. 2): vertices A, B, C, D; opposite edge pairs
(u, U) = (AB, CD), (v, V) = (BC, AD), (w, W) = (AC, BD).  Length vectors are in the
paper's order ``(u, U, v, V, w, W)``; all lengths in mm.

Every function is vectorised over a leading axis: ``lengths : (n, 6)``,
``vertices : (n, 4, 3)``.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from starforge.tol import tol

#: names of the six lengths, in the order used everywhere
LENGTH_NAMES = ("u", "U", "v", "V", "w", "W")

#: vertex index pairs of each length, same order as LENGTH_NAMES
EDGE_VERTICES = np.array([(0, 1), (2, 3), (1, 2), (0, 3), (0, 2), (1, 3)], dtype=np.intp)

#: the four faces as vertex triples (ABC, ABD, ACD, BCD)
FACE_VERTICES = np.array([(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)], dtype=np.intp)

#: the lengths (indices into LENGTH_NAMES) bounding each face; every face holds one edge of each pair
FACE_EDGES = np.array([(0, 2, 4), (0, 5, 3), (4, 1, 3), (2, 1, 5)], dtype=np.intp)

FACE_NAMES = ("ABC", "ABD", "ACD", "BCD")


def _edge_index() -> dict[tuple[int, int], int]:
    idx = {}
    for k, (a, b) in enumerate(EDGE_VERTICES):
        idx[(int(a), int(b))] = k
        idx[(int(b), int(a))] = k
    return idx


def _relabel_permutations() -> np.ndarray:
    """(24, 6) int: for each vertex permutation p, the length-index map ``new[k] = old[perm[k]]``."""
    idx = _edge_index()
    out = []
    for p in itertools.permutations(range(4)):
        # relabelled vertex i is old vertex p[i]; relabelled edge (a, b) is old edge (p[a], p[b])
        out.append([idx[(p[a], p[b])] for a, b in EDGE_VERTICES])
    return np.array(out, dtype=np.intp)


#: all 24 relabellings of the four vertices acting on length vectors
RELABELLINGS = _relabel_permutations()


def vertices_from_lengths(lengths: np.ndarray) -> np.ndarray:
    """Trilaterate the four vertices from six edge lengths (the paper's construction).

    A at the origin, B = (u, 0, 0), C in the xy-plane (y > 0) with |BC| = v and |AC| = w,
    D on the three spheres |AD| = V, |BD| = W, |CD| = U with z > 0 (the other root is the
    mirror image, which distances cannot tell apart).

    Parameters
    ----------
    lengths : (6,) or (n, 6) float, mm
        ``(u, U, v, V, w, W)``; must be realisable (see :func:`realisability`).

    Returns
    -------
    vertices : (4, 3) or (n, 4, 3) float, mm
        Rows A, B, C, D.  Unrealisable rows are NaN.
    """
    L = np.asarray(lengths, dtype=float)
    single = L.ndim == 1
    L = np.atleast_2d(L)
    u, U, v, V, w, W = L.T
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = (u * u + w * w - v * v) / (2 * u)
        cy = np.sqrt(w * w - cx * cx)
        dx = (u * u + V * V - W * W) / (2 * u)
        dy = (V * V - U * U + cx * cx + cy * cy - 2 * dx * cx) / (2 * cy)
        dz = np.sqrt(V * V - dx * dx - dy * dy)
    n = len(L)
    P = np.zeros((n, 4, 3))
    P[:, 1, 0] = u
    P[:, 2, 0] = cx
    P[:, 2, 1] = cy
    P[:, 3] = np.stack([dx, dy, dz], axis=1)
    bad = ~np.isfinite(P).all(axis=(1, 2))
    P[bad] = np.nan
    return P[0] if single else P


def lengths_from_vertices(vertices: np.ndarray) -> np.ndarray:
    """Edge lengths ``(u, U, v, V, w, W)`` of tetrahedra, mm: (4, 3) -> (6,) or (n, 4, 3) -> (n, 6)."""
    P = np.asarray(vertices, dtype=float)
    d = P[..., EDGE_VERTICES[:, 0], :] - P[..., EDGE_VERTICES[:, 1], :]
    return np.linalg.norm(d, axis=-1)


def cayley_menger_volume2(lengths: np.ndarray) -> np.ndarray:
    """Squared volume from the Cayley-Menger determinant, mm^6: (..., 6) -> (...).

    ``288 V^2 = det CM``; a value <= 0 means no tetrahedron has these lengths.
    """
    L = np.asarray(lengths, dtype=float)
    s = L * L
    # squared distances d_ij between vertices 0..3
    d01, d23, d12, d03, d02, d13 = np.moveaxis(s, -1, 0)
    # Closed form of the 5x5 Cayley-Menger determinant (symmetric expansion)
    det = (
        d01 * d23 * (d02 + d13 + d03 + d12 - d01 - d23)
        + d02 * d13 * (d01 + d23 + d03 + d12 - d02 - d13)
        + d03 * d12 * (d01 + d23 + d02 + d13 - d03 - d12)
        - d01 * d02 * d12
        - d01 * d03 * d13
        - d02 * d03 * d23
        - d12 * d13 * d23
    ) * 2.0
    return det / 288.0


def face_sides(lengths: np.ndarray) -> np.ndarray:
    """Side lengths of the four faces (ABC, ABD, ACD, BCD), each sorted ascending: (..., 6) -> (..., 4, 3)."""
    L = np.asarray(lengths, dtype=float)
    return np.sort(L[..., FACE_EDGES], axis=-1)


def realisability(lengths: np.ndarray) -> np.ndarray:
    """Why each length set is not a tetrahedron: (n, 6) -> (n,) object array of str ('' when valid).

    Checks strictly positive lengths, the strict triangle inequality on all four faces, then a
    positive Cayley-Menger volume.
    """
    L = np.atleast_2d(np.asarray(lengths, dtype=float))
    reasons = np.full(len(L), "", dtype=object)
    nonpos = (L <= 0).any(axis=1)
    reasons[nonpos] = "a length is not positive"
    f = face_sides(L)
    tri_bad = f[..., 0] + f[..., 1] <= f[..., 2] + tol.length_mm
    for k in range(4):
        m = tri_bad[:, k] & (reasons == "")
        reasons[m] = f"face {FACE_NAMES[k]} violates the triangle inequality"
    vol2 = cayley_menger_volume2(L)
    m = (vol2 <= tol.volume_mm3**2) & (reasons == "")
    reasons[m] = "Cayley-Menger volume <= 0 (the three spheres around A, B, C do not meet)"
    return reasons


def is_realisable(lengths: np.ndarray) -> np.ndarray:
    """Boolean mask of realisable length sets, vectorised: (n, 6) -> (n,)."""
    L = np.atleast_2d(np.asarray(lengths, dtype=float))
    f = face_sides(L)
    ok = (L > 0).all(axis=1) & (f[..., 0] + f[..., 1] > f[..., 2] + tol.length_mm).all(axis=1)
    return ok & (cayley_menger_volume2(L) > tol.volume_mm3**2)


def canonical_lengths(lengths: np.ndarray) -> np.ndarray:
    """The canonical representative among the 24 relabellings (lexicographically smallest).

    Stars equal up to relabelling the vertices, or mirror images (same lengths), share it.
    (6,) -> (6,) or (n, 6) -> (n, 6).
    """
    L = np.asarray(lengths, dtype=float)
    single = L.ndim == 1
    L = np.atleast_2d(L)
    forms = L[:, RELABELLINGS]  # (n, 24, 6)
    # lexicographic argmin over the 24 forms: sort keys last-to-first
    order = np.lexsort(forms.transpose(2, 0, 1)[::-1].reshape(6, -1)).reshape(-1)
    # lexsort over flattened (n*24) rows; pick per star the first row of its block in sorted order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    best = rank.reshape(len(L), 24).argmin(axis=1)
    out = forms[np.arange(len(L)), best]
    return out[0] if single else out


def canonical_assignments() -> np.ndarray:
    """(30, 6) int: the distinct ways to put six distinct sorted lengths on a tetrahedron's edges.

    Row r maps sorted ranks to positions: ``lengths = sorted6[assign[r]]`` gives the r-th
    labelling in ``(u, U, v, V, w, W)`` order.  720 assignments / 24 relabellings = 30 classes;
    a mirror image has the same lengths, so it is already the same class.  (Worked out once per
    process, 20 ms, then copied: every enumeration chunk asks for it.)
    """
    return _canonical_assignments().copy()


@functools.lru_cache(maxsize=1)
def _canonical_assignments() -> np.ndarray:
    seen = set()
    reps = []
    for perm in itertools.permutations(range(6)):
        p = np.array(perm)
        forms = p[RELABELLINGS]
        key = min(map(tuple, forms))
        if key not in seen:
            seen.add(key)
            reps.append(key)
    return np.array(sorted(reps), dtype=np.intp)


def tetra_width(lengths: np.ndarray) -> np.ndarray:
    """Minimal width of each tetrahedron (smallest extent over all directions), mm: (n, 6) -> (n,).

    For a tetrahedron the width is attained between a vertex and its opposite face, or between
    two opposite edges, so it is ``min(3V / area_face, 6V / |e x e'|)``.
    """
    L = np.atleast_2d(np.asarray(lengths, dtype=float))
    vol = np.sqrt(np.maximum(cayley_menger_volume2(L), 0.0))
    f = L[:, FACE_EDGES]
    a, b, c = f[..., 0], f[..., 1], f[..., 2]
    area = 0.25 * np.sqrt(np.maximum((a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c), 0.0))
    h = 3 * vol[:, None] / np.where(area > 0, area, np.inf)
    # |e x e'| for opposite edges from lengths: (e.e')^2 = ((d03+d12-d02-d13)/2)^2 for pair (AB, CD), etc.
    s = L * L
    d01, d23, d12, d03, d02, d13 = s.T
    dots = np.stack(
        [
            0.5 * (d03 + d12 - d02 - d13),  # AB . CD
            0.5 * (d01 + d23 - d02 - d13),  # BC . AD  (up to sign)
            0.5 * (d01 + d23 - d03 - d12),  # AC . BD  (up to sign)
        ],
        axis=1,
    )
    prod = np.stack([d01 * d23, d12 * d03, d02 * d13], axis=1)
    cross = np.sqrt(np.maximum(prod - dots * dots, 0.0))
    g = 6 * vol[:, None] / np.where(cross > 0, cross, np.inf)
    return np.minimum(h.min(axis=1), g.min(axis=1))
