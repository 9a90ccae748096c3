"""The box reported for each star, and its placement frame."""

from __future__ import annotations

import numpy as np

from starforge.geometry.fit import FIT, decide_fit, fits_limit
from starforge.geometry.obb import covariance_box, min_volume_box, placement_transform


def place_stars(P: np.ndarray, limit, method: str = "exact"):
    """Sphere centres of many stars (n, 4, 3) in the paper's placement frame.

    ``exact``: the minimum-volume box when it fits the limit (``minimum``), else the box of a
    rotation that fits, found by the fit decision (``fitting``); ``covariance``: the paper's box.
    The minimum-volume box's sides are returned in every case.

    Returns a list of (vertices (4, 3), T (4, 4), extents_xyz (3,), method, fits,
    min_box_extents (3,) sorted ascending).
    """
    P = np.asarray(P, dtype=float)
    if not len(P):
        return []
    limit = np.asarray(limit, dtype=float)
    Rm, cm, em = min_volume_box(P)
    if method == "covariance":
        R, c, e = covariance_box(P)
        how = ["covariance"] * len(P)
    else:
        R, c, e = Rm.copy(), cm.copy(), em.copy()
        how = ["minimum"] * len(P)
        bad = np.flatnonzero(~fits_limit(e, limit))
        if len(bad):
            status, Rf, _ = decide_fit(P[bad], limit)
            for k, i in enumerate(bad):
                if status[k] != FIT:
                    continue
                q = P[i] @ Rf[k].T
                lo, hi = q.min(axis=0), q.max(axis=0)
                R[i], c[i], e[i] = Rf[k].T, Rf[k].T @ (0.5 * (lo + hi)), hi - lo
                how[i] = "fitting"
    fits = fits_limit(e, limit)
    out = []
    for i in range(len(P)):
        T, ext_xyz = placement_transform(P[i], R[i], c[i], e[i])
        out.append((P[i] @ T[:3, :3].T + T[:3, 3], T, ext_xyz, how[i], bool(fits[i]), np.sort(em[i])))
    return out
