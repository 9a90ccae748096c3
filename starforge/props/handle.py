"""A handle: a thin bar a hand closes around, bounding an opening the fingers go through.

A mug, a jug, a kettle or a bucket is held mostly by such a loop, not by its body.  The loop
is found from the mesh's shape, not its name:

* a watertight mesh whose Euler characteristic is twice its number of bodies (each a sphere's,
  ``2 - 2 genus``) has no tunnel, so no loop (checked first: it costs next to nothing); any
  other mesh is searched;
* the mesh is cut by planes square to each direction it is sliced in (the caller's; see
  :func:`starforge.props.grips.held_part`) every :data:`starforge.props.hand.SLICE_M`; an
  *opening* is a hole of a section (an interior ring of a section's polygon) between
  :data:`OPENING_M` wide across its narrower and wider sides (at least a finger's width; at most what a hand still closes round)
  through which one sees along the plane's normal both ways (two rays from a point inside it
  leave the mesh without a hit): a blind pocket, like a cup's cavity cut across, is none;
* the largest opening is the handle's; its bar is the stretch of the opening's rim where the
  section square to the rim (the bar's own cross-section) is a hand's hold, its wider width
  within :data:`BAR_M`, and does not run into the body (whose section there is wider).

The fist (:func:`starforge.props.hand.fist`) closes around the bar's core: the line
along the bar's main direction (the principal direction of its cross-sections' centres) through
its outermost cross-section, over the bar's length (at most a palm), the fingers through the
opening; the wrist leaves the bar away from the body (:attr:`Handle.outward`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from shapely.geometry import LinearRing, Point, Polygon

from starforge.geometry.distance import point_segment_distance
from starforge.props.hand import PALM_M, SLICE_M
from starforge.tol import tol

#: an opening's narrower and wider sides, m (a finger is 15-20 mm thick; a hand spans ~120 mm)
OPENING_M = (0.015, 0.12)
#: the bar's cross-section: its wider width, m (a mug's handle is 6-30 mm thick; a fist closes
#: round at most 55 mm)
BAR_M = (0.005, 0.055)
#: at most this many planes (:data:`starforge.props.hand.SLICE_M` apart) along a direction
MAX_PLANES = 40
#: the rim of the opening is followed in steps this long, m
RIM_STEP_M = 0.003
#: the bar at a point of the rim is the material this far (m) off the rim, away from the opening
PROBE_M = 0.001


@dataclass(frozen=True)
class Handle:
    """A handle (prop frame, m).

    Attributes
    ----------
    a, b : (3,) float
        The bar's core the fist closes around, m.
    radius_m : float
        Half the bar's wider cross-section width, m.
    outward : (3,) float
        Unit vector from the body to the bar, square to ``b - a``: where the wrist leaves.
    through : (3,) float
        Unit vector along which the fingers pass through the opening.
    opening_m : (2,) float
        The opening's narrower and wider sides, m.
    centres : (k, 3) float
        The centres of the bar's cross-sections along the rim, m.
    """

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius_m: float
    outward: tuple[float, float, float]
    through: tuple[float, float, float]
    opening_m: tuple[float, float]
    centres: tuple[tuple[float, float, float], ...]

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.b, self.a)))

    def to_json(self) -> dict:
        return {
            "a": [round(float(x), 6) + 0.0 for x in self.a],
            "b": [round(float(x), 6) + 0.0 for x in self.b],
            "width_mm": round(2000 * self.radius_m, 1),
            "opening_mm": [round(1000 * float(x), 1) for x in self.opening_m],
            "outward": [round(float(x), 4) + 0.0 for x in self.outward],
        }


def has_tunnel(mesh) -> bool:
    """False when the mesh is watertight and each of its bodies has a sphere's Euler
    characteristic, 2 (genus 0: no loop); True when it may have a loop."""
    return not (mesh.is_watertight and int(mesh.euler_number) == 2 * int(mesh.body_count))


def _sides(poly: Polygon) -> tuple[float, float]:
    """The narrower and wider sides of the polygon's smallest rotated rectangle, m."""
    rect = np.asarray(poly.minimum_rotated_rectangle.exterior.coords)[:4]
    s = sorted(float(np.linalg.norm(rect[(i + 1) % 4] - rect[i])) for i in range(2))
    return s[0], s[1]


def _sections(mesh, normal: np.ndarray, origin: np.ndarray):
    """(polygons, to_3d (4, 4)) of the mesh cut by a plane, or ``((), None)`` when it misses."""
    sec = mesh.section(plane_origin=origin, plane_normal=normal)
    if sec is None:
        return (), None
    planar, to_3d = sec.to_2D(normal=normal)
    return tuple(planar.polygons_full), to_3d


def _to3(to_3d: np.ndarray, xy) -> np.ndarray:
    """(k, 3) prop-frame points of the plane's 2D points ``xy`` (k, 2) (``to_3d`` from :func:`_sections`)."""
    xy = np.atleast_2d(np.asarray(xy, float))
    return xy @ to_3d[:3, :2].T + to_3d[:3, 3]


