"""The hand that holds the prop, as occluders that move with it: capsules in the prop frame.

A grip is a segment (the stretch of the gripped part the palm covers, along the axis the
fingers close around) and the part's radius; the hand is one capsule around it, reaching
:data:`FINGERS_M` beyond the part and covering that stretch of its surface
(:func:`hand_capsule`: palm and fingers wrapped round the grip), which hides whatever lies inside it from every camera and covers the surface it
encloses (no marker can be stuck under the hand).  ``--grip`` gives the segment in the prop
frame (metres); without it, a built-in prop has its own grip (:data:`GRIPS`) and a mesh gets
its handle (:func:`graspable_grip`): the longest run, at least 40 mm, of cross-sections a hand
closes around (12-60 mm across along their principal axes: a blade, a plate or a body is
none), the palm (at most a quarter of the prop's length) at the run's end nearer the prop's end.  A mesh without one gets its thinnest
end: of the ends of its bounding box along the axes at least half as long as the
longest (the quarter of the box next to each face), the one whose cross-section (the vertices' farthest distance from the section's centre)
is smallest, the grip running a palm's width (:data:`PALM_M`, at most a quarter of the length)
along that axis.  The forearm is not modelled (its direction depends on how the prop
is held); that is a simplification the README states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError

#: a palm's width along the grip, m (an adult hand is 75-95 mm across the knuckles)
PALM_M = 0.09
#: what the hand adds around the gripped surface, m (fingers, about 20-25 mm thick)
FINGERS_M = 0.025

#: built-in props: grip segment (prop frame, m) and the radius of the gripped part, m
GRIPS = {
    "hammer": ((0.0, 0.0, 0.02), (0.0, 0.0, 0.11), 0.015),
    "racket": ((0.0, 0.0, 0.01), (0.0, 0.0, 0.08), 0.018),
    "sword": ((0.0, 0.0, 0.05), (0.0, 0.0, 0.15), 0.015),
    "bottle": ((0.0, 0.0, 0.07), (0.0, 0.0, 0.15), 0.037),
    "box": ((-0.045, 0.0, -0.02), (0.045, 0.0, -0.02), 0.0),  # carried from below
    "shield": ((-0.045, 0.045, 0.30), (0.045, 0.045, 0.30), 0.0125),
    "umbrella": ((0.0, 0.0, 0.01), (0.0, 0.0, 0.10), 0.014),
}


@dataclass(frozen=True)
class Capsule:
    """All points within ``radius`` of the segment ``a``-``b`` (prop frame, m)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float

    def to_json(self) -> dict:
        return {"a": [round(float(x), 9) + 0.0 for x in self.a], "b": [round(float(x), 9) + 0.0 for x in self.b], "radius": round(float(self.radius), 9)}


