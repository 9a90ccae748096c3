"""Will a body print as written, without supports?  A layer analysis of the mesh as it lies on
the bed (Z up, lowest point on Z = 0), the way a slicer sees it.

The mesh is cut at the middle of every layer.  Per layer:

* its region (the union of the section's polygons, shapely);
* **islands in mid-air**: a connected part of a layer that touches nothing of the layer below
  (a print would start it on nothing).  A bridge or an overhang is connected to supported
  material in its own layer, so it is not an island;
* **overhang**: the part of a layer further than ``layer * tan(overhang_deg)`` from the layer
  below (what a slicer calls overhanging perimeters).

The first layer's area is the bed contact.  A printable body has no island in mid-air and
enough first-layer contact; overhangs are reported (a sphere's underside on its stem is one).
"""

from __future__ import annotations

import math

import numpy as np


def _region(path2d):
    from shapely.ops import unary_union

    if path2d is None:
        return None
    polys = list(path2d.polygons_full)
    return unary_union(polys) if polys else None


def _parts(geom):
    if geom is None or geom.is_empty:
        return []
    return list(getattr(geom, "geoms", [geom]))


def layer_report(mesh, layer_mm: float = 0.2, overhang_deg: float = 45.0) -> dict:
    """Layer analysis of ``mesh`` (trimesh, mm, printing orientation).

    Returns a dict: ``layers``, ``height_mm``, ``first_layer_mm2``, ``midair_islands`` (list of
    ``{"z_mm", "area_mm2"}``), ``overhang_mm2`` (total), ``max_overhang_layer_mm2`` and
    ``max_overhang_z_mm``.
    """
    z0, z1 = float(mesh.bounds[0, 2]), float(mesh.bounds[1, 2])
    n = max(1, int(math.ceil((z1 - z0) / layer_mm - 1e-9)))
    zs = z0 + layer_mm * (np.arange(n) + 0.5)
    sections = mesh.section_multiplane(plane_origin=[0.0, 0.0, 0.0], plane_normal=[0.0, 0.0, 1.0], heights=zs)
    regions = [_region(s) for s in sections]
    reach = layer_mm * math.tan(math.radians(overhang_deg))
    islands, over = [], []
    prev = None
    for z, reg in zip(zs, regions, strict=True):
        if reg is None or reg.is_empty:
            over.append(0.0)
            prev = reg
            continue
        if prev is None or prev.is_empty:
            if z > z0 + layer_mm:  # a layer above the first with nothing below it
                islands.append({"z_mm": round(float(z), 4), "area_mm2": round(float(reg.area), 4)})
            over.append(0.0)
            prev = reg
            continue
        grown = prev.buffer(reach)
        for part in _parts(reg):
            if not part.intersects(prev):
                islands.append({"z_mm": round(float(z), 4), "area_mm2": round(float(part.area), 4)})
        over.append(float(reg.difference(grown).area))
        prev = reg
    over = np.array(over)
    k = int(over.argmax()) if len(over) else 0
    first = regions[0]
    return {
        "layers": int(n),
        "layer_mm": layer_mm,
        "height_mm": round(z1 - z0, 6),
        "first_layer_mm2": round(float(first.area) if first is not None else 0.0, 4),
        "midair_islands": islands,
        "overhang_deg": overhang_deg,
        "overhang_mm2": round(float(over.sum()), 4),
        "max_overhang_layer_mm2": round(float(over.max()) if len(over) else 0.0, 4),
        "max_overhang_z_mm": round(float(zs[k]), 4) if len(over) else 0.0,
    }
