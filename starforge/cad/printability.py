"""Will a body print as written, without supports?  A layer analysis of the mesh as it lies on
the bed (Z up, lowest point on Z = 0), the way a slicer sees it.

The mesh is cut at the middle of every layer.  Per layer:

* its region (the union of the section's polygons, shapely);
* **islands in mid-air**: a connected part of a layer that touches nothing of the layer below
  (a print would start it on nothing);
* what a layer adds beyond the layer below grown by ``layer * tan(overhang_deg)``, split into
  **bridges** (a piece held by the layer below at two or more separate places: the printer
  spans it, as across the strap's tunnel, or a ceiling held all round its outline, as over a
  magnet pocket) and **overhangs** (held along one edge only: a
  sphere's underside, the saddle channel's shallow vault);
* the first layer's area (the bed contact) and whether the body's centre of mass lies over
  the convex hull of that contact (it cannot tip over while it is printed).

:func:`printable` applies starforge's criteria to a report; they are stated there.
"""

from __future__ import annotations

import math

import numpy as np

#: starforge's criteria for "prints without supports" (see :func:`printable`)
MIN_CONTACT_MM2 = 25.0
MAX_BRIDGE_MM = 5.0
COM_MARGIN_MM = 0.5


def _region(path2d):
    from shapely.ops import unary_union

    if path2d is None:
        return None
    polys = list(path2d.polygons_full)
    return unary_union(polys) if polys else None


def _parts(geom):
    if geom is None or geom.is_empty:
        return []
    return [g for g in getattr(geom, "geoms", [geom]) if g.geom_type == "Polygon" and g.area > 0]


def _anchors(piece, support):
    """The places where ``piece``'s outline rests on ``support``: (count, their geometry)."""
    touch = piece.boundary.intersection(support.buffer(1e-6))
    lines = [g for g in getattr(touch, "geoms", [touch]) if not g.is_empty and g.length > 1e-4]
    if not lines:
        return 0, None
    from shapely.ops import linemerge, unary_union

    merged = linemerge(lines) if len(lines) > 1 else lines[0]
    return len(getattr(merged, "geoms", [merged])), unary_union(lines)


def _held_all_round(piece, support) -> bool:
    """Whether ``piece``'s outer boundary rests on ``support`` all the way round: it closes a
    pocket from above (a bridge held on every side), not an overhang held along one edge (a
    ring round a stem rests on its *inner* boundary)."""
    return piece.exterior.difference(support.buffer(1e-6)).length < 1e-4


def _span(piece, anchors, step_mm: float = 0.1) -> float:
    """How far a bridge reaches unsupported: twice the largest distance from a point of the
    piece to its nearest anchor (sampled on a ``step_mm`` grid), mm."""
    import shapely

    x0, y0, x1, y1 = piece.bounds
    gx, gy = np.meshgrid(np.arange(x0, x1 + step_mm, step_mm), np.arange(y0, y1 + step_mm, step_mm))
    inside = shapely.contains_xy(piece, gx.ravel(), gy.ravel())
    if not inside.any():
        return 0.0
    pts = shapely.points(gx.ravel()[inside], gy.ravel()[inside])
    return float(2.0 * shapely.distance(pts, anchors).max())