def hand_capsule(a, b, part_radius: float, fingers_m: float = FINGERS_M) -> Capsule:
    """The hand around the grip ``a``-``b`` (the stretch of the part the palm covers, m) of a part
    ``part_radius`` thick: a capsule of radius ``part_radius + fingers_m`` whose core is shortened
    so that where it meets the part's surface it covers ``a``-``b`` and no more (a capsule reaches
    ``sqrt(R^2 - r^2)`` past its core's ends at distance ``r`` from the axis)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    R = part_radius + fingers_m
    reach = math.sqrt(max(R * R - part_radius * part_radius, 0.0))
    L = float(np.linalg.norm(b - a))
    u = (b - a) / L if L > 0 else np.zeros(3)
    core = max(0.0, L - 2 * reach)
    mid = (a + b) / 2
    return Capsule(tuple(mid - u * core / 2), tuple(mid + u * core / 2), R)


def capsule_arrays(caps) -> np.ndarray:
    """(k, 7) float: a, b, radius of each capsule (the compiled kernels' input)."""
    if not caps:
        return np.zeros((0, 7))
    return np.array([[*c.a, *c.b, c.radius] for c in caps], dtype=float)


def parse_grip(text: str) -> Capsule:
    """A hand from ``--grip x0,y0,z0,x1,y1,z1[,r]`` (prop frame, m; ``r`` the gripped part's
    radius, default 0.015) or ``none`` handled by the caller."""
    try:
        v = [float(x) for x in str(text).replace(" ", "").split(",")]
    except ValueError:
        v = []
    if len(v) not in (6, 7) or not np.all(np.isfinite(v)):
        raise StarforgeError(f"--grip must be x0,y0,z0,x1,y1,z1[,r] in metres (prop frame), got {text!r}")
    r = v[6] if len(v) == 7 else 0.015
    if not 0 <= r <= 0.5:
        raise StarforgeError(f"--grip radius must be in [0, 0.5] m, got {r}")
    return hand_capsule(v[:3], v[3:6], r)


#: a cross-section a hand closes around: its narrower principal width at least this (m; a blade
#: or a plate is thinner) and its wider one at most :data:`GRASP_MAX_M`
GRASP_MIN_M = 0.012
GRASP_MAX_M = 0.06
#: a handle is at least this long (m) of consecutive such sections
GRASP_RUN_M = 0.04
#: the sections are this far apart along the axis (m), at most :data:`_MAX_SLICES` of them
SLICE_M = 0.004
_MAX_SLICES = 400


def section_widths(mesh, axis: int, heights: np.ndarray) -> np.ndarray:
    """(k, 4) float: per plane ``x[axis] = heights[k]`` the cross-section's two principal widths
    (wider first, m) and its centre in the other two axes (nan where the plane misses the
    mesh).  The section is the points where the mesh's edges cross the plane; its widths are
    its extents along the principal axes of those points (so a turned blade stays thin)."""
    v = np.asarray(mesh.vertices, float)
    e = np.asarray(mesh.edges_unique, int)
    others = [i for i in range(3) if i != axis]
    t0, t1 = v[e[:, 0], axis], v[e[:, 1], axis]
    lo_t, hi_t = np.minimum(t0, t1), np.maximum(t0, t1)
    h = np.asarray(heights, float)
    first = np.searchsorted(h, lo_t, side="left")
    last = np.searchsorted(h, hi_t, side="right")
    n = np.maximum(last - first, 0)
    edge = np.repeat(np.arange(len(e)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(first, n)
    a, b = v[e[edge, 0]], v[e[edge, 1]]
    da = b[:, axis] - a[:, axis]
    f = np.where(np.abs(da) > 1e-15, (h[k] - a[:, axis]) / np.where(np.abs(da) > 1e-15, da, 1.0), 0.5)
    pts = (a + f[:, None] * (b - a))[:, others]
    out = np.full((len(h), 4), np.nan)
    order = np.argsort(k, kind="stable")
    k, pts = k[order], pts[order]
    bounds = np.searchsorted(k, np.arange(len(h) + 1))
    for i in range(len(h)):
        q = pts[bounds[i] : bounds[i + 1]]
        if len(q) < 3:
            continue
        c = q.mean(axis=0)
        _, vecs = np.linalg.eigh(np.cov((q - c).T) + 1e-18 * np.eye(2))
        proj = (q - c) @ vecs
        w = np.sort(proj.max(axis=0) - proj.min(axis=0))[::-1]
        mid = (q.max(axis=0) + q.min(axis=0)) / 2
        out[i] = [w[0], w[1], mid[0], mid[1]]
    return out


def graspable_grip(mesh):
    """The longest handle of the mesh, or None: a run of at least :data:`GRASP_RUN_M` of
    consecutive cross-sections (every :data:`SLICE_M` along each axis at least half as long as
    the longest) that a hand closes around (:data:`GRASP_MIN_M` to :data:`GRASP_MAX_M` across;
    a blade, a plate or a wide body is none).  The grip covers a palm's width of it at the
    run's end nearer the prop's end, or its middle.  Returns ``(a, b, part_radius)``."""
    lo, hi = np.asarray(mesh.bounds, float)
    ext = hi - lo
    best = None
    for ax in np.argsort(-ext, kind="stable").tolist():
        if ext[ax] < 0.5 * ext.max():
            continue
        n = int(min(_MAX_SLICES, max(10, ext[ax] // SLICE_M)))
        step = ext[ax] / n
        h = lo[ax] + (np.arange(n) + 0.5) * step
        w = section_widths(mesh, ax, h)
        ok = (w[:, 1] >= GRASP_MIN_M) & (w[:, 0] <= GRASP_MAX_M)  # nan compares False
        i = 0
        while i < n:
            if not ok[i]:
                i += 1
                continue
            j = i
            while j < n and ok[j]:
                j += 1
            length = (j - i) * step
            if length >= GRASP_RUN_M - 1e-12 and (best is None or length > best[0] + 1e-9):
                best = (length, ax, i, j, h, w, step)
            i = j
    if best is None:
        return None
    length, ax, i, j, h, w, step = best
    others = [k for k in range(3) if k != ax]
    palm = min(PALM_M, length, 0.25 * ext[ax])  # at most a quarter of the prop, as for an end
    run_lo, run_hi = h[i] - step / 2, h[j - 1] + step / 2
    if run_lo - lo[ax] <= hi[ax] - run_hi:  # the run's end nearer the prop's end
        start = run_lo
    else:
        start = run_hi - palm
    under = np.arange(i, j)[(h[i:j] >= start - step) & (h[i:j] <= start + palm + step)]  # the palm's sections
    a = np.zeros(3)
    a[others] = np.nanmean(w[under, 2:], axis=0)
    b = a.copy()
    a[ax], b[ax] = start, start + palm
    return a, b, float(np.nanmax(w[under, 0]) / 2)


def default_grip(mesh, name: str = "", builtin: bool = False) -> Capsule:
    """The hand at a sensible graspable part (see the module docstring)."""
    if builtin and name in GRIPS:
        a, b, r = GRIPS[name]
        return hand_capsule(a, b, r)
    return hand_capsule(*grip_segment(mesh))


#: a prop whose longest side is shorter than this (m) is held by the fingertips, not in a fist
PINCH_BELOW_M = 0.12
#: what fingertips add around the pinched part (m; a fingertip pad is 15-20 mm thick, so the
#: tips of thumb and finger on either side reach about 10 mm past the surface they press on)
FINGERTIP_M = 0.010
#: the stretch of the part the fingertips cover along the grip (m; a fingertip is ~20 mm wide)
PINCH_M = 0.02
#: the rest of the hand beside the pinched end: a capsule this thick (radius, m) and long (m),
#: starting just past the prop's end on the grip's axis
HAND_RADIUS_M = 0.025
HAND_LENGTH_M = 0.08


def default_hand(mesh, name: str = "", builtin: bool = False) -> tuple[Capsule, ...]:
    """The hand as capsules: :func:`default_grip` (a fist round the grip) for a prop at least
    :data:`PINCH_BELOW_M` long or a built-in; a smaller prop is pinched at the same place
    (:func:`pinch`), since a hand cannot close a fist round a part shorter than its palm."""
    lo, hi = np.asarray(mesh.bounds, float)
    if (builtin and name in GRIPS) or float(np.max(hi - lo)) >= PINCH_BELOW_M:
        return (default_grip(mesh, name, builtin),)
    return pinch(mesh, *grip_segment(mesh))


def pinch(mesh, a, b, part_radius: float) -> tuple[Capsule, Capsule]:
    """A small prop held by the fingertips at the grip ``a``-``b`` (the segment a fist would
    cover, along one axis of the bounding box): the fingertips, a capsule :data:`FINGERTIP_M`
    past the part over the :data:`PINCH_M` of the grip nearer the prop's end, and the rest of the
    hand beyond that end (a capsule of :data:`HAND_RADIUS_M` on the grip's axis, just clear of
    the prop: it hides what lies behind it but covers no surface).  A simplification, as the fist
    is: where the fingers run and the palm sits depends on how the prop is held."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    lo, hi = np.asarray(mesh.bounds, float)
    ax = int(np.argmax(np.abs(b - a)))
    s0, s1 = sorted((float(a[ax]), float(b[ax])))
    near_lo = s0 - lo[ax] <= hi[ax] - s1  # the grip's end nearer the prop's end
    tip0, tip1 = a.copy(), a.copy()
    if near_lo:
        tip0[ax], tip1[ax] = s0, min(s1, s0 + PINCH_M)
        h0 = lo[ax] - HAND_RADIUS_M - 0.002
        h1 = h0 - HAND_LENGTH_M
    else:
        tip0[ax], tip1[ax] = max(s0, s1 - PINCH_M), s1
        h0 = hi[ax] + HAND_RADIUS_M + 0.002
        h1 = h0 + HAND_LENGTH_M
    ha, hb = a.copy(), a.copy()
    ha[ax], hb[ax] = h0, h1
    return hand_capsule(tip0, tip1, part_radius, FINGERTIP_M), Capsule(tuple(ha), tuple(hb), HAND_RADIUS_M)


def grip_segment(mesh) -> tuple[np.ndarray, np.ndarray, float]:
    """Where a mesh without a grip of its own is held: its handle (:func:`graspable_grip`) or
    else its thinnest end (see the module docstring).  Returns ``(a, b, part_radius)``, m."""
    handle = graspable_grip(mesh)
    if handle is not None:
        return handle
    lo, hi = np.asarray(mesh.bounds, float)
    ext = hi - lo
    v = np.asarray(mesh.vertices, float)
    best = None
    for ax in np.argsort(-ext, kind="stable").tolist():  # longest axis first (wins ties)
        if ext[ax] < 0.5 * ext.max():
            continue  # a grip runs along a long direction of the prop
        others = [i for i in range(3) if i != ax]
        t = (v[:, ax] - lo[ax]) / max(ext[ax], 1e-12)
        for end, mask in ((0, t <= 0.25), (1, t >= 0.75)):
            if not mask.any():
                continue
            w = v[mask][:, others]
            c = (w.max(0) + w.min(0)) / 2
            r = float(np.linalg.norm(w - c, axis=1).max())
            if best is None or r < best[0] - 1e-9:
                best = (r, ax, end, c)
    r, ax, end, c = best
    others = [i for i in range(3) if i != ax]
    length = min(PALM_M, 0.25 * ext[ax])
    start = lo[ax] + (0.01 if end == 0 else ext[ax] - 0.01 - length)
    a = np.zeros(3)
    a[others] = c
    b = a.copy()
    a[ax], b[ax] = start, start + length
    return a, b, min(r, 0.05)


def inside_capsules(points: np.ndarray, caps) -> np.ndarray:
    """(n,) bool: each point inside some capsule."""
    from starforge.geometry.distance import point_segment_distance

    pts = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(len(pts), bool)
    for c in caps:
        out |= point_segment_distance(pts, c.a, c.b) <= c.radius
    return out
