"""How close markers may be, and whether any layout on a set of sites can be tracked at all.

Two markers closer than :func:`spacing_m` merge in some camera image; :func:`spaced_capacity`
and :func:`spaced_triple` count how many sites keep that spacing, and :func:`line_reach` bounds
how far sites lie from one line (a layout on one line gives no orientation).  Lengths in m.
"""

from __future__ import annotations

import math

import numpy as np


def spacing_m(marker_mm: float, rig, gap_px: float) -> float:
    """Least centre distance of two markers, m: one diameter plus ``gap_px`` pixels at the farthest
    camera-to-volume distance of the rig (so two markers stay apart in every camera image)."""
    corners = np.array(
        [[c + s * (i - 0.5) for c, s, i in zip(rig.volume.center, rig.volume.size, idx, strict=True)]
         for idx in np.ndindex(2, 2, 2)]
    )
    worst = 0.0
    for cam in rig.cameras:
        d = float(np.linalg.norm(corners - np.asarray(cam.position), axis=1).max())
        pixel = math.radians(cam.fov_deg) / cam.resolution[0]
        worst = max(worst, d * pixel)
    return marker_mm / 1000.0 + gap_px * worst


def spaced_capacity(points: np.ndarray, spacing: float, enough: int) -> int:
    """How many of ``points`` (m) can be taken at least ``spacing`` apart, up to ``enough``: a
    farthest-point traversal from the first point (each step takes the point farthest from those
    taken) until the farthest is closer than ``spacing``; when that stops short of ``enough``, also
    a greedy that takes the point with the fewest untaken neighbours closer than ``spacing`` (it
    packs a narrow strip the traversal leaves gaps in), and the larger count.  A lower bound on
    the largest such set (finding that is NP-hard), exact in the common case where it reaches
    ``enough``."""
    pts = np.asarray(points, float)
    if not len(pts):
        return 0
    d = np.linalg.norm(pts - pts[0], axis=1)
    taken = 1
    while taken < enough:
        k = int(np.argmax(d))
        if d[k] < spacing:
            break
        taken += 1
        d = np.minimum(d, np.linalg.norm(pts - pts[k], axis=1))
    if taken >= enough or len(pts) > 5000:
        return taken
    near = np.linalg.norm(pts[:, None] - pts[None], axis=2) < spacing  # the diagonal included
    free = np.ones(len(pts), dtype=bool)
    packed = 0
    while free.any() and packed < enough:
        deg = near[:, free].sum(axis=1)
        k = int(np.flatnonzero(free)[np.argmin(deg[free])])
        free &= ~near[k]
        packed += 1
    return max(taken, packed)


def line_reach(points: np.ndarray, refine_below: float = math.inf) -> float:
    """An upper bound (m) on how far ``points`` lie from some line: the largest distance of a
    point from a line, for the best of a few lines (along the principal axis through the centroid
    and through the middle of the extent across it, then that line's direction and offset refined
    by a Nelder-Mead search for the least largest distance).  Any subset's RMS distance from its
    own best-fit line is at most its RMS distance from any line, so at most this: when it is below
    the tracked test's spread, no subset of the points can be tracked.  Every line tried gives a
    valid bound; the search only makes it tighter (a search, not the exact minimax line), and
    runs only when the first bound is below ``refine_below`` (a caller that needs the bound only
    against a threshold skips it where the threshold is far)."""
    pts = np.asarray(points, float)
    if len(pts) < 2:
        return 0.0
    centroid = pts.mean(axis=0)
    c = pts - centroid
    axes = np.linalg.svd(c, full_matrices=False)[2]
    if len(axes) < 3:  # two points: a line through both
        return 0.0
    across = c @ axes[1:].T  # (n, 2) across the principal axis
    mid = (across.max(axis=0) + across.min(axis=0)) / 2
    starts = [np.zeros(2), mid]
    best = min(float(np.linalg.norm(across - o, axis=1).max()) for o in starts)
    if best >= refine_below:
        return best

    def reach(x):  # the line through centroid + o (across) along the axis tilted by (a, b)
        d = axes[0] + x[0] * axes[1] + x[1] * axes[2]
        d = d / np.linalg.norm(d)
        q = c - (x[2] * axes[1] + x[3] * axes[2])
        return float(np.linalg.norm(q - np.outer(q @ d, d), axis=1).max())

    from scipy.optimize import minimize

    scale = float(np.abs(across).max()) or 1.0
    for o in starts:
        r = minimize(reach, np.array([0.0, 0.0, o[0], o[1]]), method="Nelder-Mead",
                     options={"initial_simplex": np.array([[0, 0, o[0], o[1]], [0.05, 0, o[0], o[1]], [0, 0.05, o[0], o[1]],
                                                           [0, 0, o[0] + 0.2 * scale, o[1]], [0, 0, o[0], o[1] + 0.2 * scale]]),
                              "xatol": 1e-7, "fatol": 1e-7, "maxiter": 800})  # fmt: skip
        best = min(best, reach(r.x))  # re-evaluated: the bound is the distance from that very line
    return best


def spaced_triple(points: np.ndarray, spacing: float) -> bool:
    """Whether three of ``points`` lie pairwise at least ``spacing`` apart (exact: a pair far
    apart and a point far from both, counted by a boolean matrix product)."""
    pts = np.asarray(points, float)
    if len(pts) < 3:
        return False
    far = (np.linalg.norm(pts[:, None] - pts[None], axis=2) >= spacing).astype(np.float32)
    return bool(((far @ far) * far).max() > 0.5)