def layer_report(mesh, layer_mm: float = 0.2, overhang_deg: float = 45.0) -> dict:
    """Layer analysis of ``mesh`` (trimesh, mm, printing orientation).

    Returns a dict: ``layers``, ``layer_mm``, ``height_mm``, ``first_layer_mm2``,
    ``midair_islands`` (list of ``{"z_mm", "area_mm2"}``), ``overhang_deg``, ``overhang_mm2``,
    ``bridge_mm2``, ``max_bridge_mm`` (the longest span a bridge must cross: twice the farthest
    any point of it lies from its supports, on a 0.1 mm grid), ``max_overhang_layer_mm2``, ``max_overhang_z_mm``,
    ``com_over_contact`` (bool) and ``com_margin_mm`` (distance of the centre of mass inside the
    contact's convex hull; negative outside).
    """
    from shapely.geometry import Point

    z0, z1 = float(mesh.bounds[0, 2]), float(mesh.bounds[1, 2])
    n = max(1, int(math.ceil((z1 - z0) / layer_mm - 1e-9)))
    zs = z0 + layer_mm * (np.arange(n) + 0.5)
    sections = mesh.section_multiplane(plane_origin=[0.0, 0.0, 0.0], plane_normal=[0.0, 0.0, 1.0], heights=zs)
    regions = [_region(s) for s in sections]
    reach = layer_mm * math.tan(math.radians(overhang_deg))
    islands, over, bridge, spans = [], [], [], [0.0]
    prev = None
    for z, reg in zip(zs, regions, strict=True):
        o = b = 0.0
        if reg is not None and not reg.is_empty:
            if prev is None or prev.is_empty:
                if z > z0 + layer_mm:  # a layer above the first with nothing below it
                    islands.append({"z_mm": round(float(z), 4), "area_mm2": round(float(reg.area), 4)})
            else:
                for part in _parts(reg):
                    if not part.intersects(prev):
                        islands.append({"z_mm": round(float(z), 4), "area_mm2": round(float(part.area), 4)})
                grown = prev.buffer(reach)
                for piece in _parts(reg.difference(grown)):
                    if piece.area < 1e-3:
                        continue
                    count, where = _anchors(piece, grown)
                    if count < 2 and _held_all_round(piece, grown):  # a pocket's ceiling
                        count, where = 2, piece.exterior
                    if count >= 2:
                        b += piece.area
                        spans.append(_span(piece, where))
                    else:
                        o += piece.area
        over.append(o)
        bridge.append(b)
        prev = reg
    over = np.array(over)
    k = int(over.argmax()) if len(over) else 0
    first = regions[0]
    com = np.asarray(mesh.center_mass if mesh.is_volume else mesh.centroid, float)
    if first is not None and not first.is_empty:
        hull = first.convex_hull
        p = Point(com[0], com[1])
        margin = hull.exterior.distance(p) if hull.contains(p) else -hull.exterior.distance(p)
    else:
        margin = -math.inf
    return {
        "layers": int(n),
        "layer_mm": layer_mm,
        "height_mm": round(z1 - z0, 6),
        "first_layer_mm2": round(float(first.area) if first is not None else 0.0, 4),
        "midair_islands": islands,
        "overhang_deg": overhang_deg,
        "overhang_mm2": round(float(over.sum()), 4),
        "bridge_mm2": round(float(np.sum(bridge)), 4),
        "max_bridge_mm": round(max(spans), 4),
        "max_overhang_layer_mm2": round(float(over.max()) if len(over) else 0.0, 4),
        "max_overhang_z_mm": round(float(zs[k]), 4) if len(over) else 0.0,
        "com_over_contact": bool(margin >= COM_MARGIN_MM),
        "com_margin_mm": round(float(margin), 4),
    }


def flat_levels(vertices, faces) -> list[tuple[float, float, int]]:
    """The mesh's flat (horizontal) faces by height, as a reader of the STL finds them: per
    distinct float32 height shared by the three corners of at least one triangle,
    ``(z_mm, area_mm2, triangles)``, lowest first.

    A level whose area is far below one extrusion squared is not a face anyone designed: it is
    slivers where two tessellations of one surface disagree, and a slicer whose layer plane
    meets such a level exactly may fail to close that layer's loops (Slic3r 1.3: "Unable to
    close this loop").  Parameters: vertices (n, 3) float mm, faces (m, 3) int."""
    v = np.asarray(vertices, dtype=np.float32)
    t = v[np.asarray(faces, dtype=np.int64)]
    z = t[:, :, 2]
    flat = (z[:, 0] == z[:, 1]) & (z[:, 1] == z[:, 2])
    if not flat.any():
        return []
    tf = t[flat].astype(np.float64)
    area = np.linalg.norm(np.cross(tf[:, 1] - tf[:, 0], tf[:, 2] - tf[:, 0]), axis=1) / 2
    levels, idx = np.unique(z[flat, 0], return_inverse=True)
    sums = np.bincount(idx, weights=area, minlength=len(levels))
    counts = np.bincount(idx, minlength=len(levels))
    return [(float(h), float(a), int(c)) for h, a, c in zip(levels, sums, counts, strict=True)]


def printable(report: dict) -> list[str]:
    """What keeps a body from printing without supports, by starforge's criteria (empty: none).

    * no island in mid-air (nothing starts on air);
    * at least :data:`MIN_CONTACT_MM2` mm^2 on the bed (a 5 x 5 mm pad);
    * the centre of mass at least :data:`COM_MARGIN_MM` mm inside the contact's convex hull;
    * no bridge wider than :data:`MAX_BRIDGE_MM` mm.

    Overhangs are reported, not refused: a marker sphere's underside on its stem is one, and
    every FDM printer prints a 4 mm ball on a stem.
    """
    out = []
    if report["midair_islands"]:
        i = report["midair_islands"][0]
        out.append(f"{len(report['midair_islands'])} island(s) start in mid-air (first at z = {i['z_mm']} mm)")
    if report["first_layer_mm2"] < MIN_CONTACT_MM2:
        out.append(f"bed contact {report['first_layer_mm2']:.1f} mm^2 < {MIN_CONTACT_MM2:g} mm^2")
    if not report["com_over_contact"]:
        out.append(f"centre of mass {report['com_margin_mm']:.2f} mm inside the bed contact's hull (< {COM_MARGIN_MM})")
    if report["max_bridge_mm"] > MAX_BRIDGE_MM:
        out.append(f"a bridge spans {report['max_bridge_mm']:.1f} mm > {MAX_BRIDGE_MM:g} mm")
    return out
