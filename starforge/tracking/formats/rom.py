"""NDI tool definition (``.rom``, the SROM image Polaris / Vega trackers load), written and read.

The layout, learned from public descriptions (the JHU sawNDITracker project's notes on the
format, checked byte by byte against six real ``.rom`` files kept in that repository, four of
them NDI's own): 752 bytes, little endian.

=========  ===============================  =====================================================
bytes      field                            starforge writes
=========  ===============================  =====================================================
0-2        ``NDI``                          ``NDI``
4-5        checksum (uint16)                sum of bytes 6..751, modulo 65536
8          constant                         1 (as every file seen)
12         tool sub type (uint8)            2 (undefined)
15         tool main type (uint8)           4 (user defined)
16-17      tool revision (uint16)           0
20-23      sequence number and date         0 (see below)
24         maximum marker angle, degrees    90 (as every file seen)
28         marker count                     n (at most :data:`MAX_MARKERS`)
32         minimum markers                  the export's (3: a marker may be hidden)
36-39      maximum marker error, mm (f32)   the export's (from the noise, see trackers.json)
64-67      unknown (f32)                    10.0 (as every file seen)
72-311     marker positions, 20 x xyz f32   the body's markers, mm
312-551    marker normals, 20 x xyz f32     unit directions (default +z)
552-571    firing sequence                  0, 1, .. n-1 (as every file seen)
572-575    tracking LED, LED 1-3            31 (none)
576        tool-in-port diode               9 (as every file seen)
580-591    manufacturer (ASCII, 12)         ``starforge``
592-611    part number (ASCII, 20)          the body's name (cut to 20 characters)
612        unknown                          9 (as every file seen)
613-632    face of each marker              1
633-652    group of each marker             1
653        algorithm flags                  128 ("unique geometry", as every file seen)
655        marker type                      41 (passive sphere)
656-751    face normals, 8 x xyz f32        face 1: the markers' mean normal
=========  ===============================  =====================================================

What could not be verified without NDI's software (NDI 6D Architect or a tracker): that a
tracker accepts the file (the checksum and every constant match NDI-made files, but no tracker
loaded one here), the meaning of bytes 64-67 and 612, how the maximum marker error is applied
(RMS or per marker), and the date encoding (the date is written as 0, i.e. 1900-01-01, so that
the same inputs give the same bytes).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.tracking.formats._common import RESAVE, Record, WriteContext, check_size, points_of

SUFFIX = ".rom"
#: what a tool definition carries besides its points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset({"normals", "min_markers", "max_marker_error_mm"})
SIZE = 752
#: markers one tool definition holds
MAX_MARKERS = 20
MAX_FACES = 8
MANUFACTURER = "starforge"
#: tool main types (byte 15), as the public notes name them
MAIN_TYPES = {
    0: "unknown",
    1: "reference",
    2: "pointer",
    3: "button box",
    4: "user defined",
    5: "microscope",
    7: "calibration block",
    8: "tool docking station",
    9: "isolation box",
    10: "C-arm tracker",
    11: "catheter",
    12: "GPIO device",
    14: "scan reference",
}
MARKER_TYPES = {41: "passive sphere", 49: "passive disc", 57: "radix lens"}

_POS, _NRM, _FACE_NRM = 72, 312, 656


@dataclass(frozen=True)
class RomTool:
    """Every field starforge reads from a ``.rom`` (lengths mm)."""

    points_mm: np.ndarray  # (n, 3) float32 values as float
    normals: np.ndarray  # (n, 3)
    main_type: int
    sub_type: int
    revision: int
    max_marker_angle_deg: int
    min_markers: int
    max_marker_error_mm: float
    manufacturer: str
    part_number: str
    marker_type: int
    faces: np.ndarray  # (n,) int
    face_normals: np.ndarray  # (8, 3)
    checksum: int


def _ascii(text: str, size: int) -> bytes:
    b = str(text).encode("ascii", "replace")[:size]
    return b + b"\0" * (size - len(b))


def rom_bytes(
    P,
    normals=None,
    part_number: str = "",
    manufacturer: str = MANUFACTURER,
    max_marker_error_mm: float = 2.0,
    min_markers: int = 3,
    main_type: int = 4,
    sub_type: int = 2,
    max_marker_angle_deg: int = 90,
) -> bytes:
    """A ``.rom`` image of one tool: markers ``P`` (n, 3) mm, unit ``normals`` (n, 3) or None
    (+z).  Raises StarforgeError for what the layout cannot hold."""
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    n = len(P)
    if not 1 <= n <= MAX_MARKERS:
        raise StarforgeError(f"an NDI tool definition holds 1 to {MAX_MARKERS} markers, got {n}")
    if not 1 <= min_markers <= n:
        raise StarforgeError(f"minimum markers must be in 1..{n}, got {min_markers}")
    N = (
        np.tile([0.0, 0.0, 1.0], (n, 1))
        if normals is None
        else np.asarray(normals, dtype=float).reshape(n, 3)
    )
    if not (np.isfinite(P).all() and np.isfinite(N).all()):
        raise StarforgeError("NDI tool definition: marker positions and normals must be finite")
    if not 0.0 <= max_marker_error_mm <= 10.0:
        raise StarforgeError(f"NDI maximum marker error must be in [0, 10] mm, got {max_marker_error_mm:g}")
    face = N.mean(axis=0)
    norm = np.linalg.norm(face)
    face = face / norm if norm > 1e-9 else np.zeros(3)
    d = bytearray(SIZE)
    d[0:3] = b"NDI"
    d[8] = 1
    d[12] = int(sub_type)
    d[15] = int(main_type)
    d[24] = int(max_marker_angle_deg)
    d[28] = n
    d[32] = int(min_markers)
    struct.pack_into("<f", d, 36, float(max_marker_error_mm))
    struct.pack_into("<f", d, 64, 10.0)
    struct.pack_into(f"<{3 * n}f", d, _POS, *P.ravel())
    struct.pack_into(f"<{3 * n}f", d, _NRM, *N.ravel())
    d[552 : 552 + n] = bytes(range(n))
    d[572:576] = bytes([31, 31, 31, 31])
    d[576] = 9
    d[580:592] = _ascii(manufacturer, 12)
    d[592:612] = _ascii(part_number, 20)
    d[612] = 9
    d[613 : 613 + n] = bytes([1] * n)
    d[633 : 633 + n] = bytes([1] * n)
    d[653] = 128
    d[655] = 41
    struct.pack_into("<3f", d, _FACE_NRM, *face)
    struct.pack_into("<H", d, 4, sum(d[6:]) & 0xFFFF)
    return bytes(d)


def write(name: str, P, ctx: WriteContext) -> bytes:
    return rom_bytes(
        P,
        ctx.normals,
        part_number=name,
        max_marker_error_mm=float(ctx.tolerances.get("max_marker_error_mm", 2.0)),
        min_markers=max(1, min(ctx.min_markers, len(P))),
    )


def _cstr(b: bytes) -> str:
    return b.split(b"\0", 1)[0].decode("ascii", "replace")


def read_tool(path) -> RomTool:
    """Every field of an NDI ``.rom`` (see the module docstring); StarforgeError (one line) for
    a file that is not one: wrong size or signature, checksum mismatch, marker count out of
    range, coordinates that are not finite."""
    check_size(path)
    d = Path(path).read_bytes()
    if len(d) < SIZE or d[:3] != b"NDI":
        raise StarforgeError(
            f"{path} is not an NDI tool definition (.rom: {SIZE} bytes starting with 'NDI'; got {len(d)} "
            f"bytes starting with {d[:3]!r}); {RESAVE}"
        )
    (stored,) = struct.unpack_from("<H", d, 4)
    total = sum(d[6:SIZE]) & 0xFFFF
    if stored != total:
        raise StarforgeError(
            f"{path}: NDI checksum {stored} does not match the content ({total}): corrupt file; {RESAVE}"
        )
    n = d[28]
    if not 1 <= n <= MAX_MARKERS:
        raise StarforgeError(f"{path}: NDI marker count {n} is outside 1..{MAX_MARKERS}")
    P = np.array(struct.unpack_from(f"<{3 * n}f", d, _POS), dtype=float).reshape(n, 3)
    N = np.array(struct.unpack_from(f"<{3 * n}f", d, _NRM), dtype=float).reshape(n, 3)
    if not (np.isfinite(P).all() and np.isfinite(N).all()):
        raise StarforgeError(f"{path}: NDI marker positions or normals are not finite numbers; {RESAVE}")
    return RomTool(
        points_mm=P,
        normals=N,
        main_type=d[15],
        sub_type=d[12],
        revision=struct.unpack_from("<H", d, 16)[0],
        max_marker_angle_deg=d[24],
        min_markers=d[32],
        max_marker_error_mm=float(struct.unpack_from("<f", d, 36)[0]),
        manufacturer=_cstr(d[580:592]),
        part_number=_cstr(d[592:612]),
        marker_type=d[655],
        faces=np.frombuffer(d[613 : 613 + n], dtype=np.uint8).astype(int),
        face_normals=np.array(struct.unpack_from(f"<{3 * MAX_FACES}f", d, _FACE_NRM), dtype=float).reshape(
            -1, 3
        ),
        checksum=stored,
    )


def read(path) -> dict[str, np.ndarray]:
    """{file stem: (n, 3) mm} of an NDI ``.rom`` (coordinates are float32 in the file)."""
    return points_of(load(path))


def load(path) -> list[Record]:
    """An NDI ``.rom`` as one body named after the file, with its normals, minimum markers and
    maximum marker error."""
    t = read_tool(path)
    return [
        Record(
            Path(path).stem,
            t.points_mm,
            normals=t.normals,
            min_markers=t.min_markers or None,
            tolerances={"max_marker_error_mm": t.max_marker_error_mm},
        )
    ]


def sniff(path, head: bytes) -> bool:
    return head.startswith(b"NDI\0")
