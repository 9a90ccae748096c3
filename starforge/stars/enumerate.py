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

from starforge.errors import StarforgeError
from starforge.geometry.tetra import canonical_assignments
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


def _realisable(u, U, v, V, w, W):
    """Trilaterate column arrays (mm); returns the mask of realisable rows and D's coordinates.

    Realisable iff the Gram matrix at A is positive definite: triangle ABC valid (cy > 0) and
    Cayley-Menger volume > 0 (dz > 0).  D is computed only where ABC is valid.
    """
    cx = (u * u + w * w - v * v) / (2 * u)
    cy2 = w * w - cx * cx
    ok = cy2 > tol.volume_mm3
    k = np.flatnonzero(ok)
    cx, cy = cx[k], np.sqrt(cy2[k])
    uk, Uk, Vk, Wk, wk = u[k], U[k], V[k], W[k], w[k]
    dx = (uk * uk + Vk * Vk - Wk * Wk) / (2 * uk)
    dy = (Vk * Vk - Uk * Uk + wk * wk - 2 * dx * cx) / (2 * cy)
    dz2 = Vk * Vk - dx * dx - dy * dy
    good = dz2 > tol.volume_mm3
    return k[good], cx[good], cy[good], dx[good], dy[good], np.sqrt(dz2[good])


def _width(L: np.ndarray, vol6: np.ndarray) -> np.ndarray:
    """Tetrahedron width from lengths (n, 6) and 6 x volume: min of vertex-face heights and
    opposite-edge distances (``6V / |e x e'|`` with ``|e x e'|^2 = |e|^2 |e'|^2 - (e.e')^2``)."""
    s = L * L
    d01, d23, d12, d03, d02, d13 = s.T
    width = np.full(len(L), np.inf)
    for a, b, c in ((d01, d12, d02), (d01, d13, d03), (d02, d23, d03), (d12, d23, d13)):
        area4sq = 4 * a * b - (a + b - c) ** 2  # (4 * area)^2 via Heron on squared sides
        width = np.minimum(width, 2 * vol6 / np.sqrt(np.maximum(area4sq, tol.zero)))
    for dd, p1, p2 in (
        (0.5 * (d03 + d12 - d02 - d13), d01, d23),
        (0.5 * (d01 + d23 - d02 - d13), d12, d03),
        (0.5 * (d01 + d23 - d03 - d12), d02, d13),
    ):
        cross2 = p1 * p2 - dd * dd
        width = np.minimum(width, vol6 / np.sqrt(np.maximum(cross2, tol.zero)))
    return width


def _process(subsets: np.ndarray, assign: np.ndarray, pool: np.ndarray, limit: np.ndarray, exact: bool):
    """All stages for one batch of 6-subsets; returns (index (m, 6) int16, extents (m, 3), counts)."""
    counts = dict.fromkeys(("realisable", "width_ok", "kyfan_ok", "fit_cov", "fit_face"), 0)
    # one contiguous column per length; the pool is arithmetic, so lengths are lo + step * k
    cols_idx = [subsets[:, assign[:, j]].ravel() for j in range(6)]
    lo, step = pool[0], (pool[1] - pool[0]) if len(pool) > 1 else 0.0
    cols = [lo + step * c.astype(np.float64) for c in cols_idx]
    k, cx, cy, dx, dy, dz = _realisable(*cols)
    counts["realisable"] = len(k)
    idx = np.stack([c[k] for c in cols_idx], axis=1)
    L = pool[idx]
    n = len(k)
    P = np.zeros((n, 4, 3))
    P[:, 1, 0] = L[:, 0]
    P[:, 2, 0], P[:, 2, 1] = cx, cy
    P[:, 3, 0], P[:, 3, 1], P[:, 3, 2] = dx, dy, dz
    # necessary: the width fits the shortest limit side
    ok = _width(L, L[:, 0] * cy * dz) <= limit[0] + tol.length_mm
    idx, P = idx[ok], P[ok]
    counts["width_ok"] = len(idx)
    # necessary: Ky Fan bounds on the covariance eigenvalues
    X = P - P.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", X, X) / 4
    ev = sym3_eigvalsh(C)
    kf1 = limit[0] ** 2 / 4
    kf2 = (limit[0] ** 2 + limit[1] ** 2) / 4
    ok = (ev[:, 0] <= kf1 + tol.length_mm) & (ev[:, 0] + ev[:, 1] <= kf2 + tol.length_mm)
    idx, P = idx[ok], P[ok]
    _, evec = np.linalg.eigh(C[ok])
    counts["kyfan_ok"] = len(idx)
    # sufficient: the covariance box, then O'Rourke's face-flush boxes
    ext_cov = _span(np.swapaxes(P @ evec, 1, 2))
    fit_cov = fits_limit(ext_cov, limit)
    counts["fit_cov"] = int(fit_cov.sum())
    best_ext = np.where(fit_cov[:, None], ext_cov, np.nan)
    if exact:
        rest = np.flatnonzero(~fit_cov)
        if len(rest):
            ext_f = face_flush_extents(P[rest])
            fit_f = fits_limit(ext_f, limit) & np.isfinite(ext_f).all(axis=-1)
            vol_f = np.where(fit_f, np.prod(ext_f, axis=-1), np.inf)
            j = vol_f.argmin(axis=1)
            hit = np.isfinite(vol_f[np.arange(len(rest)), j])
            counts["fit_face"] = int(hit.sum())
            best_ext[rest[hit]] = ext_f[np.flatnonzero(hit), j[hit]]
    ok = np.isfinite(best_ext).all(axis=1)
    return idx[ok].astype(np.int16), best_ext[ok], counts


