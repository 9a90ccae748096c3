"""starforge's body table: ``body,marker,x_mm,y_mm,z_mm`` (or ``x_m,y_m,z_m``, converted)."""

from __future__ import annotations

import csv
import io

import numpy as np

from starforge.errors import StarforgeError
from starforge.tracking.formats._common import Record, WriteContext, check_size, f2s, num, points_of

SUFFIX = ".csv"
#: what a body table carries besides names and points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset()

#: body CSV coordinate columns and the factor to mm
_UNITS = {("x_mm", "y_mm", "z_mm"): 1.0, ("x_m", "y_m", "z_m"): 1000.0}


def plain_csv(bodies) -> str:
    """``body,marker,x_mm,y_mm,z_mm`` rows (marker numbered from 1)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["body", "marker", "x_mm", "y_mm", "z_mm"])
    for name, P in bodies:
        for i, p in enumerate(np.asarray(P, dtype=float)):
            w.writerow([name, i + 1, f2s(p[0]), f2s(p[1]), f2s(p[2])])
    return buf.getvalue()


def write(name: str, P, ctx: WriteContext) -> bytes:
    return plain_csv([(name, P)]).encode("utf-8")


def read(path) -> dict[str, np.ndarray]:
    """{body: (n, 3) mm}, each body's markers in marker order."""
    return points_of(load(path))


def load(path) -> list[Record]:
    """The table's bodies, each body's markers in marker order."""
    check_size(path)
    rows: dict[str, list] = {}
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = tuple(reader.fieldnames or ())
            cols = next((c for c in _UNITS if set(c) <= set(header)), None)
            if cols is None or not {"body", "marker"} <= set(header):
                raise KeyError(f"header {','.join(header)}")
            for r in reader:
                rows.setdefault(r["body"], []).append(
                    (int(r["marker"]), [num(path, f"{r['body']} {c}", r[c]) * _UNITS[cols] for c in cols])
                )
    except StarforgeError:  # a value that is not a number: named as it is
        raise
    except (KeyError, ValueError, TypeError, UnicodeDecodeError, csv.Error) as exc:
        why = exc.args[0] if isinstance(exc, KeyError) and exc.args else f"{exc.__class__.__name__}: {exc}"
        raise StarforgeError(
            f"{path} is not a body,marker,x_mm,y_mm,z_mm table ({why}); give a CSV with those columns "
            "(`starforge convert FILE --format csv` writes one)"
        ) from None
    if not rows:
        raise StarforgeError(f"{path} holds no body rows")
    out = []
    for k, v in rows.items():
        ids = [i for i, _ in v]
        if len(set(ids)) != len(ids):
            raise StarforgeError(f"{path}: body {k} numbers a marker twice")
        out.append(Record(k, np.array([p for _, p in sorted(v)], dtype=float).reshape(-1, 3)))
    return out


def sniff(path, head: bytes) -> bool:
    return head.startswith(b"body,marker")
