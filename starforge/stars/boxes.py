"""The box reported for one star, and its placement frame."""

from __future__ import annotations

import itertools

import numpy as np

from starforge.geometry.obb import covariance_box, min_volume_box, placement_transform
from starforge.tol import tol


def _fits(ext, limit) -> bool:
    return bool((np.sort(ext) <= np.asarray(limit) * (1 + tol.box_rel) + tol.length_mm).all())


def _face_flush_frames(P: np.ndarray):
    """All 24 face-flush frames of one tetrahedron as (R columns, center, extents)."""
    out = []
    for f in itertools.combinations(range(4), 3):
        n = np.cross(P[f[1]] - P[f[0]], P[f[2]] - P[f[0]])
        n /= np.linalg.norm(n)
        for a, b in itertools.combinations(range(4), 2):
            e = P[b] - P[a]
            a2 = e - np.dot(e, n) * n
            if np.linalg.norm(a2) < 1e-9:
                continue
            a2 /= np.linalg.norm(a2)
            R = np.stack([n, a2, np.cross(n, a2)], axis=1)
            q = P @ R
            lo, hi = q.min(axis=0), q.max(axis=0)
            out.append((R, R @ (0.5 * (lo + hi)), hi - lo))
    return out


def star_box(P: np.ndarray, limit, method: str = "exact", mvb=None):
    """The box to report for sphere centres P (4, 3) against the sorted centre limit.

    ``exact``: the minimum-volume box if it fits, else the smallest fitting candidate box
    (covariance or face-flush), labelled ``candidate``; ``covariance``: the paper's box.

    Returns (R (3, 3) columns, center (3,), extents (3,), method str, fits bool).
    """
    if method == "covariance":
        R, c, e = covariance_box(P)
        return R, c, e, "covariance", _fits(e, limit)
    R, c, e = min_volume_box(P) if mvb is None else mvb
    if _fits(e, limit):
        return R, c, e, "exact", True
    cands = [covariance_box(P), *_face_flush_frames(P)]
    fitting = [b for b in cands if _fits(b[2], limit)]
    if not fitting:
        return R, c, e, "exact", False
    R, c, e = min(fitting, key=lambda b: float(np.prod(b[2])))
    if np.linalg.det(R) < 0:
        R = R.copy()
        R[:, 2] *= -1
    return R, c, e, "candidate", True


def _face_flush_frame(P: np.ndarray, j: int):
    """Frame j (= face * 6 + edge, the order of ``face_flush_extents``) of one tetrahedron."""
    faces = list(itertools.combinations(range(4), 3))
    edges = list(itertools.combinations(range(4), 2))
    f, (a, b) = faces[j // 6], edges[j % 6]
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
    """:func:`place_star` for many stars (n, 4, 3), batched: the exact boxes in one call, and for
    stars whose exact box does not fit, the fitting covariance / face-flush box of least volume."""
    if method != "exact" or not len(P):
        return [place_star(p, limit, method) for p in P]
    from starforge.stars.enumerate import face_flush_extents

    R, c, e = min_volume_box(P)
    bad = [i for i in range(len(P)) if not _fits(e[i], limit)]
    fallback = {}
    if bad:
        ext = face_flush_extents(P[bad])  # (b, 24, 3)
        for k, i in enumerate(bad):
            cands = [covariance_box(P[i])]
            vols = np.where([_fits(x, limit) for x in ext[k]], np.prod(ext[k], axis=1), np.inf)
            if np.isfinite(vols).any():
                cands.append(_face_flush_frame(P[i], int(np.nanargmin(vols))))
            fitting = [b for b in cands if _fits(b[2], limit)]
            if fitting:
                Rb, cb, eb = min(fitting, key=lambda b: float(np.prod(b[2])))
                if np.linalg.det(Rb) < 0:
                    Rb = Rb.copy()
                    Rb[:, 2] *= -1
                fallback[i] = (Rb, cb, eb)
    out = []
    for i in range(len(P)):
        if i in fallback or not _fits(e[i], limit):
            if i not in fallback:
                out.append((P[i], np.eye(4), e[i], "exact", False))
                continue
            Rb, cb, eb = fallback[i]
            how = "candidate"
        else:
            Rb, cb, eb, how = R[i], c[i], e[i], "exact"
        T, ext_xyz = placement_transform(P[i], Rb, cb, eb)
        out.append((P[i] @ T[:3, :3].T + T[:3, 3], T, ext_xyz, how, True))
    return out


def place_star(P: np.ndarray, limit, method: str = "exact", mvb=None):
    """Sphere centres in the paper's placement frame.

    Returns (vertices (4, 3), T (4, 4), extents_xyz (3,), method, fits).
    """
    R, c, e, how, fits = star_box(P, limit, method, mvb)
    T, ext_xyz = placement_transform(P, R, c, e)
    V = P @ T[:3, :3].T + T[:3, 3]
    return V, T, ext_xyz, how, fits
