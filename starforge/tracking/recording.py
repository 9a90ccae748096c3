"""Labelled marker trajectories from a recording: C3D (through ezc3d) and the CSV exports of
QTM (``.tsv``/``.csv`` with ``MARKER_NAMES``), OptiTrack Motive (``Format Version`` header) and
Vicon Nexus (``Trajectories`` section).

Every reader returns :class:`Trajectories` in mm with NaN where a marker is not seen (C3D: a
negative residual, which ezc3d reports as NaN; every format: a blank cell or a point at exactly
0, 0, 0, which exporters write for a gap).  Anything a reader cannot make sense of raises
StarforgeError (one line) naming the file.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError

#: recordings larger than this are refused before reading (a 10-minute, 200 Hz, 255-marker C3D
#: of floats is about 0.5 GB)
MAX_RECORDING_BYTES = 2 * 1024**3
#: text exports larger than this are refused (they are read whole; C3D is read in place)
MAX_TEXT_BYTES = 256 * 1024**2
#: factor to mm of the length units recordings state
UNITS = {"mm": 1.0, "millimeters": 1.0, "cm": 10.0, "centimeters": 10.0, "m": 1000.0, "meters": 1000.0}


@dataclass(frozen=True)
class Trajectories:
    """Labelled marker positions over frames.

    labels : tuple of str                  one per marker
    points_mm : (F, M, 3) float, mm        NaN where a marker is not seen
    rate_hz : float or None                frame rate, where the file states it
    source : str                           the file read
    """

    labels: tuple[str, ...]
    points_mm: np.ndarray
    rate_hz: float | None
    source: str

    def __post_init__(self) -> None:
        P = self.points_mm
        if P.ndim != 3 or P.shape[1:] != (len(self.labels), 3):
            raise StarforgeError(
                f"{self.source}: trajectories of {len(self.labels)} labels must be (frames, {len(self.labels)}, 3)"
            )


def _finish(path, labels, P: np.ndarray, factor: float, rate) -> Trajectories:
    P = np.asarray(P, dtype=float) * factor
    P[(P == 0).all(axis=2)] = np.nan  # exporters write a gap as 0, 0, 0
    P[~np.isfinite(P).all(axis=2)] = np.nan
    if P.shape[0] == 0 or P.shape[1] == 0:
        raise StarforgeError(f"{path} holds no marker trajectory ({P.shape[0]} frames, {P.shape[1]} markers)")
    labels = [str(x).strip() or f"marker{i + 1}" for i, x in enumerate(labels)]
    if len(set(labels)) != len(labels):
        seen: dict[str, int] = {}
        for i, x in enumerate(labels):
            seen[x] = seen.get(x, 0) + 1
            if seen[x] > 1:
                labels[i] = f"{x}_{seen[x]}"
    return Trajectories(tuple(labels), P, float(rate) if rate else None, str(path))


def read_c3d(path) -> Trajectories:
    """The labelled points of a C3D file (POINT:LABELS, LABELS2 ...; POINT:UNITS): Intel and
    MIPS files with bounded memory (:func:`starforge.tracking.c3d.read_points`), DEC files
    through ezc3d."""
    from starforge.tracking.c3d import read_points

    got = read_points(path)
    if got is None:
        return read_c3d_ezc3d(path)
    return _finish(path, got.labels, got.points, _unit(path, got.unit), got.rate_hz)


def _unit(path, unit: str) -> float:
    if unit not in UNITS:
        raise StarforgeError(
            f"{path}: POINT:UNITS {unit!r} is not a length unit starforge knows ({', '.join(UNITS)})"
        )
    return UNITS[unit]


def read_c3d_ezc3d(path) -> Trajectories:
    """:func:`read_c3d` through ezc3d (every processor type; the whole file in memory)."""
    import ezc3d

    try:
        c = ezc3d.c3d(str(path))
        point = c["parameters"]["POINT"]
        data = c["data"]["points"]
    except Exception as exc:  # ezc3d raises plain RuntimeError/IOError/KeyError on corrupt files
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        raise StarforgeError(f"{path} is not a readable C3D file ({msg})") from None
    labels = list(point.get("LABELS", {}).get("value", []))
    k = 2
    while f"LABELS{k}" in point:
        labels += list(point[f"LABELS{k}"]["value"])
        k += 1
    n = data.shape[1]
    labels = (labels + [f"marker{i + 1}" for i in range(len(labels), n)])[:n]
    unit = str((point.get("UNITS", {}).get("value") or ["mm"])[0]).strip().lower()
    rate = (point.get("RATE", {}).get("value") or [None])[0]
    P = np.ascontiguousarray(np.transpose(data[:3], (2, 1, 0)))  # (F, M, 3)
    return _finish(path, labels, P, _unit(path, unit), rate)


def _numbers(rows, first: int, n_cols: int, path) -> np.ndarray:
    """Rows of text cells -> (F, n_cols) floats (blank: NaN), from column ``first``."""
    out = np.full((len(rows), n_cols), np.nan)
    for i, row in enumerate(rows):
        cells = row[first : first + n_cols]
        try:
            vals = [float(c) if c.strip() else np.nan for c in cells]
        except ValueError:
            raise StarforgeError(
                f"{path}: row {i + 1} of the data holds a cell that is not a number"
            ) from None
        out[i, : len(vals)] = vals
    return out


def _qtm(path, lines: list[str]) -> Trajectories:
    delim = "\t" if "\t" in lines[0] else ","
    head: dict[str, list[str]] = {}
    k = 0
    while k < len(lines) and lines[k].split(delim, 1)[0].strip().isupper():
        cells = lines[k].rstrip("\r\n").split(delim)
        head[cells[0].strip()] = cells[1:]
        k += 1
    names = [x for x in head.get("MARKER_NAMES", []) if x.strip()]
    if not names:
        raise StarforgeError(f"{path}: a QTM export needs a MARKER_NAMES line")
    rows = [r.rstrip("\r\n").split(delim) for r in lines[k:] if r.strip()]
    if rows and rows[0] and not _is_number(rows[0][0]):
        rows = rows[1:]  # the column header (Frame, Time, <marker> X, ...)
    first = max(0, len(rows[0]) - 3 * len(names)) if rows else 0
    first = min(first, 2)
    unit = "mm"
    P = _numbers(rows, first, 3 * len(names), path).reshape(len(rows), len(names), 3)
    rate = (head.get("FREQUENCY") or [None])[0]
    return _finish(path, names, P, UNITS[unit], rate)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _vicon(path, lines: list[str]) -> Trajectories:
    rows = list(csv.reader(lines))
    rate = rows[1][0] if len(rows) > 1 and rows[1] else None
    names_row = rows[2] if len(rows) > 2 else []
    cols = [(i, c.strip()) for i, c in enumerate(names_row) if c.strip()]
    if not cols:
        raise StarforgeError(f"{path}: a Vicon Trajectories section needs a row of marker names")
    units = rows[4] if len(rows) > 4 else []
    unit = (units[cols[0][0]].strip().lower() if len(units) > cols[0][0] else "") or "mm"
    if unit not in UNITS:
        raise StarforgeError(f"{path}: unit {unit!r} is not a length unit starforge knows")
    data = []
    for r in rows[5:]:
        if not r or not any(c.strip() for c in r):
            break  # the next section (e.g. Model Outputs) follows a blank line
        data.append(r)
    first = cols[0][0]
    n = len(cols)
    P = _numbers(data, first, 3 * n, path).reshape(len(data), n, 3)
    return _finish(path, [c.split(":")[-1] if ":" in c else c for _, c in cols], P, UNITS[unit], rate)


def _motive(path, lines: list[str]) -> Trajectories:
    rows = list(csv.reader(lines))
    meta = rows[0]
    info = {meta[i].strip(): meta[i + 1].strip() for i in range(0, len(meta) - 1, 2)}
    unit = info.get("Length Units", "Meters").strip().lower()
    if unit not in UNITS:
        raise StarforgeError(f"{path}: Length Units {unit!r} is not a unit starforge knows")
    k = next((i for i, r in enumerate(rows) if r and r[0].strip() == "Type"), None)
    if k is None or len(rows) < k + 5:
        raise StarforgeError(f"{path}: a Motive export needs Type, Name, ID and header rows")
    types, names, axes = rows[k], rows[k + 1], rows[k + 4]
    cols = [
        i
        for i, t in enumerate(types)
        if t.strip() == "Marker" and i < len(axes) and axes[i].strip().upper() == "X"
    ]
    if not cols:
        raise StarforgeError(f"{path}: no Marker position column in the Motive export")
    data = [r for r in rows[k + 5 :] if r and any(c.strip() for c in r)]
    P = np.full((len(data), len(cols), 3), np.nan)
    for j, c in enumerate(cols):
        P[:, j] = _numbers(data, c, 3, path)
    return _finish(path, [names[c] for c in cols], P, UNITS[unit], info.get("Export Frame Rate"))


def read_recording(path) -> Trajectories:
    """Trajectories of a C3D file or a QTM, Motive or Vicon CSV export (sniffed by content)."""
    from starforge.io import check_input_file

    path = check_input_file(Path(path), "recording")
    size = path.stat().st_size
    if size > MAX_RECORDING_BYTES:
        raise StarforgeError(
            f"{path} is {size / 1024**3:.1f} GB; a recording is read up to {MAX_RECORDING_BYTES / 1024**3:.0f} GB"
        )
    with open(path, "rb") as fh:
        head = fh.read(512)
    if path.suffix.lower() == ".c3d" or (len(head) > 1 and head[1] == 0x50):
        return read_c3d(path)
    if size > MAX_TEXT_BYTES:
        raise StarforgeError(
            f"{path} is {size / 1024**2:,.0f} MB of text; text exports are read up to "
            f"{MAX_TEXT_BYTES // 1024**2} MB: export the recording as C3D"
        )
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise StarforgeError(f"{path} is neither a C3D file nor a text export (not UTF-8)") from None
    lines = io.StringIO(text).readlines()
    first = lines[0].strip() if lines else ""
    if first.startswith("NO_OF_FRAMES") or any(x.startswith("MARKER_NAMES") for x in lines[:20]):
        return _qtm(path, lines)
    if first.split(",")[0].strip() == "Trajectories":
        return _vicon(path, lines)
    if first.startswith("Format Version"):
        return _motive(path, lines)
    raise StarforgeError(
        f"{path}: not a recording starforge reads (C3D; QTM export with MARKER_NAMES; Motive CSV; "
        "Vicon CSV with a Trajectories section)"
    )


def write_c3d(path, labels, points_mm: np.ndarray, rate_hz: float) -> None:
    """A C3D file (through ezc3d) of labelled points ``points_mm`` (F, M, 3) mm, NaN unseen (the
    file marks them with a negative residual)."""
    import ezc3d

    P = np.asarray(points_mm, dtype=float)
    F, M, _ = P.shape
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(rate_hz)]
    c["parameters"]["POINT"]["LABELS"]["value"] = [str(x) for x in labels]
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    data = np.empty((4, M, F))
    data[:3] = np.transpose(P, (2, 1, 0))
    data[3] = 1.0
    c["data"]["points"] = data
    seen = np.isfinite(P).all(axis=2).T  # (M, F)
    c["data"]["meta_points"]["residuals"] = np.where(seen, 0.0, -1.0)[None]
    c.write(str(path))


def simulate_recording(
    bodies_mm,
    frames: int,
    noise_mm: float,
    gap_share: float,
    rng: np.random.Generator,
    rate_hz: float = 200.0,
) -> Trajectories:
    """A recording of rigid ``bodies_mm`` (list of (k, 3) mm) tumbling and drifting through a
    4 m room: each body turns at its own steady random rate (up to about one turn per second)
    about a random axis, its centre wanders smoothly; each coordinate gets Gaussian noise
    ``noise_mm`` (per axis) and each marker position is unseen with probability ``gap_share``.
    Labels are ``B<i>_M<j>``."""
    from scipy.spatial.transform import Rotation

    t = np.arange(frames) / rate_hz
    blocks, labels = [], []
    for i, B in enumerate(bodies_mm):
        B = np.asarray(B, dtype=float)
        spin = rng.normal(size=3) * 2.0
        start = Rotation.random(random_state=rng)
        R = (Rotation.from_rotvec(t[:, None] * spin[None]) * start).as_matrix()  # (F, 3, 3)
        centre = rng.uniform(-1500, 1500, 3) + 300.0 * np.sin(
            t[:, None] * rng.uniform(0.2, 1.0, 3) + rng.uniform(0, 6, 3)
        )
        blocks.append(np.einsum("fij,kj->fki", R, B) + centre[:, None, :])
        labels += [f"B{i + 1}_M{j + 1}" for j in range(len(B))]
    P = np.concatenate(blocks, axis=1)
    P += rng.normal(scale=noise_mm, size=P.shape)
    P[rng.random(P.shape[:2]) < gap_share] = np.nan
    return Trajectories(tuple(labels), P, rate_hz, "simulated")
