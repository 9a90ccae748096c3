"""The printed stand-off post that lifts a marker off a prop (``starforge place --standoff MM``).

Markers on posts stand clear of the hand and of the prop's own bulk, where markers stuck on a
small prop stay hidden whatever layout is chosen.  The post is a cylinder ``standoff_mm`` long
and as wide as :func:`starforge.markers.post_top` says: the marker's base, or its threaded hole
and the wall round it, at least :data:`starforge.markers.POST_MIN_WIDTH_MM`.  Its foot is glued
to the prop where the layout puts the marker (the seat rules test that foot,
:mod:`starforge.props.seat`); its top holds the marker as the catalogue attaches it: a tap-drill
or insert hole cut from the top, a pin standing on it, or a flat face to glue a base to.  It
prints standing on its foot, with no overhang.  Lengths in mm, as slicers read them.

Where the post stands on a rod instead (:mod:`starforge.props.clamp`), :func:`clamp_solid` puts the
same post on a split ring round the rod: the ring as wide as the post, its bore the rod's, its
wall :data:`starforge.props.clamp.CLAMP_WALL_MM`, cut open opposite the post across
:data:`CLAMP_OPENING` of the rod's diameter so it snaps on.  It prints lying on the ring's face,
the post level with the bed.
"""

from __future__ import annotations

import numpy as np

from starforge.markers import post_top

#: segments round the post, its hole and its pin
POST_SEGMENTS = 64
#: a clamp's opening, as a share of the rod's diameter (narrower than the rod: it snaps on)
CLAMP_OPENING = 0.8
#: rods of diameters this close (mm) take one clamp
CLAMP_ROUND_MM = 0.1


def standoff_solid(seat):
    """The post under one marker of ``seat`` (a :class:`starforge.props.seat.Seat` with a
    stand-off) as a manifold3d ``Manifold``, mm: the foot on z = 0, the marker's seat at
    z = ``seat.standoff_mm``."""
    from manifold3d import Manifold

    if seat.standoff_mm <= 0:
        raise ValueError("standoff_solid needs a seat with a stand-off (starforge.props.seat.with_standoff)")
    top = post_top(seat.marker, seat.base_mm)
    h, r = seat.standoff_mm, seat.base_mm / 2.0
    post = Manifold.cylinder(h, r, r, POST_SEGMENTS)
    if top.hole_mm > 0:
        hole = Manifold.cylinder(top.hole_depth_mm + 1.0, top.hole_mm / 2, top.hole_mm / 2, POST_SEGMENTS)
        post = post - hole.translate((0.0, 0.0, h - top.hole_depth_mm))
    if top.pin_mm > 0:
        pin = Manifold.cylinder(top.pin_length_mm + 0.2, top.pin_mm / 2, top.pin_mm / 2, POST_SEGMENTS)
        post = post + pin.translate((0.0, 0.0, h - 0.2))
    return post


def clamp_solid(seat, rod_mm: float):
    """The post under one marker of ``seat`` on a split ring round a rod ``rod_mm`` across, as a
    manifold3d ``Manifold``, mm: the ring's axis along z from z = 0 to its width, the post along
    +x from the rod's surface (x = ``rod_mm / 2``) to the marker's seat ``seat.standoff_mm``
    further, its side level with z = 0."""
    from manifold3d import Manifold

    from starforge.props.clamp import ring_radii_mm

    (r, outer), width = ring_radii_mm(rod_mm), seat.base_mm
    ring = Manifold.cylinder(width, outer, outer, POST_SEGMENTS)
    post = standoff_solid(seat).rotate((0.0, 90.0, 0.0)).translate((r, 0.0, width / 2.0))
    bore = Manifold.cylinder(width + 2.0, r, r, POST_SEGMENTS).translate((0.0, 0.0, -1.0))
    gap = CLAMP_OPENING * rod_mm
    slot = Manifold.cube((outer + 1.0, gap, width + 2.0)).translate((-(outer + 1.0), -gap / 2.0, -1.0))
    return (ring + post) - bore - slot


def clamp_size(rod_mm: float) -> float:
    """The clamp a rod ``rod_mm`` across takes: its diameter rounded to :data:`CLAMP_ROUND_MM`."""
    return round(round(float(rod_mm) / CLAMP_ROUND_MM) * CLAMP_ROUND_MM, 3)


def clamp_sizes(rods_mm) -> list[float]:
    """The clamps a layout needs (:func:`clamp_size` of its rods), once each, smallest first."""
    return sorted({clamp_size(d) for d in rods_mm})


def clamps_solid(seat, rods_mm):
    """One :func:`clamp_solid` for each size of :func:`clamp_sizes`, side by side along y, mm."""
    from manifold3d import Manifold

    out, y = Manifold(), 0.0
    for d in clamp_sizes(rods_mm):
        part = clamp_solid(seat, d)
        lo, hi = np.asarray(part.bounding_box()[:3]), np.asarray(part.bounding_box()[3:])
        out += part.translate((0.0, y - lo[1], 0.0))
        y += float(hi[1] - lo[1]) + 5.0
    return out


def solid_stl(solid) -> bytes:
    """A manifold3d ``Manifold`` as binary STL bytes, mm."""
    from starforge.meshfiles import stl_bytes

    m = solid.to_mesh()
    return stl_bytes(np.asarray(m.vert_properties, float)[:, :3], np.asarray(m.tri_verts, np.int64))


def standoff_stl(seat) -> bytes:
    """:func:`standoff_solid` as binary STL bytes, mm."""
    return solid_stl(standoff_solid(seat))


def standoff_words(seat, rods_mm) -> str:
    """One line for the guide and the run's summary: what to print and how the marker goes on;
    ``rods_mm``: per marker, the rod its post is clamped round (mm; 0: it stands on its foot)."""
    top = post_top(seat.marker, seat.base_mm)
    rods = np.asarray(rods_mm, float)
    feet = int((rods <= 0).sum())
    text = (
        f"every marker stands on a printed {seat.standoff_mm:g} mm post, {seat.base_mm:g} mm across "
        f"(standoff.stl, mm): its foot glued on the mark, the marker {top.words}; print {feet}"
    )
    for d in clamp_sizes(rods[rods > 0]):
        on = [str(i + 1) for i, rod in enumerate(rods) if rod > 0 and clamp_size(rod) == d]
        text += (
            f"; {'marker' if len(on) == 1 else 'markers'} {', '.join(on)}: the post on a split ring snapped round "
            f"the {d:g} mm rod (clamps.stl), print {len(on)}"
        )
    return text
