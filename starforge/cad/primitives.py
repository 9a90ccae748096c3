"""Plain-data primitives of a printable body and the pure geometry both backends rely on.

All lengths in mm, in the star's placement frame (see :mod:`starforge.stars.model`): the body's
"up" is +y, the shortest side of the family box, so a star lies flat on the object it marks,
its long side along the finger, and the cameras look at it from above.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


def _vec(v) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class Sphere:
    """A sphere: ``centre`` (3,) mm, ``radius_mm``."""

    centre: tuple[float, float, float]
    radius_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _vec(self.centre))

    def bounds(self) -> np.ndarray:
        c = np.array(self.centre)
        return np.array([c - self.radius_mm, c + self.radius_mm])

    def volume(self) -> float:
        return 4.0 / 3.0 * np.pi * self.radius_mm**3


@dataclass(frozen=True)
class Cylinder:
    """A solid cylinder (flat ends) from ``p0`` to ``p1`` (3,) mm, ``radius_mm``."""

    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "p0", _vec(self.p0))
        object.__setattr__(self, "p1", _vec(self.p1))

    @property
    def length_mm(self) -> float:
        return float(np.linalg.norm(np.subtract(self.p1, self.p0)))

    def bounds(self) -> np.ndarray:
        p0, p1 = np.array(self.p0), np.array(self.p1)
        d = (p1 - p0) / max(self.length_mm, 1e-12)
        ext = self.radius_mm * np.sqrt(np.clip(1.0 - d**2, 0.0, 1.0))
        return np.array([np.minimum(p0, p1) - ext, np.maximum(p0, p1) + ext])

    def volume(self) -> float:
        return np.pi * self.radius_mm**2 * self.length_mm


@dataclass(frozen=True)
class Box:
    """An axis-aligned box: ``centre`` (3,) mm, ``size`` (3,) mm."""

    centre: tuple[float, float, float]
    size: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _vec(self.centre))
        object.__setattr__(self, "size", _vec(self.size))

    def bounds(self) -> np.ndarray:
        c, s = np.array(self.centre), np.array(self.size)
        return np.array([c - s / 2, c + s / 2])

    def volume(self) -> float:
        return float(np.prod(self.size))


@dataclass(frozen=True)
class Revolved:
    """A solid of revolution about the axis ``p0`` -> ``p1`` (3,) mm: the region between the axis
    and the polyline ``profile`` of ``(t_mm, r_mm)`` points (``t`` from 0 at ``p0`` to the axis
    length at ``p1``, increasing), closed by flat ends.  Both backends revolve the same polyline,
    so a fillet's arc is the same facets in the STEP and the mesh."""

    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    profile: tuple

    def __post_init__(self) -> None:
        object.__setattr__(self, "p0", _vec(self.p0))
        object.__setattr__(self, "p1", _vec(self.p1))
        object.__setattr__(self, "profile", tuple((float(t), float(r)) for t, r in self.profile))

    @property
    def axis(self) -> np.ndarray:
        d = np.subtract(self.p1, self.p0)
        return d / np.linalg.norm(d)

    def bounds(self) -> np.ndarray:
        u = self.axis
        s = np.sqrt(np.clip(1.0 - u**2, 0.0, 1.0))
        pts = [np.array(self.p0) + t * u for t, _ in self.profile]
        lo = np.min([p - r * s for p, (_, r) in zip(pts, self.profile, strict=True)], axis=0)
        hi = np.max([p + r * s for p, (_, r) in zip(pts, self.profile, strict=True)], axis=0)
        return np.array([lo, hi])

    def volume(self) -> float:
        pr = np.array(self.profile)
        h = np.diff(pr[:, 0])
        a, b = pr[:-1, 1], pr[1:, 1]
        return float(np.pi * (h * (a * a + a * b + b * b) / 3.0).sum())


def fillet_profile(
    stem_radius_mm: float, fillet_mm: float, buried_mm: float, facets: int = 6, inset_mm: float = 0.0
) -> tuple:
    """``(t, r)`` profile of a stem root filleted into a plate: ``buried_mm`` inside the plate at the
    full radius, then a concave quarter circle of radius ``fillet_mm`` from ``stem + fillet - inset``
    at the plate's face (t = ``buried_mm``) up to ``stem - inset``, as ``facets`` chords.

    ``inset_mm`` > 0 ends the arc (and the flat end that closes the solid) inside the stem, so
    the stem swallows that end whole: an end flush with the stem's surface leaves horizontal
    sliver faces where two tessellations of the same circle disagree, and a slicer whose layer
    plane meets them cannot close its loops (Slic3r 1.3 on the flat mount's plate)."""
    rs, f, e, s = float(stem_radius_mm), float(fillet_mm), float(buried_mm), float(inset_mm)
    a = np.linspace(0.0, np.pi / 2, int(facets) + 1)
    # arc centre (r, t) = (rs + f - s, e + f): from the plate's face round to r = rs - s
    arc = [(e + f - f * np.cos(x), rs - s + f - f * np.sin(x)) for x in a]
    return ((0.0, rs + f - s), *arc)


Primitive = Sphere | Cylinder | Box | Revolved