def fits_limit(ext, limit) -> np.ndarray:
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


def _worker_init() -> None:
    """Keep large temporaries in the heap inside worker processes (glibc only, else no-op).

    Each batch allocates and frees arrays of tens of MB; with glibc's default mmap threshold
    every one is returned to the kernel and page-faulted in again, which costs about as much as
    the arithmetic.  Raising the thresholds (only in these short-lived workers) halves a batch.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        if libc is not None and hasattr(libc, "mallopt"):
            libc.mallopt(-3, 1 << 30)  # M_MMAP_THRESHOLD
            libc.mallopt(-1, 1 << 30)  # M_TRIM_THRESHOLD
    except OSError:
        pass


def enumerate_candidates(
    spec: StarSpec, chunk: int = 1 << 18, progress=None, workers: int | None = None
) -> Candidates:
    """Every star (up to relabelling and mirroring) whose centres fit ``spec``'s limit.

    Parameters
    ----------
    spec : StarSpec
    chunk : int
        Labelled candidates per vectorised batch (bounds memory, ~100 MB).
    progress : callable or None
        ``progress(done, total)`` after each batch.
    workers : int or None
        Processes for large pools (default: every core); small pools run in-process.  The
        result does not depend on it.
    """
    import os
    import time

    t0 = time.perf_counter()
    check_size(spec)
    pool = edge_pool(spec)
    limit = np.array(spec.centre_limit_mm)
    subsets = _subsets(len(pool))
    assign = canonical_assignments()
    n_labelled = len(subsets) * len(assign)
    per_chunk = max(1, chunk // len(assign))
    batches = [subsets[s0 : s0 + per_chunk] for s0 in range(0, len(subsets), per_chunk)]
    exact = spec.box_method == "exact"
    workers = (os.cpu_count() or 1) if workers is None else max(1, workers)
    results = []
    done = 0
    if workers > 1 and len(batches) > 2:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        ctx = mp.get_context("forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn")
        if ctx.get_start_method() == "forkserver":
            ctx.set_forkserver_preload([__name__])  # workers fork with numpy and this module loaded
        with ProcessPoolExecutor(
            max_workers=min(workers, len(batches)), mp_context=ctx, initializer=_worker_init
        ) as ex:
            # later subsets hold the longer, costlier edges: submit those first so both workers
            # stay busy to the end (the result is sorted afterwards, so order does not matter)
            futures = [ex.submit(_process, b, assign, pool, limit, exact) for b in batches[::-1]]
            for b, fut in zip(batches[::-1], futures, strict=True):
                results.append(fut.result())
                done += len(b)
                if progress is not None:
                    progress(done * len(assign), n_labelled)
    else:
        for b in batches:
            results.append(_process(b, assign, pool, limit, exact))
            done += len(b)
            if progress is not None:
                progress(done * len(assign), n_labelled)
    stats = {"pool_size": len(pool), "subsets": len(subsets), "labelled": n_labelled}
    for key in results[0][2]:
        stats[key] = sum(r[2][key] for r in results)
    index = np.concatenate([r[0] for r in results])
    ext = np.concatenate([r[1] for r in results])
    order = np.lexsort(index.T[::-1])  # deterministic: lexicographic on pool indices
    stats["fitting"] = int(len(index))
    stats["seconds"] = time.perf_counter() - t0
    return Candidates(pool_mm=pool, index=index[order], box_extents=ext[order], stats=stats)
