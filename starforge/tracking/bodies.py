"""Rigid bodies as a tracker sees them: named marker sets in mm, read from starforge's JSON files
or from the tracker files a lab already has.

* A star family (``family.json``, mm) gives one body per star: its four sphere centres in the
  family's placement frame; its tip is the family's (``summary.tip_mm``, by default
  :func:`starforge.geometry.rigid.default_tip_mm`).
* A prop placement (``placement.json``, metres) gives one body: its markers in the prop frame,
  converted to mm here.  Its tip is the corner of the prop's bounding box where the predicted
  target registration error is largest (TRE^2 is a convex quadratic in the target point, so its
  maximum over the box is at a corner): the worst point of the prop.
* Every tracker format of the registry (:mod:`starforge.tracking.formats`: QTM 6DOF settings or
  body files, Vicon VSK, Atracsys ``.ini``, NDI ``.rom``, starforge's body CSV) gives its bodies
  as written, in mm; their tip is the body's origin, the point trackers report (a tool's tip is
  usually defined there).  A body with fewer than 3 markers (a VSK skeleton's one- or
  two-marker segment) is no rigid body: it is left out and named in a warning.

Any mix of these may be read together (a lab's existing bodies beside new ones): names are made
unique, the match window defaults to the smallest family tolerance.  Bodies of any marker count
from 3 to :data:`MAX_MARKERS` are kept.  Every body is checked for truth before use: at least 3
markers, finite coordinates, no two markers closer than 0.1 mm, not all on one line, a
spread that a marker body can have (:data:`SPREAD_MM`, else "other units?"), and bounded size
(:data:`MAX_MARKERS` per body, :data:`MAX_TRIANGLES` in all).
"""

from __future__ import annotations

import itertools
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.io import check_input_file, read_json

PLACEMENT_FORMAT = "starforge.placement"
FAMILY_FORMAT = "starforge.family"

#: marker spreads a rigid body can have, mm (a body outside these is in other units or corrupt)
SPREAD_MM = (1.0, 20_000.0)
#: how far from its origin a marker of a body may lie, mm (100 m: any room; beyond, the file is
#: in other units or corrupt, and squares of its coordinates overflow)
MAX_COORDINATE_MM = 1e5
#: markers closer than this are one marker twice, mm
MIN_SEPARATION_MM = 0.1
#: markers per body at most (a tracker identifies from marker triples: C(n, 3) of them)
MAX_MARKERS = 64
#: marker triangles of all bodies together at most (what identification and --avoid index)
MAX_TRIANGLES = 2_000_000


@dataclass(frozen=True)
class Body:
    """One rigid body.

    Attributes
    ----------
    name : str              safe for file names (letters, digits, ``_``, ``-``, ``.``)
    id : int                numeric id (star id, or 1.. in reading order)
    points_mm : (n, 3) float, mm   marker centres in the body's own frame
    tip_mm : (3,) float or None, mm   the body's target point for accuracy reports (None: the
        body set's default)
    source : str            the file it was read from
    normals : (n, 3) float or None   unit direction each marker faces, where known (a
        placement's surface normals); None: the placement frame's +z (a star faces up)
    """

    name: str
    id: int
    points_mm: np.ndarray
    tip_mm: tuple[float, float, float] | None = None
    source: str = ""
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = np.array(self.points_mm, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 1 or not np.isfinite(p).all():
            raise StarforgeError(f"body {self.name}: points_mm must be (n, 3) finite numbers")
        p.setflags(write=False)
        object.__setattr__(self, "points_mm", p)
        if self.normals is not None:
            nrm = np.array(self.normals, dtype=float).reshape(-1, 3)
            if nrm.shape != p.shape or not np.isfinite(nrm).all():
                raise StarforgeError(f"body {self.name}: normals must be one finite (3,) vector per marker")
            length = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = np.where(length > 0, nrm / np.where(length > 0, length, 1.0), 0.0)
            nrm.setflags(write=False)
            object.__setattr__(self, "normals", nrm)

    @property
    def n_markers(self) -> int:
        return len(self.points_mm)


@dataclass(frozen=True)
class BodySet:
    """Bodies read from one or more files.

    Attributes
    ----------
    kind : "family", "placement", "tracker" (vendor or CSV files) or "mixed"
    sources : tuple of str          the files read
    bodies : tuple of Body
    tolerance_mm : float or None    the smallest family design tolerance (faces differ by this), mm
    marker_mm : float or None       marker sphere diameter, mm
    default_tip_mm : (3,) float     the tip of bodies that carry none, mm
    tip_source : str                where the tips come from
    notes : tuple of str            what reading assumed
    warnings : tuple of str         what reading left out (bodies with fewer than 3 markers)
    """

    kind: str
    sources: tuple[str, ...]
    bodies: tuple[Body, ...]
    tolerance_mm: float | None = None
    marker_mm: float | None = None
    default_tip_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_source: str = "the bodies' own origin"
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def names(self) -> list[str]:
        return [b.name for b in self.bodies]

    @property
    def min_markers(self) -> int:
        return min(b.n_markers for b in self.bodies)

    def tips_mm(self) -> np.ndarray:
        """(B, 3) target point of every body, mm."""
        return np.array(
            [b.tip_mm if b.tip_mm is not None else self.default_tip_mm for b in self.bodies], float
        )


def safe_name(text: str) -> str:
    """``text`` reduced to characters safe in file names and XML attribute values."""
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text)).strip("._")
    return s or "body"


