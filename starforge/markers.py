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

from starforge.catalog import list_templates, load_template
from starforge.errors import StarforgeError
from starforge.spec import from_mapping, in_range, require

#: ISO metric threads: (bore for a stud screwed straight into printed plastic, heat-set insert
#: hole diameter, insert length), mm.  The bore is the tap-drill size (about 0.85 x the major
#: diameter); insert holes follow the common brass inserts for 3D prints (starforge's defaults).
THREADS = {
    "M2": (1.7, 3.2, 3.0),
    "M2.5": (2.1, 3.6, 4.0),
    "M3": (2.5, 4.0, 4.0),
    "M4": (3.3, 5.6, 6.0),
    "M5": (4.2, 6.4, 7.0),
}


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


def marker_names() -> list[str]:
    """Names of the catalogue's markers, sorted."""
    return list_templates("markers")


def load_marker(name_or_path: str | Path) -> MarkerType:
    """A catalogue entry by name (``9.5mm-m3``) or TOML path; an unknown name lists the known."""
    text = str(name_or_path)
    if not (text.endswith(".toml") or "/" in text or "\\" in text) and text not in marker_names():
        raise StarforgeError(f"unknown marker {text!r}; known: {', '.join(marker_names())} (or a TOML file)")
    name, data = load_template("markers", name_or_path)
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
