"""The 3D points of a C3D file, read with bounded memory (the data section mapped, only the
point columns copied).

The layout (C3D.ORG's "The C3D File Format User Guide"): 512-byte blocks; the header block
holds the first parameter block (byte 0), the signature 0x50 (byte 1), the number of points
(word 2), the analog samples per 3D frame (word 3), the first and last frame (words 4, 5), the
scale (bytes 12-15, float: negative means float data) and the first data block (word 9).  The
parameter section starts with the processor type (its byte 3: 84 Intel, 85 DEC, 86 MIPS) and
holds groups and parameters, each ``int8 name length, int8 group id, name, int16 offset to the
next``; a parameter then ``int8 type (-1 char, 1 byte, 2 int16, 4 float), int8 dimensions,
the dimensions, the data``.  Each frame holds per point x, y, z and a residual word (negative:
not seen), then the analog samples.

Intel and MIPS files are read here; DEC files (VAX floats) go through ezc3d, which holds the
whole file in memory (:func:`starforge.tracking.recording.read_c3d`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.runtime.budget import require_memory

BLOCK = 512
INTEL, DEC, MIPS = 84, 85, 86


@dataclass(frozen=True)
class C3DPoints:
    """labels : list of str; points (F, M, 3) float in the file's unit (NaN unseen);
    unit : str (POINT:UNITS); rate_hz : float"""

    labels: list[str]
    points: np.ndarray
    unit: str
    rate_hz: float


def _params(path, data: bytes, start: int, end: int, endian: str) -> dict:
    """{(GROUP, NAME): (type, dims, raw bytes)} of the parameter section data[start:end]."""
    groups: dict[int, str] = {}
    raw: dict[tuple[int, str], tuple[int, tuple, bytes]] = {}
    pos = start
    while pos + 2 <= end:
        nchar, gid = struct.unpack_from("bb", data, pos)
        if nchar == 0:
            break
        p = pos + 2 + abs(nchar)
        if p + 2 > end:
            raise StarforgeError(f"{path}: C3D parameter section is cut short")
        name = data[pos + 2 : p].decode("ascii", "replace").strip().upper()
        (nxt,) = struct.unpack_from(endian + "h", data, p)
        q = p + 2
        if gid < 0:
            groups[-gid] = name
        elif q + 2 <= end:
            dtype, ndim = struct.unpack_from("bB", data, q)
            dims = tuple(data[q + 2 : q + 2 + ndim])
            q += 2 + ndim
            size = abs(dtype) * int(np.prod(dims, dtype=np.int64)) if ndim else abs(dtype)
            if dtype not in (-1, 1, 2, 4) or q + size > end:
                raise StarforgeError(f"{path}: C3D parameter {name} is malformed")
            raw[(gid, name)] = (dtype, dims, data[q : q + size])
        if nxt <= 0:
            break
        pos = p + nxt
    return {(groups.get(g, "?"), n): v for (g, n), v in raw.items()}


def _strings(entry) -> list[str]:
    dtype, dims, raw = entry
    if dtype != -1 or not dims:
        return []
    width = dims[0]
    count = int(np.prod(dims[1:], dtype=np.int64)) if len(dims) > 1 else 1
    return [raw[i * width : (i + 1) * width].decode("utf-8", "replace").strip() for i in range(count)]


def _numbers(entry, endian: str) -> np.ndarray:
    dtype, _, raw = entry
    kind = {1: "i1", 2: "i2", 4: "f4"}.get(dtype)
    return np.frombuffer(raw, dtype=endian + kind) if kind else np.zeros(0)


def read_points(path) -> C3DPoints | None:
    """The labelled 3D points of a C3D file, or None for a DEC file (read it with ezc3d).
    StarforgeError (one line) for a file that is not a C3D or is cut short."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(BLOCK)
        if len(head) < BLOCK or head[1] != 0x50:
            raise StarforgeError(f"{path} is not a C3D file (no C3D signature in its first block)")
        pblock = head[0]
        fh.seek((pblock - 1) * BLOCK)
        phead = fh.read(4)
        if len(phead) < 4 or pblock < 2:
            raise StarforgeError(f"{path}: C3D parameter section is missing")
        ptype = phead[3]
        if ptype == DEC:
            return None
        if ptype not in (INTEL, MIPS):
            raise StarforgeError(
                f"{path}: C3D processor type {ptype} is not Intel (84), DEC (85) or MIPS (86)"
            )
        endian = "<" if ptype == INTEL else ">"
        nblocks = max(1, phead[2])
        fh.seek((pblock - 1) * BLOCK)
        psec = fh.read(nblocks * BLOCK)
    n_points, analog, first, last = struct.unpack_from(endian + "HHHH", head, 2)
    (scale,) = struct.unpack_from(endian + "f", head, 12)
    (data_block,) = struct.unpack_from(endian + "H", head, 16)
    (rate,) = struct.unpack_from(endian + "f", head, 20)
    params = _params(path, psec, 4, len(psec), endian)
    labels: list[str] = []
    k = 1
    while ("POINT", "LABELS" if k == 1 else f"LABELS{k}") in params:
        labels += _strings(params[("POINT", "LABELS" if k == 1 else f"LABELS{k}")])
        k += 1
    labels = (labels + [f"marker{i + 1}" for i in range(len(labels), n_points)])[:n_points]
    units = _strings(params.get(("POINT", "UNITS"), (0, (), b""))) or ["mm"]
    if not np.isfinite(scale) or not np.isfinite(rate):
        raise StarforgeError(f"{path}: C3D header scale or rate is not a number")
    word = 4 if scale < 0 else 2
    frame_words = 4 * n_points + analog
    offset = (data_block - 1) * BLOCK
    if n_points == 0 or data_block < 2 or offset >= size:
        raise StarforgeError(
            f"{path}: C3D file holds no 3D points ({n_points} points, data block {data_block})"
        )
    avail = (size - offset) // (frame_words * word)
    frames = _frame_count(params, endian, first, last, avail, frame_words * word)
    if frames <= 0:
        raise StarforgeError(f"{path}: C3D data section is cut short (no whole frame)")
    require_memory(
        frames * n_points * 3 * 8 * 3.0,  # the points as float64, the columns copied, one working copy
        f"reading {frames:,} frames of {n_points} markers from {path}",
        "give a shorter recording or raise --max-memory",
    )
    kind = endian + ("f4" if word == 4 else "i2")
    mm = np.memmap(path, dtype=kind, mode="r", offset=offset, shape=(frames, frame_words))
    try:
        block = np.asarray(mm[:, : 4 * n_points]).reshape(frames, n_points, 4)
    finally:
        del mm
    residual = block[..., 3]
    P = block[..., :3].astype(float)
    if word == 2:
        P *= abs(scale)
    P[residual < 0] = np.nan
    return C3DPoints(labels, P, units[0].strip().lower(), float(rate))


def _frame_count(params: dict, endian: str, first: int, last: int, avail: int, frame_bytes: int) -> int:
    """Frames in the data section: TRIAL:ACTUAL_START/END_FIELD (32-bit, for long recordings),
    else the header's first and last frame when the file holds them (padding aside), else every
    whole frame the file holds."""
    start, end = params.get(("TRIAL", "ACTUAL_START_FIELD")), params.get(("TRIAL", "ACTUAL_END_FIELD"))
    if start and end:
        s, e = (_numbers(x, endian).astype(np.int64) for x in (start, end))
        if len(s) == 2 and len(e) == 2:
            n = int(
                (e[0] & 0xFFFF) + 65536 * (e[1] & 0xFFFF) - ((s[0] & 0xFFFF) + 65536 * (s[1] & 0xFFFF)) + 1
            )
            if 0 < n <= avail:
                return n
    n = last - first + 1
    padding = BLOCK // max(1, frame_bytes) + 1
    if 0 < n <= avail and avail - n <= padding:
        return n
    return avail
