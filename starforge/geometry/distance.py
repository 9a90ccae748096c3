"""Distances between points, segments, rays and spheres, and equal-area hemisphere directions.

Pure numpy; lengths in whatever unit the inputs use (mm for bodies, m for props).
"""

from __future__ import annotations

import numpy as np

from starforge.geometry.frames import perpendicular_basis
from starforge.tol import tol


def point_segment_distance(points, a, b) -> np.ndarray:
    """Distance from each point to the segment ``a``-``b``.

    Parameters
    ----------
    points : (n, 3) float, mm
    a, b : (3,) float, mm

    Returns
    -------
    (n,) float, mm
    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ab = b - a
    den = float(ab @ ab)
    t = np.zeros(len(p)) if den == 0 else np.clip((p - a) @ ab / den, 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def segment_segment_distance(a0, a1, b0, b1, samples: int = 0) -> float:
    """Shortest distance between segments ``a0``-``a1`` and ``b0``-``b1`` (mm).

    Exact (clamped closest points, with the end-point cases), no sampling.
    """
    a0, a1, b0, b1 = (np.asarray(v, dtype=float) for v in (a0, a1, b0, b1))
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    den = a * e - b * b
    cands = []
    if den > tol.zero:
        s = np.clip((b * f - c * e) / den, 0.0, 1.0)
        t = np.clip((b * s + f) / e, 0.0, 1.0)
        s = np.clip((b * t - c) / a, 0.0, 1.0)
        cands.append(np.linalg.norm(a0 + s * d1 - (b0 + t * d2)))
    cands.append(point_segment_distance([a0, a1], b0, b1).min())
    cands.append(point_segment_distance([b0, b1], a0, a1).min())
    return float(min(cands))


def point_segments_distance(point, a, b) -> np.ndarray:
    """(n,) distance from one ``point`` (3,) to each segment ``a[i]``-``b[i]`` (n, 3)."""
    a, b = np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))
    d, r = b - a, np.asarray(point, dtype=float) - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", r, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(r - t[:, None] * d, axis=1)


def ray_hits_spheres(origins, dirs, centres, radii) -> np.ndarray:
    """Whether each ray ``origins[i] + t dirs[i]`` (t > 0) enters any sphere.

    Parameters
    ----------
    origins, dirs : (n, 3) float (dirs unit length)
    centres : (m, 3) float, mm ; radii : (m,) float, mm

    Returns
    -------
    (n,) bool
    """
    o, d = np.atleast_2d(origins), np.atleast_2d(dirs)
    hit = np.zeros(len(o), dtype=bool)
    for c, r in zip(np.atleast_2d(centres), np.atleast_1d(radii), strict=True):
        oc = c - o
        t = np.einsum("ij,ij->i", oc, d)
        dist2 = np.einsum("ij,ij->i", oc, oc) - t**2
        # the far intersection is ahead of the origin
        hit |= (dist2 < r * r) & (t + np.sqrt(np.clip(r * r - dist2, 0.0, None)) > 0)
    return hit


def ray_segment_distance(origins, dirs, a, b) -> np.ndarray:
    """Exact smallest distance from each ray (t >= 0) to each segment, mm.

    Parameters
    ----------
    origins, dirs : (n, 3) float (dirs unit length)
    a, b : (k, 3) or (3,) float, segment ends

    Returns
    -------
    (n, k) float, or (n,) for one segment.  Closest points of the ray and the segment (the
    clamped two-step solve of Ericson, *Real-Time Collision Detection* 5.1.9, with the ray's
    parameter clamped below only).
    """
    o, d = np.atleast_2d(origins)[:, None, :], np.atleast_2d(dirs)[:, None, :]
    one = np.ndim(a) == 1
    A, B = np.atleast_2d(a)[None], np.atleast_2d(b)[None]
    e = B - A  # (1, k, 3)
    r = o - A  # (n, k, 3)
    dd = np.einsum("nkj,nkj->nk", d, d)
    ee = np.einsum("nkj,nkj->nk", e, e)
    de = np.einsum("nkj,nkj->nk", d, e)
    dr = np.einsum("nkj,nkj->nk", d, r)
    er = np.einsum("nkj,nkj->nk", e, r)
    den = dd * ee - de * de
    safe_ee = np.where(ee > 0, ee, 1.0)
    # segment parameter from the unclamped solve (parallel: the segment's start)
    s = np.where(den > tol.zero, (de * (-dr) - (-er) * dd) / np.where(den > tol.zero, den, 1.0), 0.0)
    s = np.clip(np.where(ee > 0, s, 0.0), 0.0, 1.0)
    t = np.maximum((de * s - dr) / dd, 0.0)  # the ray's closest parameter to that segment point
    s = np.where(ee > 0, np.clip((de * t + er) / safe_ee, 0.0, 1.0), 0.0)
    p_ray = o + t[..., None] * d
    p_seg = A + s[..., None] * e
    dist = np.linalg.norm(p_ray - p_seg, axis=2)
    return dist[:, 0] if one else dist


def in_band(points, a, b, radius: float) -> np.ndarray:
    """(n,) bool: each point inside the band round the segment ``a``-``b`` (a finite cylinder of
    ``radius`` whose flat ends are the planes square to the segment through ``a`` and ``b``)."""
    p = np.atleast_2d(np.asarray(points, dtype=float))
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    L = float(np.linalg.norm(b - a))
    u = (b - a) / L if L > 0 else np.zeros(3)
    r = p - a
    t = r @ u
    radial = r - t[:, None] * u
    return (t >= 0.0) & (t <= L) & (np.einsum("ij,ij->i", radial, radial) <= radius * radius)


def ray_enters_band(origins, dirs, a, b, radius: float, length=np.inf) -> np.ndarray:
    """(n,) bool: each ray ``origins[i] + s dirs[i]``, ``0 <= s <= length``, has a point inside
    the band of :func:`in_band`.

    Exact: the ray's stretch between the band's end planes (where its axial coordinate is in
    ``[0, |b - a|]``) is an interval of ``s``, and on it the squared distance from the axis is a
    convex quadratic in ``s``, least at its vertex clamped to the interval.
    """
    o = np.atleast_2d(np.asarray(origins, dtype=float))
    d = np.atleast_2d(np.asarray(dirs, dtype=float))
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    L = float(np.linalg.norm(b - a))
    u = (b - a) / L if L > 0 else np.zeros(3)
    r0 = o - a
    t0, du = r0 @ u, d @ u
    flat = np.abs(du) <= tol.zero
    safe = np.where(flat, 1.0, du)
    s_a, s_b = -t0 / safe, (L - t0) / safe
    lo = np.where(flat, np.where((t0 >= 0.0) & (t0 <= L), 0.0, np.inf), np.maximum(np.minimum(s_a, s_b), 0.0))
    hi = np.where(flat, length, np.minimum(np.maximum(s_a, s_b), length))
    w0 = r0 - t0[:, None] * u
    wd = d - du[:, None] * u
    ww = np.einsum("ij,ij->i", wd, wd)
    s = np.where(ww > tol.zero, -np.einsum("ij,ij->i", w0, wd) / np.where(ww > tol.zero, ww, 1.0), 0.0)
    s = np.clip(s, lo, np.maximum(lo, hi))
    s = np.where(np.isfinite(s), s, 0.0)
    w = w0 + s[:, None] * wd
    return (lo <= hi) & (np.einsum("ij,ij->i", w, w) <= radius * radius)


def hemisphere_directions(n: int, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """``n`` near-uniform unit directions on the hemisphere around ``up`` (Fibonacci lattice).

    Equal-area: each direction stands for the same solid angle, so a count of blocked
    directions is a fraction of the hemisphere's solid angle.  Returns (n, 3) float.
    """
    i = np.arange(n) + 0.5
    cos_t = 1.0 - i / n  # uniform in cos(theta) on [0, 1): equal area
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    local = np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])  # around +z
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1, e2 = perpendicular_basis(up)
    return local[:, :1] * e1 + local[:, 1:2] * e2 + local[:, 2:3] * up
