"""Atracsys fusionTrack / spryTrack geometry ``.ini`` (the layout Atracsys' SDK and PlusLib read).

``[geometry]`` ``count``, ``id``; ``[fiducialN]`` ``x``, ``y``, ``z``, written ``key=value`` with
no spaces (Atracsys' INI code matches keys verbatim), at most :data:`MAX_FIDUCIALS` fiducials.
Ids are unique across a lab: the export's ``id_start`` + index.  A geometry file carries no
identification tolerance (the SDK's registration-error limit is a tracker option).
"""

from __future__ import annotations

import configparser
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.tracking.formats._common import RESAVE, Record, WriteContext, check_size, f2s, num, points_of

SUFFIX = ".ini"
#: what a geometry file carries besides its points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset({"body_id"})
#: fiducials one Atracsys geometry may hold (``FTK_MAX_FIDUCIALS`` in Atracsys' SDK headers; the
#: INI loader Atracsys ships, as kept in PlusLib, writes ``count`` points into an array this long)
MAX_FIDUCIALS = 6
MAX_MARKERS = MAX_FIDUCIALS


def atracsys_ini(geometry_id: int, P) -> str:
    """Atracsys geometry ``.ini`` text, mm."""
    P = np.asarray(P, dtype=float)
    lines = ["[geometry]", f"count={len(P)}", f"id={int(geometry_id)}"]
    for i, p in enumerate(P):
        lines += [f"[fiducial{i}]", f"x={f2s(p[0])}", f"y={f2s(p[1])}", f"z={f2s(p[2])}"]
    return "\n".join(lines) + "\n"


def write(name: str, P, ctx: WriteContext) -> bytes:
    return atracsys_ini(ctx.geometry_id, P).encode("utf-8")


def read(path) -> dict[str, np.ndarray]:
    """An Atracsys geometry ``.ini``: {file stem: (count, 3) mm} (see :func:`load`)."""
    return points_of(load(path))


def load(path) -> list[Record]:
    """An Atracsys geometry ``.ini``: one body named after the file, with its geometry id.
    Optional sections such as ``[pivot]`` are ignored."""
    check_size(path)
    cp = configparser.ConfigParser()
    try:
        cp.read_string(Path(path).read_text(encoding="utf-8"))
        n = cp.getint("geometry", "count")
        gid = cp.getint("geometry", "id")
        if not 1 <= n <= 64:
            raise ValueError(f"count {n} is outside 1..64")
        raw = [[cp.get(f"fiducial{i}", c) for c in "xyz"] for i in range(n)]
    except (configparser.Error, ValueError, UnicodeDecodeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise StarforgeError(
            f"{path} is not an Atracsys geometry file ({msg}); {RESAVE}"
        ) from None
    pts = [[num(path, f"fiducial{i} {c}", v) for c, v in zip("xyz", row, strict=True)] for i, row in enumerate(raw)]
    P = np.array(pts, dtype=float).reshape(-1, 3)
    if not np.isfinite(P).all():
        raise StarforgeError(f"{path}: fiducial coordinates must be finite numbers")
    return [Record(Path(path).stem, P, body_id=gid)]


def sniff(path, head: bytes) -> bool:
    return b"[geometry]" in head
