"""The hand that holds the prop, as occluders that move with it, in the prop frame.

A fist is a segment (the stretch of the gripped part the palm covers, along the axis the
fingers close around) and the part's radius; the hand is a band around it (:func:`fist`: a
finite cylinder :data:`FINGERS_M` thicker than the part, cut square at the palm's edges, the
palm and fingers wrapped round the grip), which hides whatever lies inside it from every camera
and covers the surface it encloses (no marker can be stuck under the hand).  A band and not a
capsule: round a part as wide as a bottle or a carton, a capsule that covers the palm's stretch
of the surface swells into a ball reaching far past the palm's edges.  The wrist and forearm are
capsules.  Where on a prop people hold it, by which hand and how, is
:mod:`starforge.props.grips`; this module holds the pieces: the fist, the cross-sections a
hand closes around (:func:`section_widths`), the fingertips of a pinch (:func:`pinch`) and the
thinnest end of a prop without a graspable part (:func:`grip_segment`): of the ends of its
bounding box along the axes at least half as long as the longest (the quarter of the box next
to each face), the one whose cross-section (the vertices' farthest distance from the section's
centre) is smallest, the grip running a palm's width (:data:`PALM_M`, at most a quarter of the
length) along that axis.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.distance import (
    in_band,
    point_segment_distance,
    point_segments_distance,
    ray_enters_band,
    ray_segment_distance,
)

#: a palm's width along the grip, m (an adult hand is 75-95 mm across the knuckles)
PALM_M = 0.09
#: the prop is cut into sections this far apart (m) to find where a hand closes round it
#: (:mod:`starforge.props.grips`) and a handle's opening (:mod:`starforge.props.handle`)
SLICE_M = 0.004
#: what the hand adds around the gripped surface, m (fingers, about 20-25 mm thick)
FINGERS_M = 0.025

#: built-in props whose shape shows no graspable part (:func:`starforge.props.grips.held_part`): where
#: they are held, a segment (prop frame, m) and the radius of the gripped part, m
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
    """All points within ``radius`` of the segment ``a``-``b`` (prop frame, m); when ``flat``,
    only those between the planes square to the segment through ``a`` and ``b`` (a band: a
    finite cylinder, :func:`starforge.geometry.distance.in_band`)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float
    flat: bool = False

    def to_json(self) -> dict:
        out = {"a": [round(float(x), 9) + 0.0 for x in self.a], "b": [round(float(x), 9) + 0.0 for x in self.b], "radius": round(float(self.radius), 9)}
        return {**out, "flat": True} if self.flat else out

    def contains(self, points) -> np.ndarray:
        """(n,) bool: each point (n, 3) inside."""
        pts = np.asarray(points, float).reshape(-1, 3)
        if self.flat:
            return in_band(pts, self.a, self.b, self.radius)
        return point_segment_distance(pts, self.a, self.b) <= self.radius

    def meets(self, origins, dirs) -> np.ndarray:
        """(n,) bool: each ray ``origins[i] + t dirs[i]`` (t >= 0, unit ``dirs``) has a point inside."""
        if self.flat:
            return ray_enters_band(origins, dirs, self.a, self.b, self.radius)
        return ray_segment_distance(origins, dirs, np.asarray(self.a), np.asarray(self.b)) <= self.radius

    def meets_segments(self, starts, ends) -> np.ndarray:
        """(n,) bool: each segment ``starts[i]``-``ends[i]`` (n, 3) has a point inside.  Exact: a
        segment is a ray cut at its length, and a capsule is its band with a ball at each end."""
        p, q = np.asarray(starts, float).reshape(-1, 3), np.asarray(ends, float).reshape(-1, 3)
        length = np.linalg.norm(q - p, axis=1)
        dirs = (q - p) / np.where(length > 0, length, 1.0)[:, None]
        hit = ray_enters_band(p, dirs, self.a, self.b, self.radius, length)
        if not self.flat:
            hit |= (point_segments_distance(self.a, p, q) <= self.radius) | (point_segments_distance(self.b, p, q) <= self.radius)
        return hit


