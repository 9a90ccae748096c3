"""Enumerate every star of an edge-length pool that fits a size limit, vectorised.

Pipeline (each stage runs only on what the previous stages kept; no Python loop per star):

1. pool: ``l_min + k * delta`` (mm);
2. every 6-subset of the pool, each put on the tetrahedron in its 30 distinct ways
   (:func:`starforge.geometry.tetra.canonical_assignments`): one entry per star up to
   relabelling and mirroring;
3. realisable: the Gram matrix at A is positive definite (triangle ABC valid and
   Cayley-Menger volume > 0), read off the trilateration itself;
4. necessary fit conditions: the tetrahedron's width <= the shortest limit side, and Ky Fan's
   bounds on the covariance eigenvalues (the k smallest sum to at most the sum of the k
   shortest limit sides squared over 4);
5. sufficient fit: some candidate box orientation fits the limit: the covariance axes, then
   the 24 face-flush frames of O'Rourke's first case (a box face on a tetrahedron face, a side
   along a projected edge).  ``box_method="covariance"`` uses the covariance box alone (the
   paper's test).  O'Rourke's edge-edge frames are not tried here (too costly per candidate),
   so a star that fits only in such an orientation is missed: the enumeration is sound (every
   star kept fits, re-checked) but not complete.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from starforge.geometry.tetra import canonical_assignments
from starforge.errors import StarforgeError
from starforge.stars.spec import StarSpec
from starforge.tol import tol


@dataclass(frozen=True)
class Candidates:
    """Every star that fits, as arrays (row i is one star).

    Attributes
    ----------
    pool_mm : (p,) float         the edge-length pool, mm
    index : (m, 6) int16         pool indices of (u, U, v, V, w, W)
    box_extents : (m, 3) float   sides of the smallest fitting candidate box found, mm
    stats : dict                 counts per stage and seconds
    """

    pool_mm: np.ndarray
    index: np.ndarray
    box_extents: np.ndarray
    stats: dict

    def __len__(self) -> int:
        return len(self.index)

    @property
    def lengths(self) -> np.ndarray:
        """(m, 6) float, mm."""
        return self.pool_mm[self.index]

    @property
    def box_volume(self) -> np.ndarray:
        """(m,) float, mm^3."""
        return np.prod(self.box_extents, axis=1)


def edge_pool(spec: StarSpec) -> np.ndarray:
    """The pool of edge lengths, mm: ``l_min + k * delta`` up to ``l_max``."""
    lo, _ = spec.pool_bounds_mm
    return lo + spec.delta_mm * np.arange(spec.pool_size)


#: the most labelled candidates enumerated exhaustively (about a minute on 2 cores)
MAX_LABELLED = 150_000_000


def check_size(spec: StarSpec) -> None:
    """Refuse pools too large for exhaustive enumeration, with what to change."""
    from math import comb

    n = spec.pool_size
    labelled = comb(n, 6) * 30
    if labelled > MAX_LABELLED:
        lo, hi = spec.pool_bounds_mm
        raise StarforgeError(
            f"the edge-length pool holds {n} lengths ({lo:.2f}..{hi:.2f} mm in {spec.delta_mm} mm steps): "
            f"{labelled:,} candidates is too many to enumerate exhaustively (limit {MAX_LABELLED:,}); "
            f"raise delta_mm, gap_mm or l_min_mm, or lower l_max_mm"
        )


def _subsets(n: int, k: int = 6) -> np.ndarray:
    return np.fromiter(
        itertools.chain.from_iterable(itertools.combinations(range(n), k)), dtype=np.int16
    ).reshape(-1, k)


def _trilaterate(L: np.ndarray):
    """Vertices and a realisable mask for (m, 6) lengths (mm)."""
    u, U, v, V, w, W = L.T
    cx = (u * u + w * w - v * v) / (2 * u)
    cy2 = w * w - cx * cx
    ok = cy2 > tol.volume_mm3
    cy = np.sqrt(np.where(ok, cy2, 1.0))
    dx = (u * u + V * V - W * W) / (2 * u)
    dy = (V * V - U * U + w * w - 2 * dx * cx) / (2 * cy)
    dz2 = V * V - dx * dx - dy * dy
    ok &= dz2 > tol.volume_mm3
    P = np.zeros((len(L), 4, 3))
    P[:, 1, 0] = u
    P[:, 2, 0] = cx
    P[:, 2, 1] = cy
    P[:, 3, 0] = dx
    P[:, 3, 1] = dy
    P[:, 3, 2] = np.sqrt(np.where(ok, dz2, 0.0))
    return P, ok


def _fits(ext: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Sorted extents (..., 3) within the sorted limit (3,) (sorting 3 values without np.sort)."""
    a, b, c = ext[..., 0], ext[..., 1], ext[..., 2]
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    mid = a + b + c - lo - hi
    lim = limit * (1 + tol.box_rel) + tol.length_mm
    return (lo <= lim[0]) & (mid <= lim[1]) & (hi <= lim[2])