TIP_SOURCES = {
    "family": "the family's tip: on the long axis of the placement frame, one limit length below the mount face",
    "placement": "the prop's bounding-box corner with the largest predicted TRE",
    "tracker": "the body's origin (the point a tracker reports)",
}


def check_body(where, name: str, P: np.ndarray) -> None:
    """One-line refusal of a body a tracker could not hold (see the module docstring)."""
    if len(P) < 3:
        raise StarforgeError(f"{where}: body {name} has {len(P)} markers; a rigid body needs at least 3")
    if len(P) > MAX_MARKERS:
        raise StarforgeError(f"{where}: body {name} has {len(P)} markers; at most {MAX_MARKERS} per body")
    if not np.isfinite(P).all():
        raise StarforgeError(f"{where}: body {name} has coordinates that are not finite numbers; fix them in the file")
    if np.abs(P).max() > MAX_COORDINATE_MM:
        raise StarforgeError(
            f"{where}: body {name} has markers beyond {MAX_COORDINATE_MM / 1000:g} m of its origin "
            "; save the file in millimetres (a file in other units reads 1000 times too large)"
        )
    spread = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    if not SPREAD_MM[0] <= spread <= SPREAD_MM[1]:
        raise StarforgeError(
            f"{where}: body {name} spans {spread:.4g} mm; a marker body spans {SPREAD_MM[0]:g} to "
            f"{SPREAD_MM[1]:g} mm (is the file in other units?)"
        )
    d = np.linalg.norm(P[:, None] - P[None], axis=2)[np.triu_indices(len(P), 1)]
    if d.min() < MIN_SEPARATION_MM:
        raise StarforgeError(
            f"{where}: body {name} has two markers {d.min():.3g} mm apart (one marker given twice?)"
        )
    C = P - P.mean(axis=0)
    axis = np.linalg.svd(C, full_matrices=False)[2][0]
    off_line = float(np.linalg.norm(C - np.outer(C @ axis, axis), axis=1).max())
    if off_line < MIN_SEPARATION_MM:
        raise StarforgeError(
            f"{where}: body {name}'s markers lie on one line (all within {MIN_SEPARATION_MM:g} mm of it): no tracker can tell "
            f"its rotation about that line; a rigid body needs markers off the line"
        )


def _family_bodies(path: Path, data: dict) -> tuple[list[Body], float, float]:
    from starforge.geometry.rigid import default_tip_mm
    from starforge.stars.model import family_from_json

    fam = family_from_json(data, where=str(path))
    base = safe_name(fam.spec.name)
    width = max(3, len(str(max(s.id for s in fam.stars))))
    tip = fam.spec.tip_mm if fam.spec.tip_mm is not None else default_tip_mm(fam.spec.box_mm)
    tip = tuple(float(x) for x in tip)
    # a family written from named bodies (starforge convert / measure) keeps each star's name
    named = {s.get("id"): s.get("name") for s in data.get("stars", []) if isinstance(s, dict)}
    bodies = [
        Body(safe_name(named.get(s.id) or f"{base}_{s.id:0{width}d}"), int(s.id), s.vertices, tip, str(path))
        for s in fam.stars
    ]
    for b in bodies:
        check_body(path, b.name, b.points_mm)
    return bodies, float(fam.spec.tol_mm), float(fam.spec.marker_mm)


