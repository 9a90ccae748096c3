"""One printable body per star, as plain data both CAD backends build the same way.

How a body sits (the design decision, in the placement frame of ``family.json``):

- the sphere centres stay exactly where family.json puts them;
- "up" is +y, the family box's shortest side: the star lies flat on the object (its long side
  along a finger segment) and the cameras see it from above;
- the mount is a plate under the star, its top face ``standoff_mm`` below the lowest finished
  sphere; a stem runs from the plate to each sphere, vertical where it can be, tilted where a
  vertical stem would pass through (or too close to) another sphere or stem;
- the star id is engraved in a pixel font (:mod:`starforge.cad.label`) on the plate's top face, in a free spot
  (the plate grows at its -z end when there is none).

The whole body, with the *finished* (coated) spheres, is compared against the family's size
limit (sorted sides, so any axis assignment counts): :func:`fit_report`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from starforge.cad.label import label_boxes, label_counters, label_size  # noqa: F401 (the label's home; kept importable here)
from starforge.cad.mounts import Mount, mount_geometry
from starforge.cad.primitives import Cylinder, Revolved, Sphere, fillet_profile
from starforge.cad.stems import route_stems
from starforge.geometry.distance import segment_segment_distance
from starforge.markers import POST_PLAY_MM, seat_hole
from starforge.spec import in_range, require

UP = np.array([0.0, 1.0, 0.0])
#: features of different markers stay this many nozzle widths apart (``BodySpec.clearance_mm``)
CLEARANCE_NOZZLES = 2.0
#: what a stem can end in (``BodySpec.seat``)
SEATS = ("sphere", "glue", "post", "screw", "insert")
#: the seats that suit a catalogue marker, by its attachment (a printed sphere always does)
SEATS_FOR = {
    "glue": ("glue", "sphere"),
    "post": ("post", "sphere"),
    "screw": ("screw", "insert", "sphere"),
    "insert": ("insert", "screw", "sphere"),
}
#: a stem's root fillet reaches this far into the plate below its face (one solid, no seam)
FILLET_BURIED_MM = 0.3
#: a root fillet's top ends this far inside its stem (beyond the stem's tilt and both circles'
#: tessellation, < 0.01 mm at the default segments), so the stem swallows the fillet's flat end
FILLET_INSET_MM = 0.05
#: a seat wider than its stem (a pad, an insert boss) stands on a cone round the stem that
#: flares out to it: its half-angle is 45 deg less the stem's tilt (every side then rises at
#: least 45 deg from the bed), but at least this much (the cone stays short on steep stems)
SEAT_CONE_MIN_DEG = 25.0


@dataclass(frozen=True)
class BodySpec:
    """How to turn a star into a printable body.  Lengths in mm.

    Attributes
    ----------
    coating_mm : float
        Coating allowance on the diameter: printed sphere = marker_mm - coating_mm
        (paper: 3.8 mm printed, 4 mm finished -> 0.2).  Range [0, marker_mm / 2].
    seat : "sphere", "post", "glue", "screw", "insert" or None
        What each stem ends in: a printed sphere, or a seat for a bought marker: a post with a
        shoulder (a hole in the marker's base), a pad (a flat base glued on), a bore (a threaded
        stud screwed in) or a heat-set insert hole.  None: the catalogue marker's own attachment
        (``marker``), else a printed sphere.  With a catalogue marker the seat must suit it
        (:data:`SEATS_FOR`): a printed sphere in its place, or its attachment (a threaded marker
        takes a bore or an insert).
    marker : str or None
        A catalogue marker (``starforge.markers``: name or TOML file); its attachment, base and
        centre height shape the seat, and its diameter must be the family's.
    post_mm : float
        Post diameter for ``tip = "post"`` without a catalogue marker, range [0.8, 4].
    post_length_mm : float
        How far that post reaches into the marker from its seat, range [0.5, 6].
    stem_mm : float or None
        Stem diameter; None scales it with the marker (0.45 x, within [min_stem_mm, 4]).
    min_stem_mm : float
        Printable minimum stem diameter (SLS nylon: about 0.8 mm).  Range [0.3, 4].
    fillet_mm : float or None
        Radius of the concave fillet rounding each stem's root into the plate (about the plate's
        normal, 6 facets; it adds this much to the root's radius at the plate); None: half the
        stem diameter.  Kept below the lowest marker (at most standoff - 0.1).  [0, 4].
    standoff_mm : float
        Gap between the lowest finished sphere and the plate (room for the foil), [0.2, 10].
    clearance_mm : float or None
        Least gap between a stem and another (finished) marker or stem, [0, 4]; None: two
        nozzle widths (:data:`CLEARANCE_NOZZLES`), so a slicer keeps the two apart instead of
        fusing them or stringing between them.
    max_tilt_deg : float
        A stem leans at most this far from vertical, [0, 60] (FDM: keep it <= 45).
    nozzle_mm : float
        The printer's nozzle: engraved strokes, counters and gaps are at least 2 x as wide,
        [0.1, 1.2].
    label : bool
        Engrave the star id on the plate.
    label_mm : float
        Digit height (raised when the nozzle needs wider strokes), [1.5, 8].
    label_depth_mm : float
        Engraving depth, [0.2, 1.5].
    min_visibility : float
        Warn when a sphere's upper hemisphere is less free than this fraction, [0, 1].
    sphere_segments, cylinder_segments : int
        Tessellation of the mesh backend (STL/3MF), [16, 256].
    """

    coating_mm: float = 0.2
    seat: Literal["sphere", "post", "glue", "screw", "insert"] | None = None
    marker: str | None = None
    post_mm: float = 1.5
    post_length_mm: float = 2.0
    stem_mm: float | None = None
    min_stem_mm: float = 0.8
    fillet_mm: float | None = None
    standoff_mm: float = 1.0
    clearance_mm: float | None = None
    max_tilt_deg: float = 40.0
    nozzle_mm: float = 0.4
    label: bool = True
    label_mm: float = 2.5
    label_depth_mm: float = 0.6
    min_visibility: float = 0.6
    sphere_segments: int = 64
    cylinder_segments: int = 48

    def __post_init__(self) -> None:
        require(
            self.seat is None or self.seat in SEATS,
            f"seat must be one of {', '.join(SEATS)}, got {self.seat!r}",
        )
        in_range("coating_mm", self.coating_mm, 0.0, 10.0)
        in_range("post_mm", self.post_mm, 0.8, 4.0)
        in_range("post_length_mm", self.post_length_mm, 0.5, 6.0)
        in_range("min_stem_mm", self.min_stem_mm, 0.3, 4.0)
        if self.stem_mm is not None:
            require(
                math.isfinite(float(self.stem_mm)) and self.stem_mm >= self.min_stem_mm,
                f"stem_mm must be >= the printable minimum min_stem_mm={self.min_stem_mm}, got {self.stem_mm}",
            )
            in_range("stem_mm", self.stem_mm, self.min_stem_mm, 4.0)
        if self.fillet_mm is not None:
            in_range("fillet_mm", self.fillet_mm, 0.0, 4.0)
        in_range("standoff_mm", self.standoff_mm, 0.2, 10.0)
        if self.clearance_mm is not None:
            in_range("clearance_mm", self.clearance_mm, 0.0, 4.0)
        in_range("max_tilt_deg", self.max_tilt_deg, 0.0, 60.0)
        in_range("nozzle_mm", self.nozzle_mm, 0.1, 1.2)
        in_range("label_mm", self.label_mm, 1.5, 8.0)
        in_range("label_depth_mm", self.label_depth_mm, 0.2, 1.5)
        in_range("min_visibility", self.min_visibility, 0.0, 1.0)
        in_range("sphere_segments", self.sphere_segments, 16, 256)
        in_range("cylinder_segments", self.cylinder_segments, 16, 256)

    def stem_for(self, marker_mm: float) -> float:
        """The stem diameter in effect for ``marker_mm`` markers, mm."""
        if self.stem_mm is not None:
            return float(self.stem_mm)
        return float(min(4.0, max(self.min_stem_mm, 0.45 * marker_mm)))

    def clearance(self) -> float:
        """The stem clearance in effect, mm: ``clearance_mm``, else two nozzle widths."""
        return CLEARANCE_NOZZLES * self.nozzle_mm if self.clearance_mm is None else float(self.clearance_mm)

    def fillet_for(self, marker_mm: float) -> float:
        """The fillet (radius added at the stem root) in effect, mm."""
        return self.stem_for(marker_mm) / 2 if self.fillet_mm is None else float(self.fillet_mm)

    def label_height(self) -> float:
        """Digit height in effect, mm: 5 pixels of :func:`starforge.cad.label.pixel_mm` (strokes,
        counters and gaps are whole pixels, each at least 2 nozzle widths)."""
        from starforge.cad.label import ROWS, pixel_mm

        return ROWS * pixel_mm(self.label_mm, self.nozzle_mm)


@dataclass(frozen=True)
class Body:
    """A printable star body (plain data).

    Attributes
    ----------
    star_id : int
    name : str                       ``star_<id>``, the STEP solid's name and the file stem
    add : tuple of primitives        united: spheres (or posts), stems, the mount's plate
    subtract : tuple of primitives   cut from the union: holes, slots, pockets, label digits
    centres : (4, 3) float, mm       marker centres (family.json's vertices)
    marker_mm : float                finished marker diameter
    printed_mm : float or None       printed sphere diameter (None for posts)
    stems : tuple of Cylinder        stem axes (root on the plate -> sphere)
    mount : str                      mount template name
    label : str                      engraved text
    label_counters : tuple           the label's counters (raised islands inside 0, 4, 6, 8, 9) as
                                     (x0, x1, z0, z1) mm on the plate's top face (placement frame)
    label_face_y : float or None     that face's height, mm (the engraving reaches label_depth below)
    """

    star_id: int
    name: str
    add: tuple
    subtract: tuple
    centres: tuple
    marker_mm: float
    printed_mm: float | None
    stems: tuple
    mount: str
    label: str
    label_counters: tuple = ()
    label_face_y: float | None = None

    @property
    def centres_array(self) -> np.ndarray:
        return np.array(self.centres, dtype=float)


def body_name(star_id: int) -> str:
    """File stem and STEP name of a star's body: ``star_007``."""
    return f"star_{int(star_id):03d}"


# ---------------------------------------------------------------------------------------------
def body_spec_for(marker: str | None, seat: str | None, marker_mm: float) -> BodySpec:
    """The default body for a catalogue ``marker`` (or None) and a ``seat`` (or None), checked
    against ``marker_mm`` up front (the marker's diameter, the seat suiting it); what
    ``starforge stars --mount`` designs a family for."""
    spec = BodySpec(marker=marker, seat=seat)
    seat_kind(spec, marker_mm)
    return spec


def seat_kind(spec: BodySpec, marker_mm: float):
    """(seat kind, marker type or None) for a body: ``spec.seat``, by default the catalogue
    marker's attachment (a printed sphere without one).  Raises StarforgeError for a marker of
    another diameter, a seat that does not suit the marker, or a threaded seat without one."""
    if spec.marker is None:
        kind = spec.seat or "sphere"
        require(
            kind in ("sphere", "post", "glue"),
            f"seat {kind} needs a catalogue marker (--marker NAME: its thread and stud)",
        )
        return kind, None
    from starforge.markers import load_marker

    mt = load_marker(spec.marker)
    require(
        abs(mt.diameter_mm - marker_mm) <= 0.05,
        f"marker {mt.name} is {mt.diameter_mm:g} mm; this family is designed for {marker_mm:g} mm markers",
    )
    kind = spec.seat or mt.attach
    require(
        kind in SEATS_FOR[mt.attach],
        f"seat {kind} does not suit marker {mt.name} ({mt.attach}); choose one of {', '.join(SEATS_FOR[mt.attach])}",
    )
    return kind, mt


def _seat_depth(kind: str, mt, spec: BodySpec, marker_mm: float) -> float:
    """How far below the marker centre the seat's parts reach (the plate stays below them), mm."""
    rf = marker_mm / 2
    if kind == "sphere":
        return rf
    if mt is None:
        return rf + 1.0
    if kind in ("post", "glue"):
        return mt.centre_height_mm + 1.0
    _, hole_len, _ = seat_hole(kind, mt)
    return mt.centre_height_mm + hole_len + 1.0


def plate_gap_mm(spec: BodySpec, marker_mm: float) -> float:
    """How far the plate's top face lies below the lowest finished marker's surface, mm: the
    standoff, or more where a bought marker's seat reaches further down."""
    kind, mt = seat_kind(spec, marker_mm)
    rf = marker_mm / 2
    return max(spec.standoff_mm, _seat_depth(kind, mt, spec, marker_mm) + 0.5 - rf)


def root_fillet_mm(spec: BodySpec, marker_mm: float) -> float:
    """The stem-root fillet radius in effect, mm: ``spec``'s, kept 0.1 mm below the lowest marker."""
    return float(min(spec.fillet_for(marker_mm), plate_gap_mm(spec, marker_mm) - 0.1))


def _tip_parts(kind: str, mt, spec: BodySpec, cen, u, marker_mm: float, stem_r: float, root=None):
    """(what the stem runs to, parts added, parts cut) for one marker's seat.

    ``cen`` is the marker centre, ``u`` the unit stem direction (root -> centre), ``root`` where
    the stem leaves the plate (a seat block's cone starts no lower).  Bought markers
    sit on a seat whose top lies ``centre_height`` below the centre along the stem, so the marker
    ends up exactly where family.json puts it.
    """
    rf = marker_mm / 2
    if kind == "sphere":
        printed = marker_mm - spec.coating_mm
        return cen, [Sphere(cen, printed / 2)], []
    if mt is None:  # a plain post: a shoulder at the marker's surface, the pin into its base
        h_c, base, pin, depth = (
            rf,
            max(spec.post_mm * 1.8, 2 * stem_r + 0.8),
            spec.post_mm,
            spec.post_length_mm + POST_PLAY_MM,  # the hole this pin of post_length_mm needs
        )
    else:
        h_c, base = mt.centre_height_mm, mt.base_mm
        pin = (mt.hole_mm - mt.fit_mm) if mt.hole_mm is not None else None
        depth = mt.hole_depth_mm
    seat = cen - h_c * u  # the marker's base plane meets the stem axis here
    adds, cuts = [], []
    if kind in ("post", "glue"):
        adds.append(seat_block(seat, u, 1.0, max(base, 2 * stem_r + 0.4) / 2, stem_r, root))
        if kind == "post":  # the pin stops short of the hole's bottom: the base seats on the shoulder
            adds.append(Cylinder(seat - 0.2 * u, seat + (depth - POST_PLAY_MM) * u, pin / 2))
        return seat - 0.5 * u, adds, cuts  # the stem runs into the pad: one piece
    hole_d, hole_len, wall = seat_hole(kind, mt)
    boss_d = max(hole_d + 2 * wall, 2 * stem_r + 0.4)
    boss_len = hole_len + 1.0
    adds.append(seat_block(seat, u, boss_len, boss_d / 2, stem_r, root))
    cuts.append(Cylinder(seat - hole_len * u, seat + 0.5 * u, hole_d / 2))
    return seat - (boss_len - 0.5) * u, adds, cuts  # into the boss, below the hole


def root_fillet(root, u, stem_radius_mm: float, fillet_mm: float) -> Revolved:
    """The fillet round a stem's root (the plate's face at ``root`` (3,), the stem along the unit
    ``u``), revolved about the plate's normal; its top ends inside the stem's cross-section at
    that height (a tilted stem's axis has moved ``height * tan(tilt)`` from the root by then), by
    :data:`FILLET_INSET_MM`.  A stem tilted so far that the arc cannot end inside at full height
    gets a lower fillet."""
    rs, f = float(stem_radius_mm), float(fillet_mm)
    u = np.asarray(u, float)
    tan = math.sqrt(max(0.0, 1.0 - u[1] ** 2)) / max(u[1], 1e-9)
    room = 0.9 * rs - FILLET_INSET_MM  # the arc's end stays at least 0.1 rs from the axis
    if tan > 0 and f * tan > room:
        f = max(room, 0.0) / tan
    inset = f * tan + FILLET_INSET_MM
    root = np.asarray(root, float)
    return Revolved(root - FILLET_BURIED_MM * UP, root + f * UP, fillet_profile(rs, f, FILLET_BURIED_MM, inset_mm=inset))


def seat_block(seat, u, length_mm: float, radius_mm: float, stem_radius_mm: float, root=None) -> Revolved:
    """A seat's block (a pad or an insert boss): a cylinder of ``radius_mm`` and ``length_mm``
    along the unit stem direction ``u`` (3,), its top face the marker's base plane at ``seat``
    (3,) mm, standing on a cone that flares out from inside the stem (``stem_radius_mm``).

    The cone's half-angle about the stem is 45 deg less the stem's tilt, at least
    :data:`SEAT_CONE_MIN_DEG`: on a stem up to 20 deg from vertical every side of it rises at
    least 45 deg from the bed.  Without it the block's rim overhangs the stem flat, and on a tilted
    stem its lowest rim starts in mid-air (the limb families' post pads and insert bosses).  It
    starts :data:`FILLET_INSET_MM` inside the stem, so the stem swallows its flat end, and no
    lower than the stem's ``root`` (3,) on the plate (steeper where the stem is that short)."""
    u = np.asarray(u, float)
    seat = np.asarray(seat, float)
    R, rs = float(radius_mm), float(stem_radius_mm)
    tilt = math.degrees(math.acos(min(1.0, max(-1.0, u[1]))))
    flare = R - (rs - FILLET_INSET_MM)
    if flare <= 0:  # no wider than the stem: a plain cylinder (a revolved rectangle)
        return Revolved(seat - length_mm * u, seat, ((0.0, R), (length_mm, R)))
    alpha = math.radians(max(45.0 - tilt, SEAT_CONE_MIN_DEG))
    cone = flare / math.tan(alpha)
    if root is not None:  # the stem's length from its root to the block's bottom
        room = float((seat - length_mm * u - np.asarray(root, float)) @ u)
        cone = min(cone, max(room, 1e-3))
    return Revolved(
        seat - (length_mm + cone) * u,
        seat,
        ((0.0, rs - FILLET_INSET_MM), (cone, R), (cone + length_mm, R)),
    )


def build_body(star_id: int, centres, marker_mm: float, mount: Mount, spec: BodySpec) -> Body:
    """The body description of one star (pure: no CAD kernel involved).

    Parameters
    ----------
    star_id : int
    centres : (4, 3) float, mm, placement frame (family.json's vertices)
    marker_mm : float, finished marker diameter
    mount : :class:`~starforge.cad.mounts.Mount`
    spec : :class:`BodySpec`
    """
    c = np.asarray(centres, float)
    require(c.ndim == 2 and c.shape[1] == 3 and np.isfinite(c).all(), "centres must be (n, 3) finite mm")
    rf = marker_mm / 2
    stem_mm = spec.stem_for(marker_mm)
    rs = stem_mm / 2
    kind, mt = seat_kind(spec, marker_mm)
    require(
        spec.coating_mm <= marker_mm / 2,
        f"coating_mm must be in [0, {marker_mm / 2:g}] (half the marker diameter), got {spec.coating_mm}",
    )
    printed = None
    if kind == "sphere":
        printed = marker_mm - spec.coating_mm
        require(
            printed > stem_mm,
            f"coating_mm={spec.coating_mm} leaves a printed sphere of {printed:.2f} mm, not wider than the stem ({stem_mm:g} mm)",
        )
    elif kind == "post" and mt is None:
        require(spec.post_mm < marker_mm, f"post_mm={spec.post_mm} must be < marker_mm={marker_mm}")
    below = plate_gap_mm(spec, marker_mm) + rf
    y_top = float(c[:, 1].min() - below)
    roots = route_stems(c, rf, rs, y_top, spec.clearance(), spec.max_tilt_deg)
    # the material under the label: thinner mounts cannot take a deep engraving
    floor = mount["thickness_mm"]
    if mount.kind == "magnet":
        floor = mount["floor_mm"]
    elif mount.kind == "adhesive":
        floor = mount["thickness_mm"] - mount["recess_mm"]
    text = str(int(star_id))
    label_h = spec.label_height()
    if spec.label:
        require(
            spec.label_depth_mm <= floor - 0.3,
            f"label_depth_mm={spec.label_depth_mm} leaves less than 0.3 mm of the {mount.name} mount "
            f"({floor:.2f} mm under the label)",
        )
    fillet = root_fillet_mm(spec, marker_mm)
    mg = mount_geometry(
        mount,
        roots[:, [0, 2]],
        rs + fillet,
        y_top,
        label_size(text, label_h) if spec.label else None,
        overhead_xz=np.column_stack([c[:, 0], c[:, 2], np.full(len(c), rf)]),
    )
    adds: list = []
    subs: list = []
    stems = []
    for root, cen in zip(roots, c, strict=True):
        u = (cen - root) / np.linalg.norm(cen - root)
        start = root - u * (0.3 / max(u[1], 1e-6))  # 0.3 mm into the plate
        end, parts, cuts = _tip_parts(kind, mt, spec, cen, u, marker_mm, rs, root)
        stem = Cylinder(start, end, rs)
        stems.append(stem)
        adds.append(stem)
        if fillet > 0:  # a fillet round the root, about the plate's normal: no notch at the plate
            adds.append(root_fillet(root, u, rs, fillet))
        adds.extend(parts)
        subs.extend(cuts)
    adds.extend(mg.add)
    subs.extend(mg.subtract)
    if spec.label:
        subs.extend(label_boxes(text, label_h, mg.label_centre, y_top, spec.label_depth_mm))
    return Body(
        star_id=int(star_id),
        name=body_name(star_id),
        add=tuple(adds),
        subtract=tuple(subs),
        centres=tuple(map(tuple, c.tolist())),
        marker_mm=float(marker_mm),
        printed_mm=printed,
        stems=tuple(stems),
        mount=mount.name,
        label=text if spec.label else "",
        label_counters=tuple(label_counters(text, label_h, mg.label_centre)) if spec.label else (),
        label_face_y=float(y_top) if spec.label else None,
    )


def closest_features_mm(body: Body) -> float:
    """The smallest gap between features of two different markers, mm: a stem (above the
    plate, as routed: root -> marker centre) and another marker's finished sphere, or two stems.
    What :func:`route_stems` keeps at least ``BodySpec.clearance()``; an independent re-check
    (exact segment distances).  The plate joins every stem on purpose and does not count."""
    c = body.centres_array
    rf = body.marker_mm / 2
    gaps = []
    segs = []
    for st in body.stems:
        p0, p1 = np.array(st.p0), np.array(st.p1)
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        root = p0 + u * (0.3 / max(u[1], 1e-6))  # where it leaves the plate
        segs.append((root, p1, st.radius_mm))
    for i, (a0, a1, ra) in enumerate(segs):
        for j in range(len(c)):
            if j != i:
                d = segment_segment_distance(a0, a1, c[j], c[j])
                gaps.append(d - ra - rf)
        for k in range(i + 1, len(segs)):
            b0, b1, rb = segs[k]
            gaps.append(segment_segment_distance(a0, a1, b0, b1) - ra - rb)
    return float(min(gaps)) if gaps else float("inf")


def body_bounds(body: Body, finished: bool = True) -> np.ndarray:
    """(2, 3) bounds of the body, mm; ``finished`` counts the coated spheres (marker_mm)."""
    b = [p.bounds() for p in body.add]
    if finished:
        c = body.centres_array
        b.append(np.array([c.min(0) - body.marker_mm / 2, c.max(0) + body.marker_mm / 2]))
    b = np.array(b)
    return np.array([b[:, 0].min(0), b[:, 1].max(0)])


@dataclass(frozen=True)
class FitReport:
    """The body against the family's size limit (sorted sides, mm).

    Attributes
    ----------
    size_mm : (3,) the body's sides along x, y, z (finished spheres)
    limit_mm : (3,) the family's box_mm
    excess_mm : (3,) by how much each sorted side exceeds the sorted limit (0 where it fits)
    fits : bool
    """

    size_mm: tuple
    limit_mm: tuple
    excess_mm: tuple
    fits: bool

    @property
    def worst_mm(self) -> float:
        return float(max(self.excess_mm))

    def message(self, name: str) -> str:
        s = " x ".join(f"{v:.2f}" for v in self.size_mm)
        lim = " x ".join(f"{v:g}" for v in self.limit_mm)
        return f"{name}: body {s} mm exceeds the size limit {lim} mm by {self.worst_mm:.2f} mm"


def fit_report(body: Body, limit_mm) -> FitReport:
    """Compare the body's sorted sides with the sorted limit (any axis assignment); a limit of
    None (a tool read from a tracker file) is met by any body."""
    b = body_bounds(body)
    size = b[1] - b[0]
    lim = np.full(3, np.inf) if limit_mm is None else np.asarray(limit_mm, float)
    excess = np.maximum(np.sort(size) - np.sort(lim) - 1e-9, 0.0)
    return FitReport(
        size_mm=tuple(float(v) for v in size),
        limit_mm=tuple(float(v) for v in lim),
        excess_mm=tuple(float(v) for v in excess),
        fits=bool((excess <= 0).all()),
    )