def _span(d: np.ndarray) -> np.ndarray:
    """Extent of the projections (..., 4) of four points: max - min over the last axis."""
    a, b, c, e = d[..., 0], d[..., 1], d[..., 2], d[..., 3]
    return np.maximum(np.maximum(a, b), np.maximum(c, e)) - np.minimum(np.minimum(a, b), np.minimum(c, e))


def sym3_eigvalsh(C: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues of symmetric 3x3 matrices (n, 3, 3) in closed form (trigonometric)."""
    a, b, c = C[:, 0, 0], C[:, 1, 1], C[:, 2, 2]
    d, e, f = C[:, 0, 1], C[:, 1, 2], C[:, 0, 2]
    q = (a + b + c) / 3
    p1 = d * d + e * e + f * f
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2 * p1
    p = np.sqrt(p2 / 6)
    ps = np.where(p > 0, p, 1.0)
    A, B, Cc = (a - q) / ps, (b - q) / ps, (c - q) / ps
    D, E, F = d / ps, e / ps, f / ps
    detB = A * (B * Cc - E * E) - D * (D * Cc - E * F) + F * (D * E - B * F)
    phi = np.arccos(np.clip(detB / 2, -1.0, 1.0)) / 3
    l3 = q + 2 * p * np.cos(phi)
    l1 = q + 2 * p * np.cos(phi + 2 * np.pi / 3)
    l2 = 3 * q - l1 - l3
    return np.stack([l1, l2, l3], axis=1)


_EDGES = np.array(list(itertools.combinations(range(4), 2)), dtype=np.intp)
_FACES = np.array(list(itertools.combinations(range(4), 3)), dtype=np.intp)


def face_flush_extents(P: np.ndarray) -> np.ndarray:
    """Box extents for O'Rourke's face-flush candidates: 4 face normals x 6 projected edges.

    Computed from dot-product tables without building frames: along the face normal F the
    projections are F.p; along a2 = (E - (E.F) F)/|..| they are (E.p - (E.F)(F.p))/|..|; along
    a3 = F x a2 they are (F x E).p/|..|.

    P : (n, 4, 3) -> (n, 24, 3) float, mm (NaN where an edge is parallel to the normal).
    """
    E = P[:, _EDGES[:, 1]] - P[:, _EDGES[:, 0]]
    E /= np.linalg.norm(E, axis=-1, keepdims=True)
    F = np.cross(P[:, _FACES[:, 1]] - P[:, _FACES[:, 0]], P[:, _FACES[:, 2]] - P[:, _FACES[:, 0]])
    F /= np.linalg.norm(F, axis=-1, keepdims=True)
    Pt = np.swapaxes(P, 1, 2)  # (n, 3, 4)
    FP = F @ Pt  # (n, 4f, 4k)
    EP = E @ Pt  # (n, 6e, 4k)
    EF = E @ np.swapaxes(F, 1, 2)  # (n, 6e, 4f)
    norm = np.sqrt(np.maximum(1.0 - EF**2, 0.0))  # |E - (E.F)F|
    good = norm > 1e-9
    inv = np.where(good, 1.0 / np.where(good, norm, 1.0), np.nan)  # (n, e, f)
    # (n, f, e, k)
    a2 = (EP[:, None, :, :] - np.swapaxes(EF, 1, 2)[..., None] * FP[:, :, None, :]) * np.swapaxes(inv, 1, 2)[..., None]
    FxE = np.cross(F[:, :, None, :], E[:, None, :, :])  # (n, f, e, 3)
    a3 = (FxE @ Pt[:, None]) * np.swapaxes(inv, 1, 2)[..., None]
    e1 = np.broadcast_to(_span(FP)[:, :, None], a2.shape[:3])
    ext = np.stack([e1, _span(a2), _span(a3)], axis=-1)
    return ext.reshape(len(P), 24, 3)


def enumerate_candidates(spec: StarSpec, chunk: int = 1 << 19, progress=None) -> Candidates:
    """Every star (up to relabelling and mirroring) whose centres fit ``spec``'s limit.

    Parameters
    ----------
    spec : StarSpec
    chunk : int
        Labelled candidates processed per vectorised batch (memory bound).
    progress : callable or None
        ``progress(done, total)`` called after each batch.
    """
    import time

    t0 = time.perf_counter()
    check_size(spec)
    pool = edge_pool(spec)
    limit = np.array(spec.centre_limit_mm)
    subsets = _subsets(len(pool))
    assign = canonical_assignments()
    n_labelled = len(subsets) * len(assign)
    stats = {"pool_size": len(pool), "subsets": len(subsets), "labelled": n_labelled}
    counts = dict.fromkeys(("realisable", "width_ok", "kyfan_ok", "fit_cov", "fit_face"), 0)
    kf1 = limit[0] ** 2 / 4
    kf2 = (limit[0] ** 2 + limit[1] ** 2) / 4
    out_idx, out_e = [], []
    per_chunk = max(1, chunk // len(assign))
    for s0 in range(0, len(subsets), per_chunk):
        idx = subsets[s0 : s0 + per_chunk][:, assign].reshape(-1, 6)
        L = pool[idx]
        P, ok = _trilaterate(L)
        idx, L, P = idx[ok], L[ok], P[ok]
        counts["realisable"] += len(idx)
        # necessary: width (vertex-face heights and opposite-edge distances)
        vol6 = P[:, 1, 0] * P[:, 2, 1] * P[:, 3, 2]  # 6 * volume
        f = L[:, [[0, 2, 4], [0, 5, 3], [4, 1, 3], [2, 1, 5]]]
        a, b, c = f[..., 0], f[..., 1], f[..., 2]
        area4 = np.sqrt(np.maximum((a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c), 0.0))
        width = (2 * vol6[:, None] / area4).min(axis=1)  # 3V/area = 6V*2/(4*area)
        for e1, e2 in ((0, 1), (2, 3), (4, 5)):
            ea = P[:, 1] - P[:, 0] if e1 == 0 else (P[:, 2] - P[:, 1] if e1 == 2 else P[:, 2] - P[:, 0])
            eb = P[:, 3] - P[:, 2] if e1 == 0 else (P[:, 3] - P[:, 0] if e1 == 2 else P[:, 3] - P[:, 1])
            cr = np.linalg.norm(np.cross(ea, eb), axis=1)
            width = np.minimum(width, vol6 / np.where(cr > 0, cr, np.inf))
        ok = width <= limit[0] + tol.length_mm
        idx, L, P = idx[ok], L[ok], P[ok]
        counts["width_ok"] += len(idx)
        # necessary: Ky Fan on the covariance eigenvalues
        X = P - P.mean(axis=1, keepdims=True)
        C = np.einsum("nki,nkj->nij", X, X) / 4
        ev = sym3_eigvalsh(C)
        ok = (ev[:, 0] <= kf1 + tol.length_mm) & (ev[:, 0] + ev[:, 1] <= kf2 + tol.length_mm)
        idx, P = idx[ok], P[ok]
        _, evec = np.linalg.eigh(C[ok])
        counts["kyfan_ok"] += len(idx)
        # sufficient: the covariance box, then O'Rourke's face-flush boxes
        proj = P @ evec  # (n, 4, 3): coordinates along the eigenvectors
        ext_cov = _span(np.swapaxes(proj, 1, 2))
        fit_cov = _fits(ext_cov, limit)
        counts["fit_cov"] += int(fit_cov.sum())
        best_ext = np.where(fit_cov[:, None], ext_cov, np.nan)
        if spec.box_method == "exact":
            rest = np.flatnonzero(~fit_cov)
            if len(rest):
                ext_f = face_flush_extents(P[rest])
                fit_f = _fits(ext_f, limit) & np.isfinite(ext_f).all(axis=-1)
                vol_f = np.where(fit_f, np.prod(ext_f, axis=-1), np.inf)
                j = vol_f.argmin(axis=1)
                hit = np.isfinite(vol_f[np.arange(len(rest)), j])
                counts["fit_face"] += int(hit.sum())
                best_ext[rest[hit]] = ext_f[np.flatnonzero(hit), j[hit]]
        ok = np.isfinite(best_ext).all(axis=1)
        out_idx.append(idx[ok])
        out_e.append(best_ext[ok])
        if progress is not None:
            progress(min(s0 + per_chunk, len(subsets)) * len(assign), n_labelled)
    index = np.concatenate(out_idx).astype(np.int16)
    ext = np.concatenate(out_e)
    order = np.lexsort(index.T[::-1])  # deterministic: lexicographic on pool indices
    stats.update(counts)
    stats["fitting"] = int(len(index))
    stats["seconds"] = time.perf_counter() - t0
    return Candidates(pool_mm=pool, index=index[order], box_extents=ext[order], stats=stats)
