"""The hand that holds the prop, as occluders that move with it: capsules in the prop frame.

A grip is a segment (the stretch of the gripped part the palm covers, along the axis the
fingers close around) and the part's radius; the hand is one capsule around it, reaching
:data:`FINGERS_M` beyond the part and covering that stretch of its surface
(:func:`hand_capsule`: palm and fingers wrapped round the grip), which hides whatever lies inside it from every camera and covers the surface it
encloses (no marker can be stuck under the hand).  ``--grip`` gives the segment in the prop
frame (metres); without it, a built-in prop has its own grip (:data:`GRIPS`) and a mesh gets
its thinnest end: of the ends of its bounding box along the axes at least half as long as the
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


def hand_capsule(a, b, part_radius: float) -> Capsule:
    """The hand around the grip ``a``-``b`` (the stretch of the part the palm covers, m) of a part
    ``part_radius`` thick: a capsule of radius ``part_radius + FINGERS_M`` whose core is shortened
    so that where it meets the part's surface it covers ``a``-``b`` and no more (a capsule reaches
    ``sqrt(R^2 - r^2)`` past its core's ends at distance ``r`` from the axis)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    R = part_radius + FINGERS_M
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


def default_grip(mesh, name: str = "", builtin: bool = False) -> Capsule:
    """The hand at a sensible graspable part (see the module docstring)."""
    if builtin and name in GRIPS:
        a, b, r = GRIPS[name]
        return hand_capsule(a, b, r)
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
    return hand_capsule(a, b, min(r, 0.05))


def inside_capsules(points: np.ndarray, caps) -> np.ndarray:
    """(n,) bool: each point inside some capsule."""
    from starforge.cad.primitives import point_segment_distance

    pts = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(len(pts), bool)
    for c in caps:
        out |= point_segment_distance(pts, c.a, c.b) <= c.radius
    return out
