"""Symmetry of a marker set (metres).

* :func:`is_symmetric` -- the paper's test (section 3.2.2): is there a k-fold rotational
  symmetry about an axis parallel to x, y or z through the set's centroid?  Every order
  ``j = 2..k`` is tried (rotation by 360/j degrees), so a square (4-fold), a regular triangle
  (3-fold) or a pentagon is caught with k = 8.  Points match when a rotated point lies within
  ``tol_m`` of an original point and the matching is one-to-one (a distance tolerance, not the
  string equality of rounded coordinates the paper used).  A set lying on the axis (within
  ``tol_m``) is symmetric about it.
* :func:`near_symmetry_margin` -- a continuous version: the smallest RMS residual (m) of any
  non-identity rigid self-match (proper rotation + translation mapping the set onto a
  permutation of itself).  0 for an exactly symmetric set; large for a distinctive one.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.geometry.rigid import kabsch

_AXES = np.eye(3)


def _rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _matches(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """True when the point sets a and b (same size) match one-to-one within tol."""
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    close = d <= tol
    if not close.any(axis=1).all() or not close.any(axis=0).all():
        return False
    from scipy.optimize import linear_sum_assignment

    r, c = linear_sum_assignment(d)
    return bool(np.all(d[r, c] <= tol))


def quick_reject(points: np.ndarray, tol: float) -> bool:
    """Cheap exact test: True when no rotation about any axis through the centroid can be a symmetry.

    A rotation about an axis through the centroid keeps each point's distance to the centroid,
    and moves every point farther than ``tol`` from the axis onto another point.  So if some
    point is off all three axes and no other point has (within 2 tol) the same distance to the
    centroid, no symmetry exists.  Random sets almost always fail this at once.
    """
    p = np.asarray(points, dtype=float)
    return quick_reject_xyz(p[:, 0].tolist(), p[:, 1].tolist(), p[:, 2].tolist(), tol)


def quick_reject_xyz(xs: list, ys: list, zs: list, tol: float) -> bool:
    """:func:`quick_reject` on coordinate lists, in plain Python (fast for the chain's n <= 20)."""
    n = len(xs)
    cx, cy, cz = sum(xs) / n, sum(ys) / n, sum(zs) / n
    r = [math.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) for x, y, z in zip(xs, ys, zs, strict=True)]
    t2, tt = 2.0 * tol, tol * tol
    for i in range(n):
        ri = r[i]
        paired = False
        for j in range(n):
            if j != i and abs(r[j] - ri) <= t2:
                paired = True
                break
        if not paired:
            dx, dy, dz = (xs[i] - cx) ** 2, (ys[i] - cy) ** 2, (zs[i] - cz) ** 2
            if dy + dz > tt and dx + dz > tt and dx + dy > tt:
                return True
    return False


def is_symmetric(points: np.ndarray, k: int = 8, tol_m: float = 0.002) -> bool:
    """The paper's SMC(M): k-fold rotational symmetry about x, y or z through the centroid.

    Parameters
    ----------
    points : (n, 3) float, m
    k : int
        Largest rotation order tried (Table 1: 8); orders 2..k are tested.
    tol_m : float
        Matching tolerance, m.
    """
    p = np.asarray(points, dtype=float)
    if len(p) < 2:
        return False
    if quick_reject(p, tol_m):
        return False
    q = p - p.mean(axis=0)
    for axis in range(3):
        radial = np.delete(q, axis, axis=1)
        if np.all((radial * radial).sum(axis=1) <= tol_m * tol_m):
            return True  # all on this axis: every rotation about it maps the set onto itself
        for order in range(2, k + 1):
            R = _rotation(axis, 2 * math.pi / order)
            if _matches(q @ R.T, q, tol_m):
                return True
    return False


def near_symmetry_margin(points: np.ndarray, refine: int = 24, cap: float = math.inf) -> float:
    """Smallest RMS residual (m) of a non-identity rigid self-match of the point set.

    Candidate motions map an anchor triple (a wide triangle of the set) onto every other
    ordered triple of points (batched Kabsch, proper rotations only).  A triple whose side
    lengths differ from the anchor's by ``e`` cannot give a residual below ``e / sqrt(2 n)``
    (exact bound), so triples with a bound >= ``cap`` are skipped and ``cap`` is returned when
    none is left.  The rest are scored by the RMS distance of the moved points to their nearest
    points; those whose nearest-point matching is not the identity are ranked first, and
    candidates are refined (until ``refine`` of them end in a non-identity matching) by alternating an optimal one-to-one assignment (Hungarian) with Kabsch on
    all points, and the smallest residual of a non-identity assignment is returned (at most
    ``cap``).  It is a search: an upper bound on the true margin, exact (0) for exactly
    symmetric sets.  Returns ``inf`` (or ``cap``) for fewer than 3 points.
    """
    from scipy.optimize import linear_sum_assignment

    p = np.asarray(points, dtype=float)
    n = len(p)
    if n < 3:
        return cap
    D = np.linalg.norm(p[:, None] - p[None], axis=2)
    i0 = int(np.argmax(D.sum(axis=1)))
    j0 = int(np.argmax(D[i0]))
    cross = np.linalg.norm(np.cross(p - p[i0], p[j0] - p[i0]), axis=1)
    cross[[i0, j0]] = -1.0
    k0 = int(np.argmax(cross))
    idx = np.arange(n)
    A, B, C = (g.ravel() for g in np.meshgrid(idx, idx, idx, indexing="ij"))
    ok = (A != B) & (B != C) & (A != C) & ~((A == i0) & (B == j0) & (C == k0))
    A, B, C = A[ok], B[ok], C[ok]
    bound = np.max(np.abs([D[A, B] - D[i0, j0], D[B, C] - D[j0, k0], D[A, C] - D[i0, k0]]), axis=0)
    keep = bound / math.sqrt(2 * n) < cap
    if not keep.any():
        return cap
    A, B, C = A[keep], B[keep], C[keep]
    src = np.broadcast_to(p[[i0, j0, k0]], (len(A), 3, 3))
    dst = np.stack([p[A], p[B], p[C]], axis=1)
    R, t = kabsch(src, dst)
    moved = np.einsum("mij,nj->mni", R, p) + t[:, None]
    d2 = ((moved[:, :, None, :] - p[None, None]) ** 2).sum(axis=3)  # (m, n, n)
    nearest = d2.argmin(axis=2)
    nn = d2.min(axis=2).mean(axis=1)
    not_identity = np.any(nearest != idx, axis=1)
    order = np.argsort(nn, kind="stable")
    order = np.concatenate([order[not_identity[order]], order[~not_identity[order]]])
    best = cap
    found = 0
    for m in order[: 10 * refine]:
        if found >= refine:
            break
        Rm, tm = R[m], t[m]
        perm = idx
        for _ in range(4):
            cost = ((p @ Rm.T + tm)[:, None] - p[None]) ** 2
            _, perm = linear_sum_assignment(cost.sum(axis=2))
            if np.array_equal(perm, idx):
                break
            Rm, tm = (x[0] for x in kabsch(p[None], p[perm][None]))
        if np.array_equal(perm, idx):
            continue
        rms = math.sqrt(float(((p @ Rm.T + tm - p[perm]) ** 2).sum(axis=1).mean()))
        best = min(best, rms)
        found += 1
    return best
