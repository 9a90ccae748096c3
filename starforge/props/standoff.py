"""The printed stand-off post that lifts a marker off a prop (``starforge place --standoff MM``).

Markers on posts stand clear of the hand and of the prop's own bulk, where markers stuck on a
small prop stay hidden whatever layout is chosen.  The post is a cylinder ``standoff_mm`` long
and as wide as :func:`starforge.markers.post_top` says: the marker's base, or its threaded hole
and the wall round it, at least :data:`starforge.markers.POST_MIN_WIDTH_MM`.  Its foot is glued
to the prop where the layout puts the marker (the seat rules test that foot,
:mod:`starforge.props.seat`); its top holds the marker as the catalogue attaches it: a tap-drill
or insert hole cut from the top, a pin standing on it, or a flat face to glue a base to.  It
prints standing on its foot, with no overhang.  Lengths in mm, as slicers read them.
"""

from __future__ import annotations

import numpy as np

from starforge.markers import post_top

#: segments round the post, its hole and its pin
POST_SEGMENTS = 64


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


def standoff_stl(seat) -> bytes:
    """:func:`standoff_solid` as binary STL bytes, mm."""
    from starforge.meshfiles import stl_bytes

    m = standoff_solid(seat).to_mesh()
    return stl_bytes(np.asarray(m.vert_properties, float)[:, :3], np.asarray(m.tri_verts, np.int64))


def standoff_words(seat, count: int) -> str:
    """One line for the guide and the run's summary: what to print (``count`` posts) and how the
    marker goes on."""
    top = post_top(seat.marker, seat.base_mm)
    return (
        f"every marker stands on a printed {seat.standoff_mm:g} mm post, {seat.base_mm:g} mm across "
        f"(standoff.stl, mm): its foot glued on the mark, the marker {top.words}; print {count}"
    )
