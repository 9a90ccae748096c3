"""The stems of a body: from the plate to each sphere, routed clear of the other spheres and
stems (pure geometry, no CAD kernel), and the letters the spheres go by."""

from __future__ import annotations

import math

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.distance import segment_segment_distance


def sphere_letter(i: int) -> str:
    """A body's i-th sphere as the family paper names a star's: A, B, C, D, then E, F, ..."""
    return chr(ord("A") + int(i))



def _ring_offsets(max_r: float, step: float = 0.25, per_ring: int = 24) -> np.ndarray:
    out = [np.zeros(2)]
    for r in np.arange(step, max_r + 1e-9, step):
        a = np.linspace(0, 2 * np.pi, per_ring, endpoint=False)
        out.append(np.column_stack([r * np.cos(a), r * np.sin(a)]))
    return np.vstack(out)


def _point_to_segments(p, starts, end) -> np.ndarray:
    """Distance from point ``p`` (3,) to each segment ``starts[k]`` -> ``end``, (k,)."""
    ab = end[None, :] - starts
    den = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.clip(np.einsum("ij,ij->i", p[None, :] - starts, ab) / den, 0.0, 1.0)
    return np.linalg.norm(p[None, :] - (starts + t[:, None] * ab), axis=1)


def route_stems(
    centres,
    marker_radius_mm: float,
    stem_radius_mm: float,
    y_top: float,
    clearance_mm: float,
    max_tilt_deg: float,
    tip_clear=None,
) -> np.ndarray:
    """Root points (n, 3) mm on the plane y = ``y_top`` for stems to each centre.

    Each stem is the segment root -> centre.  Spheres are routed from the lowest up; a stem
    keeps ``marker_radius + stem_radius + clearance`` from every other centre and
    ``2 stem_radius + clearance`` from the stems already routed (above the plate), leaning at
    most ``max_tilt_deg``.  Among clear roots the most vertical one wins.  Raises
    StarforgeError when a sphere has no clear route.
    """
    c = np.asarray(centres, float)
    n = len(c)
    roots = np.zeros((n, 3))
    placed: list[int] = []
    keep_sphere = marker_radius_mm + stem_radius_mm + clearance_mm
    keep_stem = 2 * stem_radius_mm + clearance_mm
    for i in np.argsort(c[:, 1], kind="stable"):
        height = c[i, 1] - y_top
        max_off = height * math.tan(math.radians(max_tilt_deg))
        offsets = _ring_offsets(max_off) if max_off > 0 else np.zeros((1, 2))
        cand = np.column_stack(
            [c[i, 0] + offsets[:, 0], np.full(len(offsets), y_top), c[i, 2] + offsets[:, 1]]
        )
        ok = np.ones(len(cand), dtype=bool)
        for j in range(n):
            if j != i:
                ok &= _point_to_segments(c[j], cand, c[i]) >= keep_sphere
        found = None
        for root in cand[ok]:
            if all(segment_segment_distance(root, c[i], roots[k], c[k]) >= keep_stem for k in placed):
                found = root
                break
        if found is None:
            raise StarforgeError(
                f"no stem route for sphere {sphere_letter(i)} clear of the other spheres "
                f"(stem {2 * stem_radius_mm:.2f} mm, tilt <= {max_tilt_deg:g} deg)"
            )
        roots[i] = found
        placed.append(int(i))
    return roots
