"""What every tracker-format module shares: number text, XML bytes, size checks, number parsing.

Format modules import only this module (never each other, the bodies or the commands).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError

#: tracker files larger than this are refused before parsing (a body file is a few kB)
MAX_FILE_BYTES = 64 * 1024**2


@dataclass(frozen=True)
class WriteContext:
    """What a writer needs besides the body's name and points.

    index : int                   the body's position in the export (colours)
    geometry_id : int             a lab-unique numeric id (Atracsys geometry id)
    marker_radius_mm : float      marker sphere radius, mm
    normals : (n, 3) float or None   unit direction each marker faces (None: +z, the star's
        placement frame faces up)
    tolerances : dict             identification tolerances for the files
        (:func:`starforge.tracking.tolerances.export_tolerances`): ``noise_mm``,
        ``bone_length_tolerance_mm``, ``maximum_residual_mm``, ``max_marker_error_mm``
    min_markers : int             markers a tracker needs to report the body
    marker_names : tuple of str or None   each marker's name, in order (None: the format's own
        numbering)
    """

    index: int = 0
    geometry_id: int = 1
    marker_radius_mm: float = 2.0
    normals: np.ndarray | None = None
    tolerances: dict = field(default_factory=dict)
    min_markers: int = 3
    marker_names: tuple[str, ...] | None = None


#: what a body record may carry besides its points (the names :data:`Record` fields use)
FIELDS = ("marker_names", "body_id", "normals", "marker_mm", "tolerances", "min_markers")


@dataclass(frozen=True)
class Record:
    """One rigid body as a tracker file holds it: its points and what else the file says.

    name : str                                 the body's name in the file (or the file's stem)
    points_mm : (n, 3) float, mm               marker centres, in the file's order
    marker_names : tuple of str or None        each marker's name, where the file names them
    body_id : int or None                      the file's numeric id of the body
    normals : (n, 3) float or None             unit direction each marker faces
    marker_mm : float or None                  marker sphere diameter, mm
    tolerances : dict                          identification tolerances the file states, mm:
        ``bone_length_tolerance_mm``, ``maximum_residual_mm``, ``max_marker_error_mm``
    min_markers : int or None                  markers the tracker needs to report the body
    """

    name: str
    points_mm: np.ndarray
    marker_names: tuple[str, ...] | None = None
    body_id: int | None = None
    normals: np.ndarray | None = None
    marker_mm: float | None = None
    tolerances: dict = field(default_factory=dict)
    min_markers: int | None = None

    def carried(self) -> set[str]:
        """The fields of :data:`FIELDS` this record has a value for (a tolerance by its key)."""
        have = {f for f in FIELDS if f != "tolerances" and getattr(self, f) is not None}
        return have | set(self.tolerances)


def points_of(records: list[Record]) -> dict[str, np.ndarray]:
    """{name: (n, 3) mm} of records (the plain readers' result)."""
    return {r.name: r.points_mm for r in records}


def f2s(x: float) -> str:
    """Python's shortest round-trip text of a float (reading it back gives the same double)."""
    return repr(float(x))


def noise_note(tolerances: dict, gates: str, verb: str = "keep", tail: str = "") -> str | None:
    """The comment a file carries about the noise its tolerances assume (None when the
    tolerances were not derived from a noise): ``gates`` names the file's own fields."""
    t = tolerances
    if "noise_mm" not in t:
        return None
    return (
        f"starforge: {gates} {verb} >= {100 * t['keep']:g} % of frames at {t['noise_mm']:g} mm "
        f"marker noise per axis (see trackers.json){tail}"
    )


def xml_bytes(root: ET.Element, comment: str | None = None) -> bytes:
    """UTF-8 XML with a declaration; ``comment`` goes first inside the root element."""
    if comment:
        root.insert(0, ET.Comment(f" {comment} "))
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def check_size(path) -> None:
    size = Path(path).stat().st_size
    if size > MAX_FILE_BYTES:
        from starforge.runtime.budget import format_bytes

        raise StarforgeError(
            f"{path} is {format_bytes(size)}; a tracker body file is at most {format_bytes(MAX_FILE_BYTES)}"
        )


#: the way out of a tracker file that cannot be read as written
RESAVE = "save the body again from the tracker's software"
#: the way out of one value in a tracker file that is not a plain decimal number
FIX_VALUE = "write it as a decimal number such as 12.5, or " + RESAVE


def parse_xml(path) -> ET.Element:
    """The root of an XML tracker file; refuses files over :data:`MAX_FILE_BYTES` and any entity
    declaration (no tracker file has one; an entity bomb is made of them)."""
    check_size(path)
    data = Path(path).read_bytes()
    if b"<!ENTITY" in data:
        raise StarforgeError(f"{path} declares XML entities, which no tracker file does; {RESAVE}")
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise StarforgeError(f"{path} is not valid XML ({exc}); {RESAVE}") from None


#: a decimal number as tracker files write them: Python's float() also takes "1_0" (as 10),
#: "nan", "infinity" and non-ASCII digits, which no tracker writes and which would be misread
_NUMBER = re.compile(r"\s*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*")


def num(path, what: str, text) -> float:
    """``text`` as a finite float written as a plain decimal number, else one-line
    StarforgeError naming ``path`` and ``what``."""
    if isinstance(text, str) and text.strip().lstrip("+-").lower() in ("nan", "inf", "infinity"):
        raise StarforgeError(f"{path}: {what} is not finite ({text!r}); {FIX_VALUE}")
    if not isinstance(text, str) or not _NUMBER.fullmatch(text) or not text.isascii():
        raise StarforgeError(f"{path}: {what} is not a number ({text!r}); {FIX_VALUE}")
    v = float(text)
    if not np.isfinite(v):
        raise StarforgeError(f"{path}: {what} is not finite ({text!r}); {FIX_VALUE}")
    return v