def prop_tip_mm(points_mm: np.ndarray, bounds_mm: np.ndarray) -> tuple[float, float, float]:
    """The corner of the box ``bounds_mm`` (2, 3) where the predicted TRE of a fit on
    ``points_mm`` is largest (the worst target on the prop)."""
    from starforge.geometry.rigid import tre_rms

    corners = np.array(list(itertools.product(*bounds_mm.T)), dtype=float)  # (8, 3)
    tre = tre_rms(np.broadcast_to(points_mm, (8, *points_mm.shape)), corners, 1.0)
    return tuple(float(x) for x in corners[int(np.argmax(tre))])


def _placement_body(path: Path, data: dict, notes: list) -> tuple[Body, float]:
    if data.get("version") != 1:
        raise StarforgeError(f"{path}: unsupported placement version {data.get('version')!r}, expected 1")
    try:
        prop = data.get("prop", {}) or {}
        # a tracker sees the balls' centres: one radius off the surface (placements that record them)
        centres = (data.get("tracked", {}) or {}).get("marker_centres_m")
        src = centres if centres is not None else [m["position"] for m in data["markers"]]
        pos = np.array(src, dtype=float).reshape(-1, 3)
        nrm = [m.get("normal") for m in data.get("markers", [])]
        normals = (
            np.array(nrm, dtype=float).reshape(-1, 3) if nrm and all(v is not None for v in nrm) else None
        )
        if normals is not None and normals.shape != pos.shape:
            normals = None
        name = str(prop.get("name", path.parent.name or path.stem))
        diameter_m = float(data.get("marker_diameter_m", 0.0))
        bounds = prop.get("bounds_m")
        bounds = None if bounds is None else np.array(bounds, dtype=float).reshape(2, 3) * 1000.0
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise StarforgeError(f"{path} has malformed markers ({exc.__class__.__name__}: {exc})") from None
    if len(pos) == 0:
        raise StarforgeError(f"{path} holds no markers")
    P = pos * 1000.0
    check_body(path, name, P)
    if bounds is not None and np.isfinite(bounds).all() and (bounds[1] >= bounds[0]).all():
        tip = prop_tip_mm(P, bounds)
    else:
        tip = (0.0, 0.0, 0.0)
        notes.append(f"{path}: no prop bounds_m; its tip is the prop frame's origin")
    return Body(safe_name(name), 0, P, tip, str(path), normals), diameter_m * 1000.0


def _tracker_bodies(path: Path, fmt: str, warnings: list) -> list[Body]:
    from starforge.tracking.formats import FORMATS

    bodies = []
    small = []
    for name, P in FORMATS[fmt].read(path).items():
        if len(P) < 3:
            small.append(f"{name} ({len(P)} marker{'s' if len(P) != 1 else ''})")
            continue
        check_body(path, name, P)
        bodies.append(Body(safe_name(name), 0, P, (0.0, 0.0, 0.0), str(path)))
    if not bodies:
        raise StarforgeError(
            f"{path}: no body with 3 or more markers (a rigid body needs at least 3): {', '.join(small[:5])}"
        )
    if small:
        more = f" and {len(small) - 10} more" if len(small) > 10 else ""
        warnings.append(
            f"{path}: left out {len(small)} bodies with fewer than 3 markers (no rigid body): "
            f"{', '.join(small[:10])}{more}"
        )
    return bodies


def _resolve(p: Path) -> Path:
    if p.is_dir():
        for cand in ("family.json", "placement.json"):
            if (p / cand).exists():
                return p / cand
    return p


def check_body_files(paths, what: str = "input file") -> list[Path]:
    """The files :func:`load_bodies` would read (a folder: its family.json or placement.json),
    each checked (:func:`starforge.io.check_input_file`: it exists, is a regular file of a
    readable size, no symbolic-link loop) and given once; StarforgeError in one line otherwise.
    Cheap: commands call it before their work starts."""
    if isinstance(paths, str | Path):
        paths = [paths]
    paths = [_resolve(Path(p)) for p in paths]
    if not paths:
        raise StarforgeError(f"no {what} given")
    first: dict[str, Path] = {}
    for p in paths:
        check_input_file(p, what, "json" if p.suffix.lower() == ".json" else "tracker")
        key = os.path.realpath(p)
        if key in first:
            raise StarforgeError(f"{p} is given twice (as {first[key]} before): give each file once")
        first[key] = p
    return paths


