"""The triangle library of a set of bodies: every triangle of 3 markers, its sides, sorted for
range look-ups, and the margins a tracker's distance window must stay under.

A triangle is the smallest identifying unit a tracker uses (what is left of a 4-marker star with
one marker hidden); see :mod:`starforge.tracking.identify`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from starforge.spec import require


@dataclass(frozen=True)
class Library:
    """Precomputed triangle table of a set of bodies (all lengths mm).

    Attributes
    ----------
    names : tuple of str
    points : (B, nmax, 3) float, mm       body markers, NaN-padded
    counts : (B,) int                     markers per body
    tri_body : (M,) int                   body of each triangle
    tri_verts : (M, 3) int                its marker indices
    tri_sides : (M, 3) float, mm          side opposite each vertex
    tri_sorted : (M, 3) float, mm         sorted sides; rows ordered by the longest side
    """

    names: tuple[str, ...]
    points: np.ndarray = field(repr=False)
    counts: np.ndarray = field(repr=False)
    tri_body: np.ndarray = field(repr=False)
    tri_verts: np.ndarray = field(repr=False)
    tri_sides: np.ndarray = field(repr=False)
    tri_sorted: np.ndarray = field(repr=False)

    @property
    def n_bodies(self) -> int:
        return len(self.names)

    @property
    def n_max(self) -> int:
        return self.points.shape[1]


def triangle_sides(A: np.ndarray) -> np.ndarray:
    """Sides opposite each vertex of triangles ``A`` (..., 3, 3) -> (..., 3), same units."""
    return np.stack(
        [
            np.linalg.norm(A[..., 1, :] - A[..., 2, :], axis=-1),
            np.linalg.norm(A[..., 0, :] - A[..., 2, :], axis=-1),
            np.linalg.norm(A[..., 0, :] - A[..., 1, :], axis=-1),
        ],
        axis=-1,
    )


def build_library(points_list, names=None) -> Library:
    """The triangle library of bodies given as a list of (n_i, 3) mm arrays (n_i >= 3)."""
    pts = [np.asarray(p, dtype=float).reshape(-1, 3) for p in points_list]
    require(len(pts) >= 1, "need at least one body")
    for i, p in enumerate(pts):
        require(len(p) >= 3, f"body {i} has {len(p)} markers; identification needs at least 3")
    names = tuple(names) if names is not None else tuple(f"body_{i + 1}" for i in range(len(pts)))
    nmax = max(len(p) for p in pts)
    P = np.full((len(pts), nmax, 3), np.nan)
    for i, p in enumerate(pts):
        P[i, : len(p)] = p
    tb, tv = [], []
    for i, p in enumerate(pts):
        tri = np.array(list(itertools.combinations(range(len(p)), 3)), dtype=np.intp)
        tb.append(np.full(len(tri), i))
        tv.append(tri)
    tri_body = np.concatenate(tb)
    tri_verts = np.concatenate(tv)
    sides = triangle_sides(P[tri_body[:, None], tri_verts])
    srt = np.sort(sides, axis=1)
    order = np.argsort(srt[:, 2], kind="stable")
    return Library(
        names,
        P,
        np.array([len(p) for p in pts]),
        tri_body[order],
        tri_verts[order],
        sides[order],
        srt[order],
    )


def close_triangle_pairs(lib: Library, window_mm: float, chunk: int = 4096):
    """Pairs of different library triangles whose sorted sides all differ by less than
    ``window_mm`` (the bottleneck distance: some vertex correspondence matches that closely).

    Returns ``(i, j, d)``: triangle indices ``i < j`` into the library's arrays and their
    bottleneck distances, mm.  Triangles of one body are paired too (a hidden marker can leave
    either).  Work is chunked over ``i``; memory grows with the pairs found.
    """
    S = lib.tri_sorted
    lo = np.searchsorted(S[:, 2], S[:, 2] - window_mm, side="left")
    hi = np.searchsorted(S[:, 2], S[:, 2] + window_mm, side="right")
    out_i, out_j, out_d = [], [], []
    for a in range(0, len(S), chunk):
        q0 = np.arange(a, min(a + chunk, len(S)))
        cnt = hi[q0] - lo[q0]
        q = np.repeat(q0, cnt)
        j = lo[q] + (np.arange(len(q)) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        keep = j > q
        q, j = q[keep], j[keep]
        d = np.abs(S[q] - S[j]).max(axis=1)
        keep = d < window_mm
        out_i.append(q[keep])
        out_j.append(j[keep])
        out_d.append(d[keep])
    if not out_i:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp), np.zeros(0)
    return np.concatenate(out_i), np.concatenate(out_j), np.concatenate(out_d)


def drop1_margin_mm(lib: Library) -> float:
    """The bodies' identification margin with one marker hidden, mm: the smallest difference a
    tracker's distance window must stay under so that no three markers it may see match a
    wrong body or a wrong correspondence.

    The minimum of (a) the bottleneck distance between any two different triangles (of two
    bodies, or of one body) and (b) the smallest gap between two sides of one triangle (under
    which the triangle matches itself with two vertices swapped).
    """
    S = lib.tri_sorted
    self_gap = float(np.min(np.diff(S, axis=1))) if len(S) else np.inf
    best = self_gap
    window = 1.0
    while window < 4 * max(float(S[:, 2].max()), 1.0):
        _, _, d = close_triangle_pairs(lib, min(window, best + 1e-9))
        if len(d):
            return float(min(best, d.min()))
        if window >= best:
            return best
        window *= 4.0
    return best