def _opening(mesh, directions):
    """The largest see-through opening: (area m^2, the plane's normal (3,), its rim (a 2D ring in
    the plane), the plane's 2D-to-3D transform (4, 4), its narrower and wider sides m), or None."""
    v = np.asarray(mesh.vertices, float)
    best = None
    for d in directions:
        d = np.asarray(d, float) / np.linalg.norm(d)
        t = v @ d
        n = int(min(MAX_PLANES, max(1, (t.max() - t.min()) // SLICE_M)))
        for h in t.min() + (np.arange(n) + 0.5) * (t.max() - t.min()) / n:
            polys, to_3d = _sections(mesh, d, h * d)
            for poly in polys:
                for ring in poly.interiors:
                    hole = Polygon(ring)
                    if best is not None and hole.area <= best[0]:
                        continue
                    lo, hi = _sides(hole)
                    if not (OPENING_M[0] <= lo and hi <= OPENING_M[1]):
                        continue
                    p = _to3(to_3d, hole.representative_point().coords[0])[0]
                    if mesh.ray.intersects_any(np.array([p, p]), np.array([d, -d])).any():
                        continue  # a pocket, not a way through
                    best = (hole.area, d, LinearRing(ring), to_3d, (lo, hi))
    return best


def _bar(mesh, ring: LinearRing, to_3d: np.ndarray):
    """Along the rim ``ring``: per step, the bar's cross-section centre (3,) and wider width,
    or None where the rim is the body's."""
    hole = Polygon(ring)
    k = max(8, int(ring.length // RIM_STEP_M))
    s = np.arange(k) * ring.length / k
    pts = np.array([ring.interpolate(x).coords[0] for x in s])
    tangent = np.roll(pts, -1, axis=0) - np.roll(pts, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    out = []
    for p, tg, nm in zip(pts, tangent, normal, strict=True):
        if hole.contains(Point(p + PROBE_M * nm)):
            nm = -nm
        p3 = _to3(to_3d, p)[0]
        inner = _to3(to_3d, p + PROBE_M * nm)[0]
        t3 = to_3d[:3, :2] @ tg
        polys, t_3d = _sections(mesh, t3, p3)
        found = None
        for poly in polys:
            q = np.linalg.solve(t_3d[:3, :3], inner - t_3d[:3, 3])[:2]
            if poly.contains(Point(q)):
                lo, hi = _sides(poly)
                if BAR_M[0] <= lo and hi <= BAR_M[1]:
                    c = np.asarray(poly.centroid.coords[0])
                    found = (_to3(t_3d, c)[0], hi)
                break
        out.append(found)
    return out


def _longest_cyclic_run(ok: np.ndarray) -> np.ndarray:
    """Indices of the longest run of true values of ``ok`` read round a circle."""
    n = len(ok)
    if ok.all():
        return np.arange(n)
    start = int(np.flatnonzero(~ok)[0])
    order = (np.arange(n) + start) % n
    best, cur = [], []
    for i in order:
        cur = [*cur, i] if ok[i] else []
        if len(cur) > len(best):
            best = cur
    return np.asarray(best, int)


def find_handle(mesh, directions) -> Handle | None:
    """The mesh's handle (see the module docstring), or None; ``directions`` the (3,) unit
    vectors to cut the mesh square to."""
    if not has_tunnel(mesh):
        return None
    found = _opening(mesh, directions)
    if found is None:
        return None
    _, d, ring, to_3d, sides = found
    bar = _bar(mesh, ring, to_3d)
    run = _longest_cyclic_run(np.array([b is not None for b in bar]))
    if len(run) < 3:
        return None
    centres = np.array([bar[i][0] for i in run])
    radius = float(np.median([bar[i][1] for i in run])) / 2
    c = centres.mean(axis=0)
    _, _, vt = np.linalg.svd(centres - c)
    u = vt[0]
    body = np.asarray(mesh.vertices, float).mean(axis=0)
    out = c - body
    out -= (out @ u) * u
    out /= max(float(np.linalg.norm(out)), tol.zero)
    tip = centres[np.argmax(centres @ out)]  # the outermost cross-section
    along = (centres - c) @ u
    half = min(float(np.ptp(along)), PALM_M) / 2
    mid = tip - ((tip - c) @ u) * u + (along.min() + along.max()) / 2 * u
    a, b = mid - half * u, mid + half * u
    return Handle(
        tuple(map(float, a)), tuple(map(float, b)), radius, tuple(map(float, out)), tuple(map(float, d)),
        (float(sides[0]), float(sides[1])), tuple(tuple(map(float, x)) for x in centres),
    )


def without_handle(mesh, handle: Handle):
    """The mesh less the faces within the bar (``handle``'s cross-section centres and half its
    width, and a millimetre): the body a hand may also wrap."""
    cen = np.asarray(mesh.triangles_center, float)
    pts = np.asarray(handle.centres, float)
    near = np.zeros(len(cen), bool)
    for p, q in zip(pts[:-1], pts[1:], strict=True):
        near |= point_segment_distance(cen, p, q) <= handle.radius_m + 1e-3
    return mesh.submesh([np.flatnonzero(~near)], append=True)
