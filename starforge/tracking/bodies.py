"""Rigid bodies as a tracker sees them: named marker sets in mm, read from starforge's JSON files
or from the tracker files a lab already has.

A star family (``family.json``, mm) gives one body per star: its four sphere centres in the
family's placement frame.  A prop placement (``placement.json``, metres) gives one body: its
markers in the prop frame, converted to mm here (tracker files and the simulation work in mm).
QTM (6DOF settings or body files), Vicon VSK, Atracsys ``.ini`` and starforge's body CSV give
their bodies as written (mm), so a lab's existing bodies can be checked beside new ones.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.io import read_json

PLACEMENT_FORMAT = "starforge.placement"
FAMILY_FORMAT = "starforge.family"


@dataclass(frozen=True)
class Body:
    """One rigid body.

    Attributes
    ----------
    name : str              safe for file names (letters, digits, ``_``, ``-``, ``.``)
    id : int                numeric id (star id, or 1.. for placements)
    points_mm : (n, 3) float, mm   marker centres in the body's own frame
    """

    name: str
    id: int
    points_mm: np.ndarray

    def __post_init__(self) -> None:
        p = np.array(self.points_mm, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.isfinite(p).all():
            raise StarforgeError(f"body {self.name}: points_mm must be (n, 3) finite numbers")
        p.setflags(write=False)
        object.__setattr__(self, "points_mm", p)

    @property
    def n_markers(self) -> int:
        return len(self.points_mm)


@dataclass(frozen=True)
class BodySet:
    """Bodies read from one or more JSON files.

    Attributes
    ----------
    kind : "family" or "placement"
    sources : tuple of str          the files read
    bodies : tuple of Body
    tolerance_mm : float or None    the family's design tolerance (faces/edges differ by this), mm
    marker_mm : float or None       marker sphere diameter, mm
    default_tip_mm : (3,) float     the tip for accuracy reports when none is given, mm
    tip_source : str                where that default comes from
    """

    kind: str
    sources: tuple[str, ...]
    bodies: tuple[Body, ...]
    tolerance_mm: float | None = None
    marker_mm: float | None = None
    default_tip_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_source: str = "the bodies' own origin"

    @property
    def names(self) -> list[str]:
        return [b.name for b in self.bodies]

    @property
    def min_markers(self) -> int:
        return min(b.n_markers for b in self.bodies)


def safe_name(text: str) -> str:
    """``text`` reduced to characters safe in file names and XML attribute values."""
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text)).strip("._")
    return s or "body"


def _family_bodies(path: Path, data: dict) -> BodySet:
    from starforge.geometry.rigid import default_tip_mm
    from starforge.stars.model import family_from_json

    fam = family_from_json(data, where=str(path))
    base = safe_name(fam.spec.name)
    width = max(3, len(str(max(s.id for s in fam.stars))))
    bodies = tuple(Body(f"{base}_{s.id:0{width}d}", int(s.id), s.vertices) for s in fam.stars)
    tip = fam.spec.tip_mm if fam.spec.tip_mm is not None else tuple(default_tip_mm(fam.spec.box_mm))
    return BodySet(
        "family",
        (str(path),),
        bodies,
        float(fam.spec.tol_mm),
        float(fam.spec.marker_mm),
        tuple(float(x) for x in tip),
        "the family's tip (placement frame: long axis, one limit length below the mount face)",
    )


#: marker spreads a rigid body can have, mm (a body outside these is in other units or corrupt)
SPREAD_MM = (1.0, 20_000.0)


def _check_spread(path, name: str, P: np.ndarray) -> None:
    if len(P) < 2:
        return
    spread = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    if not SPREAD_MM[0] <= spread <= SPREAD_MM[1]:
        raise StarforgeError(
            f"{path}: body {name} spans {spread:.4g} mm; a marker body spans {SPREAD_MM[0]:g} to {SPREAD_MM[1]:g} mm "
            f"(is the file in other units?)"
        )


def _tracker_bodies(path: Path, fmt: str) -> list[Body]:
    from starforge.tracking.formats import READERS

    bodies = []
    for k, (name, P) in enumerate(READERS[fmt](path).items()):
        if len(P) < 3:
            raise StarforgeError(f"{path}: body {name} has {len(P)} markers; a rigid body needs at least 3")
        _check_spread(path, name, P)
        bodies.append(Body(safe_name(name), k + 1, P))
    return bodies


def _placement_body(path: Path, data: dict, index: int) -> tuple[Body, float]:
    if data.get("version") != 1:
        raise StarforgeError(f"{path}: unsupported placement version {data.get('version')!r}, expected 1")
    try:
        pos = np.array([m["position"] for m in data["markers"]], dtype=float).reshape(-1, 3)
        name = str(data.get("prop", {}).get("name", path.parent.name or path.stem))
        diameter_m = float(data.get("marker_diameter_m", 0.0))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise StarforgeError(f"{path} has malformed markers ({exc.__class__.__name__}: {exc})") from None
    if len(pos) == 0:
        raise StarforgeError(f"{path} holds no markers")
    if not np.isfinite(pos).all():
        raise StarforgeError(f"{path}: marker positions must be finite numbers")
    return Body(safe_name(name), index, pos * 1000.0), diameter_m * 1000.0


def load_bodies(paths) -> BodySet:
    """Read a family JSON, or one or more placement JSONs or tracker files (QTM, VSK, Atracsys,
    body CSV); a folder means the JSON inside it.

    Raises StarforgeError for a missing or corrupt file, a format it does not know, a body in
    other units, or a mix of a family with other files.
    """
    from starforge.io import check_input_file
    from starforge.tracking.formats import sniff_format

    if isinstance(paths, str | Path):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if not paths:
        raise StarforgeError("no input file given")
    docs, tracker = [], []
    for p in paths:
        if p.is_dir():
            for cand in ("family.json", "placement.json"):
                if (p / cand).exists():
                    p = p / cand
                    break
        check_input_file(p, "input file")
        fmt = sniff_format(p)
        if fmt is not None and p.suffix.lower() != ".json":
            tracker.append((p, fmt))
            continue
        data = read_json(p, what="input file")
        docs.append((p, data))
    kinds = [d.get("format") for _, d in docs]
    for (p, _), k in zip(docs, kinds, strict=True):
        if k not in (FAMILY_FORMAT, PLACEMENT_FORMAT):
            raise StarforgeError(
                f"{p} is neither a star family nor a prop placement (format {k!r}; "
                f"expected {FAMILY_FORMAT!r} or {PLACEMENT_FORMAT!r}) nor a QTM, VSK, Atracsys or body CSV file"
            )
    if FAMILY_FORMAT in kinds:
        if len(docs) > 1 or tracker:
            raise StarforgeError("give one family file, or placement and tracker files (not a mix)")
        return _family_bodies(*docs[0])
    bodies, diameters, seen = [], [], {}

    def add(b: Body) -> None:
        n = seen.get(b.name, 0)
        seen[b.name] = n + 1
        bodies.append(
            Body(f"{b.name}_{n + 1}", len(bodies) + 1, b.points_mm)
            if n
            else Body(b.name, len(bodies) + 1, b.points_mm)
        )

    for i, (p, data) in enumerate(docs):
        b, d = _placement_body(p, data, i + 1)
        _check_spread(p, b.name, b.points_mm)
        add(b)
        diameters.append(d)
    for p, fmt in tracker:
        for b in _tracker_bodies(p, fmt):
            add(b)
    marker = max(diameters) if diameters and max(diameters) > 0 else None
    kind = "placement" if docs and not tracker else ("tracker" if tracker and not docs else "mixed")
    sources = tuple(str(p) for p, _ in docs) + tuple(str(p) for p, _ in tracker)
    return BodySet(kind, sources, tuple(bodies), None, marker)