def fist(a, b, part_radius: float, fingers_m: float = FINGERS_M) -> Capsule:
    """The hand around the grip ``a``-``b`` (the stretch of the part the palm covers, m) of a part
    ``part_radius`` thick: a band of radius ``part_radius + fingers_m`` from ``a`` to ``b``."""
    return Capsule(tuple(float(x) for x in a), tuple(float(x) for x in b), part_radius + fingers_m, True)


#: columns of :func:`capsule_arrays`: a (3), b (3), radius, flat (1.0 for a band)
CAPSULE_COLUMNS = 8


def capsule_arrays(caps) -> np.ndarray:
    """(k, 8) float: a, b, radius and flat (1.0 or 0.0) of each capsule (the compiled kernels' input)."""
    if not caps:
        return np.zeros((0, CAPSULE_COLUMNS))
    return np.array([[*c.a, *c.b, c.radius, float(c.flat)] for c in caps], dtype=float)


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
    return fist(v[:3], v[3:6], r)


def section_widths(mesh, axis: int, heights: np.ndarray) -> np.ndarray:
    """(k, 4) float: per plane ``x[axis] = heights[k]`` the cross-section's two principal widths
    (wider first, m) and its centre in the other two axes (nan where the plane misses the
    mesh).  The section is the points where the mesh's edges cross the plane; its widths are
    its extents along the principal axes of those points (so a turned blade stays thin)."""
    return section_widths_of(np.asarray(mesh.vertices, float), np.asarray(mesh.edges_unique, int), axis, heights)


def section_widths_of(v: np.ndarray, e: np.ndarray, axis: int, heights: np.ndarray) -> np.ndarray:
    """:func:`section_widths` of the mesh with vertices ``v`` (n, 3) and unique edges ``e`` (k, 2)."""
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


def pinch(mesh, a, b, part_radius: float) -> tuple[Capsule, Capsule]:
    """A small prop held by the fingertips at the grip ``a``-``b`` (the segment a fist would
    cover, along one axis of the bounding box): the fingertips, a band :data:`FINGERTIP_M`
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
    return fist(tip0, tip1, part_radius, FINGERTIP_M), Capsule(tuple(ha), tuple(hb), HAND_RADIUS_M)


def grip_segment(mesh) -> tuple[np.ndarray, np.ndarray, float]:
    """Where a mesh without a graspable part is held: its thinnest end (see the module
    docstring).  Returns ``(a, b, part_radius)``, m."""
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


def posts_in_hands(bases: np.ndarray, tops: np.ndarray, occluders: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(n, g) bool: the post from ``bases[i]`` to ``tops[i]`` (n, 3) passes through a capsule (or
    band) of grip g: rows ``starts[g]:starts[g + 1]`` of ``occluders`` (:func:`capsule_arrays`).

    A hand cannot close round a post: where the grip's hand would hold a stand-off marker's post,
    the marker is taken as hidden at that grip (the hand covers it, or holds the prop elsewhere).
    Exact (:meth:`Capsule.meets_segments`), in time and memory linear in posts x capsules."""
    a, b = np.asarray(bases, float).reshape(-1, 3), np.asarray(tops, float).reshape(-1, 3)
    G = len(starts) - 1
    out = np.zeros((len(a), G), bool)
    if not len(a) or not len(occluders):
        return out
    for g in range(G):
        for row in occluders[starts[g] : starts[g + 1]]:
            out[:, g] |= Capsule(tuple(row[:3]), tuple(row[3:6]), float(row[6]), bool(row[7])).meets_segments(a, b)
    return out


def inside_capsules(points: np.ndarray, caps) -> np.ndarray:
    """(n,) bool: each point inside some capsule (or band)."""
    pts = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(len(pts), bool)
    for c in caps:
        out |= c.contains(pts)
    return out