def plate_cuts(parts, cut_bounds, margin_mm: float = 1e-6) -> list:
    """Which cuts can be made on a plate before the union: per cut (its (2, 3) bounds, mm), the
    index in ``parts`` of the one :class:`Box` it meets when its bounds stay more than
    ``margin_mm`` clear of every other part's, else None.  (A u B) - C = (A - C) u B when C
    misses B, and cutting a box is far cheaper than cutting the finished body, in both backends.
    """
    boxes = [i for i, p in enumerate(parts) if isinstance(p, Box)]
    bounds = [p.bounds() for p in parts]

    def apart(a, b) -> bool:
        return bool((a[0] > b[1] + margin_mm).any() or (b[0] > a[1] + margin_mm).any())

    out = []
    for cb in cut_bounds:
        hit = [i for i in boxes if not apart(cb, bounds[i])]
        others_clear = all(apart(cb, bounds[i]) for i in range(len(parts)) if i not in boxes)
        out.append(hit[0] if len(hit) == 1 and others_clear else None)
    return out


def _clip_profile(profile, radius_mm: float, length_mm: float) -> tuple:
    """The ``(t, r)`` profile of the union of a solid of revolution (``profile``, t from 0) and
    a cylinder of ``radius_mm`` on t in [0, ``length_mm``] about the same axis: max(r(t),
    radius) with the crossings put in, runs at the cylinder's radius collapsed to their ends."""
    rs = float(radius_mm)
    pts: list[tuple[float, float]] = []
    for (t0, r0), (t1, r1) in itertools.pairwise(profile):
        if not pts:
            pts.append((float(t0), max(float(r0), rs)))
        if (r0 - rs) * (r1 - rs) < 0:  # the segment crosses the cylinder's surface
            pts.append((float(t0 + (t1 - t0) * (rs - r0) / (r1 - r0)), rs))
        pts.append((float(t1), max(float(r1), rs)))
    if pts[-1][0] < length_mm:
        pts.append((float(length_mm), rs))
    out = [pts[0]]
    for i in range(1, len(pts)):
        inner = 0 < i < len(pts) - 1
        if inner and pts[i][1] == rs and out[-1][1] == rs and pts[i + 1][1] == rs:
            continue
        if pts[i][0] > out[-1][0] or pts[i][1] != out[-1][1]:
            out.append(pts[i])
    return tuple(out)


def merge_coaxial(parts) -> tuple:
    """``parts`` with each cylinder and the solid of revolution that shares its start and axis
    (a vertical stem and its root fillet) replaced by one :class:`Revolved`: the profile
    max(fillet, stem radius) over the stem's length (:func:`_clip_profile`).

    The union is the same solid, built as one primitive: the backends then skip a boolean
    between two surfaces that meet at the fillet's top, the slowest one of a body in OCCT and a
    source of slivers in the mesh.  Only exact matches merge (start and axis equal, the
    profile's t increasing from 0 and ending inside the cylinder's length); everything else is
    returned as given, in order (a merged pair at the cylinder's place).
    """
    parts = list(parts)
    used: set[int] = set()
    out: list = []
    revs = [(i, p) for i, p in enumerate(parts) if isinstance(p, Revolved)]
    for i, p in enumerate(parts):
        if i in used:
            continue
        if isinstance(p, Cylinder) and p.length_mm > 0:
            u = np.subtract(p.p1, p.p0) / p.length_mm
            for j, r in revs:
                if j in used or r.p0 != p.p0:
                    continue
                ts = [t for t, _ in r.profile]
                if (
                    np.linalg.norm(np.cross(r.axis, u)) <= 1e-12
                    and float(r.axis @ u) > 0
                    and ts[0] == 0.0
                    and all(b > a for a, b in itertools.pairwise(ts))
                    and ts[-1] < p.length_mm
                ):
                    used.add(j)
                    p = Revolved(p.p0, p.p1, _clip_profile(r.profile, p.radius_mm, p.length_mm))
                    break
        out.append(p)
    return tuple(out)


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
    if den > 1e-12:
        s = np.clip((b * f - c * e) / den, 0.0, 1.0)
        t = np.clip((b * s + f) / e, 0.0, 1.0)
        s = np.clip((b * t - c) / a, 0.0, 1.0)
        cands.append(np.linalg.norm(a0 + s * d1 - (b0 + t * d2)))
    cands.append(point_segment_distance([a0, a1], b0, b1).min())
    cands.append(point_segment_distance([b0, b1], a0, a1).min())
    return float(min(cands))


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
    s = np.where(den > 1e-12, (de * (-dr) - (-er) * dd) / np.where(den > 1e-12, den, 1.0), 0.0)
    s = np.clip(np.where(ee > 0, s, 0.0), 0.0, 1.0)
    t = np.maximum((de * s - dr) / dd, 0.0)  # the ray's closest parameter to that segment point
    s = np.where(ee > 0, np.clip((de * t + er) / safe_ee, 0.0, 1.0), 0.0)
    p_ray = o + t[..., None] * d
    p_seg = A + s[..., None] * e
    dist = np.linalg.norm(p_ray - p_seg, axis=2)
    return dist[:, 0] if one else dist


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
    helper = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 0, 1.0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return local[:, :1] * e1 + local[:, 1:2] * e2 + local[:, 2:3] * up
