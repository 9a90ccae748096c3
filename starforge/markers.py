"""The markers labs buy: a catalogue as data (``templates/markers/*.toml``), by name or file.

Each entry gives the finished sphere diameter, how the marker attaches (``glue``: a flat base
stuck to a pad; ``post``: a hole in its base pressed onto a post; ``screw``: a threaded stud
screwed into a bore; ``insert``: the stud in a heat-set insert), the base geometry that seats
it (the distance from its base plane to the sphere centre) and a ``source`` for the numbers.
Where a vendor does not publish a dimension, the entry says the value is starforge's default:
measure your markers and pass an edited copy (``--marker my_marker.toml``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from starforge.catalog import list_templates, load_template, unknown_name, values_from
from starforge.errors import StarforgeError
from starforge.spec import from_mapping, in_range, require


@dataclass(frozen=True)
class Thread:
    """Holes for one ISO metric thread in a print, mm (sources in :data:`THREAD_SOURCES`).

    Attributes
    ----------
    tap_drill_mm : the bore a stud is screwed straight into (ISO 2306 tap-drill diameter)
    insert_hole_mm : the hole a heat-set insert is melted into (its published hole diameter)
    insert_length_mm : the insert's length; the hole is :data:`INSERT_HOLE_EXTRA_MM` deeper
    insert_wall_mm : least plastic round the insert hole
    """

    tap_drill_mm: float
    insert_hole_mm: float
    insert_length_mm: float
    insert_wall_mm: float


#: ISO metric threads starforge seats markers on.  Tap drills: ISO 2306; heat-set inserts: the
#: common brass inserts for 3D prints (ruthex RX-M.. / CNC Kitchen), see :data:`THREAD_SOURCES`.
THREADS = {
    "M2": Thread(1.6, 3.2, 4.0, 1.3),
    "M2.5": Thread(2.05, 3.6, 5.7, 1.5),
    "M3": Thread(2.5, 4.0, 5.7, 1.6),
    "M4": Thread(3.3, 5.6, 8.1, 2.3),
    "M5": Thread(4.2, 6.4, 9.5, 2.6),
}
#: clearance holes a screw of each size passes through, mm: ISO 273, fine series
CLEARANCE_HOLES_MM = {"M2": 2.2, "M2.5": 2.7, "M3": 3.2, "M4": 4.3, "M5": 5.3, "M6": 6.4}


def metric_size(text: str) -> str | None:
    """``"m3"`` -> ``"M3"`` when ``text`` names a metric screw size starforge knows, else None."""
    t = str(text).strip().upper()
    return t if t in CLEARANCE_HOLES_MM else None


def thread_words(thread: str, attach: str) -> str:
    """What an ``M3`` stud's seat is in a print, in words: the tap drill (``screw``) or the insert
    and its hole (``insert``)."""
    th = THREADS[thread]
    if attach == "screw":
        return f"{thread} stud screwed into a {th.tap_drill_mm:g} mm tap-drill bore (ISO 2306)"
    return (
        f"{thread} heat-set insert ({th.insert_length_mm:g} mm long) melted into a {th.insert_hole_mm:g} mm hole"
    )


#: an insert's hole is this much deeper than the insert (room for the plastic it displaces)
INSERT_HOLE_EXTRA_MM = 0.5
THREAD_SOURCES = (
    "tap drills: ISO 2306 (drills for use prior to tapping), coarse pitch: M2 1.6, M2.5 2.05, M3 2.5, "
    "M4 3.3, M5 4.2 mm; heat-set inserts: the standard brass inserts for 3D printing (ruthex RX-M2x4, "
    "RX-M2.5x5.7, RX-M3x5.7, RX-M4x8.1, RX-M5x9.5; CNC Kitchen's standard inserts have the same "
    "lengths and holes): hole diameters 3.2 / 3.6 / 4.0 / 5.6 / 6.4 mm as in the pilot-hole chart "
    "https://www.accu.co.uk/p/488-threaded-insert-hole-size-charts-for-3d-printing-pla-petg-resin, "
    "hole depth = insert length + 0.5 mm as in https://tools.creative3dp.com/blog/heat-set-insert-hole-size-chart; "
    "wall round the hole: 0.4 x the hole diameter rounded up to 0.1 mm (M3: 1.6 mm, ruthex's minimum wall; "
    "within the 0.25-0.9 x outer diameter secam recommends for commodity plastics, "
    "http://secam-fixing.com/inserts/screw-insert/type-1/recommendation-for-the-designer/)"
)


@dataclass(frozen=True)
class MarkerType:
    """One marker kind (lengths in mm)."""

    name: str
    diameter_mm: float
    attach: Literal["glue", "post", "screw", "insert"]
    source: str
    description: str = ""
    base_mm: float = 3.0
    centre_height_mm: float = 2.0
    hole_mm: float | None = None
    hole_depth_mm: float | None = None
    fit_mm: float = 0.1
    thread: str | None = None
    stud_length_mm: float | None = None
    dimensions: Literal["vendor", "default"] = "default"

    def __post_init__(self) -> None:
        in_range("diameter_mm", self.diameter_mm, 1.0, 50.0)
        require(
            self.attach in ("glue", "post", "screw", "insert"),
            f"attach must be glue, post, screw or insert, got {self.attach!r}",
        )
        require(bool(self.source.strip()), f"marker {self.name}: a source is required for its numbers")
        require(
            self.dimensions in ("vendor", "default"),
            f"marker {self.name}: dimensions must be vendor (published) or default (starforge's), "
            f"got {self.dimensions!r}",
        )
        in_range("base_mm", self.base_mm, 0.5, 50.0)
        in_range("centre_height_mm", self.centre_height_mm, 0.0, self.diameter_mm)
        if self.attach == "post":
            require(
                self.hole_mm is not None and self.hole_depth_mm is not None,
                f"marker {self.name}: a post needs hole_mm and hole_depth_mm",
            )
            in_range("hole_mm", self.hole_mm, 0.5, self.diameter_mm)
            in_range("hole_depth_mm", self.hole_depth_mm, 0.5, self.diameter_mm)
            in_range("fit_mm", self.fit_mm, 0.0, 0.5)
        if self.attach in ("screw", "insert"):
            require(
                self.thread in THREADS,
                f"marker {self.name}: thread must be one of {', '.join(THREADS)}, got {self.thread!r}",
            )
            require(self.stud_length_mm is not None, f"marker {self.name}: stud_length_mm is required")
            in_range("stud_length_mm", self.stud_length_mm, 1.0, 30.0)


def seat_hole(kind: str, mt) -> tuple[float, float, float]:
    """(diameter, depth, least wall round it), mm, of a threaded marker's hole: the ISO 2306
    tap drill for ``screw`` (the stud's length + 0.5 mm deep, a 1.2 mm wall), the insert's
    published hole for ``insert`` (its length, or the stud's if longer, + 0.5 mm); see
    :data:`THREAD_SOURCES`."""
    th = THREADS[mt.thread]
    if kind == "screw":
        return th.tap_drill_mm, mt.stud_length_mm + 0.5, 1.2
    depth = max(th.insert_length_mm, mt.stud_length_mm) + INSERT_HOLE_EXTRA_MM
    return th.insert_hole_mm, depth, th.insert_wall_mm


#: a post's pin is this much shorter than the hole in the marker's base, so the marker seats on
#: the shoulder (its designed centre), never on the pin's end
POST_PLAY_MM = 0.3
#: the least length of a printed post, mm, below a threaded marker's hole
POST_FLOOR_MM = 1.0
#: the least width of a printed post, mm (a thinner one snaps when a hand knocks its marker)
POST_MIN_WIDTH_MM = 5.0


@dataclass(frozen=True)
class PostTop:
    """The top of a printed post a marker sits on, mm: the post's width, and the hole cut into it
    (a threaded marker's tap drill or insert, :func:`seat_hole`) or the pin standing on it (a
    post marker's, :data:`POST_PLAY_MM` shorter than its hole); neither for a glued marker."""

    width_mm: float
    words: str
    hole_mm: float = 0.0
    hole_depth_mm: float = 0.0
    pin_mm: float = 0.0
    pin_length_mm: float = 0.0

    @property
    def min_length_mm(self) -> float:
        """The shortest post that holds this top (its hole and :data:`POST_FLOOR_MM` below it)."""
        return self.hole_depth_mm + POST_FLOOR_MM


def post_top(marker: MarkerType | None, base_mm: float) -> PostTop:
    """How ``marker`` (None: a plain ball glued by a base of ``base_mm``) sits on top of a printed
    post: the post is as wide as the marker's base, or as its threaded hole and the wall round it,
    and at least :data:`POST_MIN_WIDTH_MM`."""
    width = max(float(base_mm), POST_MIN_WIDTH_MM)
    if marker is None or marker.attach == "glue":
        return PostTop(width, "its base glued to the post's top")
    if marker.attach == "post":
        pin = marker.hole_mm - marker.fit_mm
        return PostTop(
            width, f"pressed onto a {pin:g} mm pin on the post's top", pin_mm=pin,
            pin_length_mm=marker.hole_depth_mm - POST_PLAY_MM,
        )  # fmt: skip
    d, depth, wall = seat_hole(marker.attach, marker)
    return PostTop(max(width, d + 2.0 * wall), thread_words(marker.thread, marker.attach), hole_mm=d, hole_depth_mm=depth)


def marker_names() -> list[str]:
    """Names of the catalogue's markers, sorted."""
    return list_templates("markers")


def load_marker(name_or_path: str | Path) -> MarkerType:
    """A catalogue entry by name (``9.5mm-m3``) or TOML path; an unknown name lists the known."""
    text = str(name_or_path)
    if not (text.endswith(".toml") or "/" in text or "\\" in text) and text not in marker_names():
        raise unknown_name("marker", "markers", text, "a catalogue marker")
    name, data = load_template("markers", name_or_path)
    with values_from(name_or_path):
        return from_mapping(MarkerType, {"name": name, **data}, where=f"marker {name}")


def marker_diameter_mm(text: str | float) -> float:
    """A finished marker diameter, mm, from a number or a catalogue entry.

    ``12.7``, ``"12.7"`` and ``"12.7mm-m3"`` all give 12.7; a TOML path reads that file.  An
    unknown name raises StarforgeError listing the catalogue; a number outside [1, 50] mm (or
    not finite) is refused naming the range.
    """
    if isinstance(text, bool):
        raise StarforgeError(f"marker must be a diameter in mm or a catalogue name, got {text!r}")
    try:
        v = float(str(text).strip().removesuffix("mm"))
    except (TypeError, ValueError):
        return load_marker(str(text).strip()).diameter_mm
    if not (math.isfinite(v) and 1.0 <= v <= 50.0):
        raise StarforgeError(f"marker diameter must be in [1, 50] mm, got {text}")
    return v
