"""The box reported for each star, and its placement frame."""

from __future__ import annotations

import itertools

import numpy as np

from starforge.geometry.obb import covariance_box, min_volume_box, placement_transform
from starforge.stars.enumerate import face_flush_extents, fits_limit

_FACES = list(itertools.combinations(range(4), 3))
_EDGES = list(itertools.combinations(range(4), 2))


def _face_flush_frame(P: np.ndarray, j: int):
    """Frame j (= face * 6 + edge, the order of ``face_flush_extents``) of one tetrahedron,
    as (R (3, 3) columns, det = +1; center (3,); extents (3,))."""
    f, (a, b) = _FACES[j // 6], _EDGES[j % 6]
    n = np.cross(P[f[1]] - P[f[0]], P[f[2]] - P[f[0]])
    n /= np.linalg.norm(n)
    e = P[b] - P[a]
    a2 = e - np.dot(e, n) * n
    a2 /= np.linalg.norm(a2)
    R = np.stack([n, a2, np.cross(n, a2)], axis=1)
    q = P @ R
    lo, hi = q.min(axis=0), q.max(axis=0)
    return R, R @ (0.5 * (lo + hi)), hi - lo


def place_stars(P: np.ndarray, limit, method: str = "exact"):
    """Sphere centres of many stars (n, 4, 3) in the paper's placement frame.

    ``exact``: the minimum-volume box if it fits the sorted centre ``limit``, else the fitting
    covariance or face-flush box of least volume (labelled ``candidate``); ``covariance``: the
    paper's box.  Boxes are computed in batches.

    Returns a list of (vertices (4, 3), T (4, 4), extents_xyz (3,), method, fits).
    """
    P = np.asarray(P, dtype=float)
    if not len(P):
        return []
    limit = np.asarray(limit, dtype=float)
    if method == "covariance":
        R, c, e = covariance_box(P)
        how = ["covariance"] * len(P)
    else:
        R, c, e = min_volume_box(P)
        how = ["exact"] * len(P)
        bad = np.flatnonzero(~fits_limit(e, limit))
        if len(bad):
            Rc, cc, ec = covariance_box(P[bad])
            ext = face_flush_extents(P[bad])  # (b, 24, 3)
            for k, i in enumerate(bad):
                cands = [(Rc[k], cc[k], ec[k])]
                vols = np.where(fits_limit(ext[k], limit), np.prod(ext[k], axis=1), np.inf)
                if np.isfinite(vols).any():
                    cands.append(_face_flush_frame(P[i], int(vols.argmin())))
                fitting = [b for b in cands if fits_limit(b[2], limit)]
                if fitting:
                    R[i], c[i], e[i] = min(fitting, key=lambda b: float(np.prod(b[2])))
                    how[i] = "candidate"
    fits = fits_limit(e, limit)
    out = []
    for i in range(len(P)):
        T, ext_xyz = placement_transform(P[i], R[i], c[i], e[i])
        out.append((P[i] @ T[:3, :3].T + T[:3, 3], T, ext_xyz, how[i], bool(fits[i])))
    return out
