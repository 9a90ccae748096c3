"""The room a mount needs, so a family designed for it has bodies that fit the size limit.

A body is the star's finished spheres plus stems and the mount (see :mod:`starforge.cad.body`):
up is the box's shortest side, the plate lies under the star, the star's long side runs along
the plate's length.  Against the sorted size limit the mount costs:

* shortest side: the standoff under the lowest sphere plus the mount's depth (plate thickness;
  the saddle's rails, the magnet's pocket and floor, the strap's roof, tunnel and floor), exactly;
* middle and longest sides: the plate's edge beyond the outer spheres, twice: stem radius +
  root fillet + margin - sphere radius when positive.

These are what every body needs.  Some bodies need more (a label or a screw hole that finds no
free spot grows the plate; a pad or magnet wider than the star): :func:`bodies_fit` builds the
bodies of a family and tells which fit, so ``starforge stars --mount NAME`` can replace the ones
that do not and ``export`` never has to refuse such a family.
"""

from __future__ import annotations

import numpy as np

from starforge.cad.body import BodySpec, build_body, fit_report
from starforge.cad.mounts import Mount, load_mount
from starforge.errors import StarforgeError


def mount_depth_mm(mount: Mount) -> float:
    """How far the mount reaches below the plate's top face, mm."""
    p = mount.params
    t = p["thickness_mm"]
    if mount.kind == "magnet":
        from starforge.cad.mounts import magnet_chamfer_mm

        return max(t, p["magnet_height_mm"] + magnet_chamfer_mm(p) + p["floor_mm"])
    if mount.kind == "strap":
        from starforge.cad.mounts import strap_roof_mm

        return t + p["slot_mm"] + strap_roof_mm(p) + p["floor_mm"]
    if mount.kind == "saddle":
        from starforge.cad.mounts import saddle_profile

        return t + saddle_profile(p)[0]
    return t


def mount_reserve_mm(
    mount: Mount | str, marker_mm: float, spec: BodySpec | None = None
) -> tuple[float, float, float]:
    """Millimetres of the size limit's shortest, middle and longest side the mount needs."""
    m = load_mount(mount) if isinstance(mount, str) else mount
    spec = spec or BodySpec()
    from starforge.cad.body import plate_gap_mm, root_fillet_mm

    rf = marker_mm / 2
    rs = spec.stem_for(marker_mm) / 2
    edge = max(0.0, rs + root_fillet_mm(spec, marker_mm) + m["margin_mm"] - rf)
    short = plate_gap_mm(spec, marker_mm) + mount_depth_mm(m)
    middle = 2 * edge
    longest = 2 * edge
    return (round(short, 6), round(middle, 6), round(longest, 6))


def bodies_fit(
    vertices, marker_mm: float, limit_mm, mount: Mount | str, spec: BodySpec | None = None
) -> np.ndarray:
    """Which stars (placement-frame centres, (n, 4, 3) mm) make bodies inside ``limit_mm``.

    A star whose body cannot be built at all (no clear stem route) counts as not fitting.
    """
    m = load_mount(mount) if isinstance(mount, str) else mount
    spec = spec or BodySpec()
    out = np.zeros(len(vertices), dtype=bool)
    for i, V in enumerate(vertices):
        try:
            out[i] = fit_report(build_body(i + 1, V, marker_mm, m, spec), limit_mm).fits
        except StarforgeError:
            out[i] = False
    return out
