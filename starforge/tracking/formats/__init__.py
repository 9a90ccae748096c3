"""One registry of tracker formats: a name -> :class:`Format` (reader, writer, suffix, sniffer).

Every command that reads or writes a lab's rigid-body files looks its format up here
(``starforge export --format``, ``check``, ``stars --avoid``, ``place --avoid`` through
:func:`starforge.tracking.bodies.load_bodies`).  Each format lives in its own module with a
``read(path) -> {name: (n, 3) mm}``, a ``write(name, points_mm, ctx) -> bytes`` (one file per
body) and a ``sniff(path, head) -> bool``; format modules import only
:mod:`~starforge.tracking.formats._common`, never each other, the bodies or the commands (as
trimesh's ``exchange/load.py`` keeps its loaders in one dict).

* ``qtm`` (:mod:`.qtm`): Qualisys QTM 6DOF settings XML
* ``vsk`` (:mod:`.vsk`): Vicon VSK
* ``atracsys`` (:mod:`.atracsys`): Atracsys geometry ``.ini``
* ``rom`` (:mod:`.rom`): NDI tool definition (binary SROM image)
* ``motive`` (:mod:`.motive`): OptiTrack Motive profile (``.motive`` XML) with rigid-body assets
* ``csv`` (:mod:`.bodycsv`): starforge's ``body,marker,x_mm,y_mm,z_mm`` table

Every reader returns millimetres: the vendor formats hold mm by definition, the body CSV says
its unit in its header.  Anything a reader cannot make sense of raises StarforgeError (one
line) naming the file and what is wrong.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.tracking.formats import atracsys, bodycsv, motive, qtm, rom, vsk
from starforge.tracking.formats._common import FIELDS, MAX_FILE_BYTES, Record, WriteContext  # noqa: F401


@dataclass(frozen=True)
class Format:
    """One tracker format: what it is, where it comes from, and its functions.

    ``load`` returns :class:`~starforge.tracking.formats._common.Record` s (points and what else
    the file states); ``read`` only the points.  ``carries``: the record fields and tolerance
    keys a file of this format keeps (names and marker order every format keeps)."""

    name: str
    suffix: str
    vendor: str
    read: Callable[[Path], dict]
    write: Callable[[str, np.ndarray, WriteContext], bytes]
    sniff: Callable[[Path, bytes], bool]
    max_markers: int | None = None
    load: Callable[[Path], list] | None = None
    carries: frozenset = frozenset()


def _format(name: str, module, vendor: str, max_markers: int | None = None) -> Format:
    return Format(
        name,
        module.SUFFIX,
        vendor,
        module.read,
        module.write,
        module.sniff,
        max_markers,
        module.load,
        module.CARRIES,
    )


FORMATS: dict[str, Format] = {
    "qtm": _format("qtm", qtm, "Qualisys QTM"),
    "vsk": _format("vsk", vsk, "Vicon"),
    "atracsys": _format("atracsys", atracsys, "Atracsys", atracsys.MAX_MARKERS),
    "rom": _format("rom", rom, "NDI", rom.MAX_MARKERS),
    "motive": _format("motive", motive, "OptiTrack Motive"),
    "csv": _format("csv", bodycsv, "starforge"),
}
TRACKER_FORMATS = tuple(FORMATS)
READERS = {k: f.read for k, f in FORMATS.items()}
ATRACSYS_MAX_FIDUCIALS = atracsys.MAX_FIDUCIALS


def check_id_start(id_start, n_bodies: int) -> None:
    """Numeric body ids ``id_start`` .. ``id_start + n_bodies - 1`` fit every format's id field
    (a signed 32-bit integer, never negative); StarforgeError naming ``id_start`` otherwise."""
    top = 2**31 - 1 - n_bodies
    if not (isinstance(id_start, int) and not isinstance(id_start, bool) and 0 <= id_start <= top):
        raise StarforgeError(f"id_start must be an integer in [0, {top}], got {id_start!r}")


def get_format(name: str) -> Format:
    """The format called ``name``; StarforgeError naming the known ones."""
    key = str(name).strip().lower()
    if key not in FORMATS:
        raise StarforgeError(f"unknown tracker format {name!r}; known: {', '.join(FORMATS)}")
    return FORMATS[key]


def parse_formats(formats) -> list[str]:
    """``"qtm,vsk"`` or a list -> validated, de-duplicated list; StarforgeError names the known ones."""
    if isinstance(formats, str):
        formats = formats.split(",")
    out: list[str] = []
    for f in formats:
        f = str(f).strip().lower()
        if not f:
            continue
        get_format(f)
        if f not in out:
            out.append(f)
    if not out:
        raise StarforgeError(f"no tracker format given; known: {', '.join(FORMATS)}")
    return out


def sniff_format(path) -> str | None:
    """The tracker format of a file by its content (then its suffix), or None."""
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if rom.sniff(path, head):
        return "rom"
    head = head.removeprefix(b"\xef\xbb\xbf").lstrip()
    for name in ("vsk", "motive", "qtm", "atracsys", "csv"):
        if FORMATS[name].sniff(path, head):
            return name
    by_suffix = {".xml": "qtm"} | {f.suffix: k for k, f in FORMATS.items() if k not in ("qtm", "csv")}
    if head.startswith(b"<"):
        return {".vsk": "vsk", ".xml": "qtm", ".motive": "motive"}.get(path.suffix.lower())
    return by_suffix.get(path.suffix.lower()) or ("csv" if path.suffix.lower() == ".csv" else None)


def read_file(path, fmt: str | None = None) -> dict[str, np.ndarray]:
    """{body name: (n, 3) mm} of a tracker file (format sniffed unless given)."""
    return {r.name: r.points_mm for r in load_file(path, fmt)}


def load_file(path, fmt: str | None = None) -> list[Record]:
    """The body records of a tracker file (format sniffed unless given)."""
    fmt = fmt or sniff_format(path)
    if fmt is None:
        raise StarforgeError(f"{path}: not a tracker file starforge reads ({', '.join(FORMATS)})")
    return FORMATS[fmt].load(Path(path))
