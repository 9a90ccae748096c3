"""Lay printed bodies out on print beds (pure shelf packing).

Bodies arrive in their printing orientation (:func:`print_transform`: plate down, the body's
up (+y in the placement frame) along the bed's +Z, lowest point on Z = 0, centred on the Z
axis), so a layout only translates them.  When one bed cannot hold them all, the rest go on a
second bed, and so on: ``plate_1``, ``plate_2``, ...
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.spec import positive

# placement (x, y, z) -> print (x, -z, y): a rotation of +90 deg about x; +y up becomes +Z up
TO_BED = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


def print_transform(bounds) -> np.ndarray:
    """(4, 4) placement frame -> printing orientation for a body with these placement-frame
    bounds (2, 3): rotated plate-down onto Z = 0, centred on the Z axis."""
    b = np.asarray(bounds, float)
    corners = (
        np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) @ TO_BED.T
    )
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    T = np.eye(4)
    T[:3, :3] = TO_BED
    T[:3, 3] = [-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]]
    return T


@dataclass(frozen=True)
class PlateLayout:
    """Where the bodies of one bed go.

    Attributes
    ----------
    bed_mm : (2,) bed size (X, Y), mm
    gap_mm : float, least gap between two bodies' footprints and to the bed's edge, mm
    members : tuple of int, which bodies (indices into the caller's list)
    transforms : tuple of (4, 4) arrays, printing orientation -> bed position (translations)
    footprints : (n, 4) float, (x0, y0, x1, y1) on the bed, mm
    """

    bed_mm: tuple
    gap_mm: float
    members: tuple
    transforms: tuple
    footprints: np.ndarray


def layout_plates(bounds, bed_mm=(200.0, 200.0), gap_mm: float = 5.0) -> list[PlateLayout]:
    """Shelf-pack bodies (printing-orientation bounds (n, 2, 3), mm) on as many beds as needed.

    Raises StarforgeError when one body alone is larger than the bed.
    """
    bx, by = (positive(f"bed_mm[{i}]", v) for i, v in enumerate(bed_mm))
    gap = positive("gap_mm", gap_mm)
    b = np.asarray(bounds, float)
    size = b[:, 1] - b[:, 0]
    for i in range(len(b)):
        if size[i, 0] + 2 * gap > bx + 1e-9 or size[i, 1] + 2 * gap > by + 1e-9:
            raise StarforgeError(
                f"plate: body {i + 1} is {size[i, 0]:.1f} x {size[i, 1]:.1f} mm, larger than the {bx:g} x {by:g} mm "
                f"bed with {gap:g} mm gaps; pass a larger --bed or a smaller --gap"
            )
    order = sorted(range(len(b)), key=lambda i: (-size[i, 1], -size[i, 0], i))
    beds: list[dict] = []
    cur: dict = {}
    x = y = shelf = 0.0
    for i in order:
        w, h = size[i, 0], size[i, 1]
        if not cur:
            cur, x, y, shelf = {}, gap, gap, 0.0
        if x + w + gap > bx + 1e-9:
            x, y, shelf = gap, y + shelf + gap, 0.0
        if y + h + gap > by + 1e-9:  # this bed is full: start the next one
            beds.append(cur)
            cur, x, y, shelf = {}, gap, gap, 0.0
        cur[i] = (x, y)
        x += w + gap
        shelf = max(shelf, h)
    if cur:
        beds.append(cur)
    out = []
    for bed in beds:
        members = tuple(sorted(bed))
        transforms, fps = [], []
        for i in members:
            T = np.eye(4)
            T[:3, 3] = np.array([bed[i][0], bed[i][1], 0.0]) - np.array([b[i, 0, 0], b[i, 0, 1], 0.0])
            transforms.append(T)
            fps.append([bed[i][0], bed[i][1], bed[i][0] + size[i, 0], bed[i][1] + size[i, 1]])
        out.append(PlateLayout((bx, by), gap, members, tuple(transforms), np.array(fps).reshape(-1, 4)))
    return out
