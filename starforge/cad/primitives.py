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

