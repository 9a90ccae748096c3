"""Lay bodies out on one print bed (pure shelf packing) and merge their meshes into a plate.

On the bed the body stands on its mount: body +y becomes bed +Z (a rotation of +90 deg
about x, so body z becomes bed -Y); every body is then moved so its footprint sits at its
slot and its lowest point on Z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.spec import positive

# body (x, y, z) -> bed (x, -z, y): +y up becomes +Z up
TO_BED = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


@dataclass(frozen=True)
class PlateLayout:
    """Where each body goes on the bed.

    Attributes
    ----------
    bed_mm : (2,) bed size (X, Y), mm
    gap_mm : float, least gap between two bodies' footprints and to the bed's edge, mm
    transforms : tuple of (4, 4) arrays, body frame -> bed frame, one per body
    footprints : (n, 4) float, (x0, y0, x1, y1) on the bed, mm
    """

    bed_mm: tuple
    gap_mm: float
    transforms: tuple
    footprints: np.ndarray


def layout_plate(bounds, bed_mm=(200.0, 200.0), gap_mm: float = 5.0) -> PlateLayout:
    """Shelf-pack bodies with these bounds on a bed.

    Parameters
    ----------
    bounds : (n, 2, 3) float, mm, each body's (min, max) corners in its own frame
    bed_mm : (2,) bed size X, Y in mm
    gap_mm : least gap between bodies and to the bed edge, mm

    Raises StarforgeError (saying how many do not fit) when the bed is too small.
    """
    bx, by = (positive(f"bed_mm[{i}]", v) for i, v in enumerate(bed_mm))
    gap = positive("gap_mm", gap_mm)
    b = np.asarray(bounds, float)
    n = len(b)
    # bed-frame bounds of each body (a rotation of an axis-aligned box is axis-aligned here)
    corners = np.stack([b[:, 0], b[:, 1]], axis=1)  # (n, 2, 3)
    bed_pts = corners @ TO_BED.T
    lo, hi = bed_pts.min(axis=1), bed_pts.max(axis=1)
    size = hi - lo
    order = sorted(range(n), key=lambda i: (-size[i, 1], -size[i, 0], i))
    x, y, shelf_h = gap, gap, 0.0
    place = {}
    for i in order:
        w, h = size[i, 0], size[i, 1]
        if x + w + gap > bx + 1e-9:
            x, y, shelf_h = gap, y + shelf_h + gap, 0.0
        if x + w + gap > bx + 1e-9 or y + h + gap > by + 1e-9:
            left = n - len(place)
            raise StarforgeError(
                f"plate: {left} of {n} bodies do not fit on a {bx:g} x {by:g} mm bed with {gap:g} mm gaps; "
                "pass a larger --bed or fewer --ids"
            )
        place[i] = (x, y)
        x += w + gap
        shelf_h = max(shelf_h, h)
    transforms, fps = [], []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = TO_BED
        T[:3, 3] = np.array([place[i][0], place[i][1], 0.0]) - lo[i]
        transforms.append(T)
        fps.append([place[i][0], place[i][1], place[i][0] + size[i, 0], place[i][1] + size[i, 1]])
    return PlateLayout((bx, by), gap, tuple(transforms), np.array(fps).reshape(n, 4))


def plate_mesh(meshes, layout: PlateLayout):
    """All meshes moved to their slots, concatenated into one trimesh (one body per shell)."""
    import trimesh

    moved = []
    for m, T in zip(meshes, layout.transforms, strict=True):
        c = m.copy()
        c.apply_transform(T)
        moved.append(c)
    return trimesh.util.concatenate(moved)