def load_bodies(paths) -> BodySet:
    """Read star families, prop placements and tracker files (every format of
    :data:`starforge.tracking.formats.FORMATS`), in any mix; a folder means the family.json or placement.json inside it.

    Raises StarforgeError (one line) for a missing or corrupt file, a format it does not know,
    or a body that is not a rigid body a tracker could hold (see the module docstring).
    """
    from starforge.tracking.formats import sniff_format

    paths = check_body_files(paths)
    raw: list[Body] = []
    kinds, sources, notes, warnings = [], [], [], []
    tolerances, markers = [], []
    for p in paths:
        fmt = sniff_format(p)
        if fmt is not None and p.suffix.lower() != ".json":
            raw.extend(_tracker_bodies(p, fmt, warnings))
            kinds.append("tracker")
        else:
            if p.suffix.lower() != ".json":
                _refuse_unknown(p)
            data = read_json(p, what="input file")
            k = data.get("format")
            if k == FAMILY_FORMAT:
                bodies, tol, marker = _family_bodies(p, data)
                raw.extend(bodies)
                tolerances.append(tol)
                markers.append(marker)
                kinds.append("family")
            elif k == PLACEMENT_FORMAT:
                b, d = _placement_body(p, data, notes)
                raw.append(b)
                if d > 0:
                    markers.append(d)
                kinds.append("placement")
            else:
                raise StarforgeError(
                    f"{p} is neither a star family nor a prop placement (format {k!r}; expected "
                    f"{FAMILY_FORMAT!r} or {PLACEMENT_FORMAT!r}) nor a tracker file "
                    f"({', '.join(_format_names())})"
                )
        sources.append(str(p))
        triangles = sum(math.comb(b.n_markers, 3) for b in raw)
        if triangles > MAX_TRIANGLES:
            raise StarforgeError(
                f"the input files hold {triangles:,} marker triangles (over {len(raw):,} bodies); at most "
                f"{MAX_TRIANGLES:,}: give fewer or smaller bodies"
            )
    seen: dict[str, int] = {}
    bodies = []
    renamed = []
    for b in raw:
        n = seen.get(b.name, 0)
        seen[b.name] = n + 1
        name = f"{b.name}_{n + 1}" if n else b.name
        if n:
            renamed.append(f"{b.name} -> {name}")
        ident = b.id if kinds == ["family"] else len(bodies) + 1
        bodies.append(Body(name, ident, b.points_mm, b.tip_mm, b.source, b.normals))
    if renamed:
        shown = ", ".join(renamed[:3]) + (f" and {len(renamed) - 3} more" if len(renamed) > 3 else "")
        notes.append(f"{len(renamed)} bodies share a name with a body of another file; renamed {shown}")
    kind = kinds[0] if len(set(kinds)) == 1 else "mixed"
    if kind == "family" and len(kinds) > 1:
        kind = "mixed"
    tip_source = TIP_SOURCES.get(
        kind, "per body: " + "; ".join(f"{k}: {TIP_SOURCES[k]}" for k in sorted(set(kinds)))
    )
    default_tip = bodies[0].tip_mm if bodies[0].tip_mm is not None else (0.0, 0.0, 0.0)
    return BodySet(
        kind,
        tuple(sources),
        tuple(bodies),
        min(tolerances) if tolerances else None,
        max(markers) if markers else None,
        default_tip,
        tip_source,
        tuple(notes),
        tuple(warnings),
    )


#: files labs have that starforge does not read, with what to do instead
UNSUPPORTED = {
    ".tra": "an OptiTrack Motive 1.x rigid-body file (binary .tra) is not supported: save the rigid body in "
    "Motive 2 or later as a .motive profile",
    ".tak": "an OptiTrack take (.tak) holds recordings, not rigid-body definitions: save the rigid body as a "
    ".motive profile",
    ".c3d": "a C3D file holds marker trajectories, not rigid-body definitions",
    ".vst": "a Vicon skeleton template (.vst) is a template, not a subject's calibrated VSK: give the .vsk",
}


def _refuse_unknown(path: Path) -> None:
    """One line for a file that is neither JSON nor a tracker format starforge reads."""
    why = UNSUPPORTED.get(path.suffix.lower())
    if why is None:
        with open(path, "rb") as fh:
            head = fh.read(512).lstrip()
        if head[:1] in (b"{", b"["):
            return  # JSON under another name: read as such
        why = "not a format starforge reads"
    raise StarforgeError(
        f"{path}: {why} (tracker formats read: {', '.join(_format_names())}; or a family.json / placement.json)"
    )


def _format_names() -> list[str]:
    from starforge.tracking.formats import FORMATS

    return list(FORMATS)
