"""How much of each sphere's upper hemisphere the body leaves free (pure, analytic).

For sphere i and a direction d of the hemisphere around "up" (+y), the surface point
``c_i + r d`` is seen by a distant camera in direction d when the ray from it along d misses
every other (finished) sphere and every stem.  The fraction of free directions (equal-area
Fibonacci directions) is the sphere's visibility.  The mount does not enter: it lies entirely
below the plate's top face (holes and engravings only remove material), and every ray starts
above that face going up (d . up >= 0).
"""

from __future__ import annotations

import numpy as np

from starforge.cad.body import UP, Body
from starforge.cad.primitives import Cylinder
from starforge.geometry.distance import hemisphere_directions, ray_hits_spheres, ray_segment_distance


def sphere_visibility(body: Body, directions: int = 400) -> np.ndarray:
    """Per marker, the free fraction of its upper hemisphere's directions, (n,) in [0, 1]."""
    c = body.centres_array
    r = body.marker_mm / 2
    dirs = hemisphere_directions(directions, UP)
    blockers = [p for p in body.add if isinstance(p, Cylinder)]  # stems and posts
    out = np.zeros(len(c))
    for i, ci in enumerate(c):
        o = ci + r * dirs * (1 + 1e-9)
        others = [j for j in range(len(c)) if j != i]
        blocked = ray_hits_spheres(o, dirs, c[others], np.full(len(others), r))
        starts, ends, radii = [], [], []
        for cyl in blockers:
            a, b = np.array(cyl.p0), np.array(cyl.p1)
            # only the part outside sphere i can block its own surface
            inside = np.linalg.norm(np.array([a, b]) - ci, axis=1) < r
            if inside.all():
                continue
            if inside.any():
                keep, end = (b, a) if inside[0] else (a, b)
                u = end - keep
                # clip the segment where it leaves sphere i
                f = keep - ci
                qa, qb, qc = u @ u, 2 * f @ u, f @ f - r * r
                t = (-qb - np.sqrt(max(qb * qb - 4 * qa * qc, 0.0))) / (2 * qa)
                a, b = keep, keep + np.clip(t, 0.0, 1.0) * u
            starts.append(a)
            ends.append(b)
            radii.append(cyl.radius_mm)
        if starts:
            dist = ray_segment_distance(o, dirs, np.array(starts), np.array(ends))
            blocked |= (dist < np.array(radii)[None, :]).any(axis=1)
        out[i] = 1.0 - blocked.mean()
    return out
