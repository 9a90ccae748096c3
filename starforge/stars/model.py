"""Star and family values, and ``family.json`` / ``family.csv`` I/O (the source of truth).

``family.json`` layout (version 2; version 1 files are still read)::

    {
      "format": "starforge.family", "version": 2,
      "spec": {...StarSpec fields...},
      "units": "mm",
      "summary": {"size": .., "rule": "face", "upper_bound": .., "optimal": false, ...},
      "stars": [
        {"id": 1,
         "lengths": {"u": .., "U": .., "v": .., "V": .., "w": .., "W": ..},   # mm
         "vertices": [[x, y, z] x 4],        # A, B, C, D sphere centres, mm, placement frame
         "obb": {"extents": [x, y, z],        # the fitting box's sides along placement x, y, z, mm
                 "transform": 4x4,            # construction frame -> placement frame
                 "method": "minimum" | "fitting" | "covariance",
                 "min_extents": [a, b, c]},   # the minimum-volume box's sides, sorted, mm
         "depth_mm": ..,                      # width: smallest box side in any orientation, mm
         "faces": [[a, b, c] x 4],            # sorted sides of ABC, ABD, ACD, BCD, mm
         "margins": {"internal_mm": .., "family_face_mm": .., "family_pair_mm": ..},
         "accuracy": {"rotation_deg": .., "rotation_hidden_deg": .., "tip_tre_mm": ..,
                      "tip_tre_hidden_mm": .., "worst_hidden_marker": "A"}},
        ...
      ]
    }

``obb.method``: ``minimum`` when the minimum-volume box fits the limit, ``fitting`` when only
another orientation does (found by the fit decision), ``covariance`` for the paper's box.
Accuracy is predicted for the spec's ``noise_mm`` at the summary's ``tip_mm``.

Vertices are in the paper's placement frame: z along the longest box side, y along the
shortest, origin at the centre of the bottom face, so the box spans
``[-x/2, x/2] x [-y/2, y/2] x [0, z]``.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.tetra import LENGTH_NAMES, face_sides
from starforge.io import read_json
from starforge.spec import to_mapping
from starforge.stars.spec import StarSpec, spec_from_mapping

FORMAT = "starforge.family"
VERSION = 2
#: versions this starforge reads
READABLE = (1, 2)


@dataclass(frozen=True)
class Star:
    """One marker star (frozen; arrays are read-only copies).

    Attributes
    ----------
    id : int
    lengths : (6,) float, mm          (u, U, v, V, w, W)
    vertices : (4, 3) float, mm       sphere centres A, B, C, D in the placement frame
    obb_extents : (3,) float, mm      box sides along placement x, y, z
    obb_transform : (4, 4) float      construction frame -> placement frame
    obb_method : str                  "minimum", "fitting" or "covariance"
    margins : dict                    internal_mm, family_face_mm (and family_pair_mm)
    min_box_extents : (3,) float, mm  sides of the minimum-volume box, sorted (NaN if unknown)
    depth_mm : float or None          the star's width (smallest box side in any orientation)
    accuracy : dict                   predicted rotation error and tip TRE (see the module doc)
    """

    id: int
    lengths: np.ndarray
    vertices: np.ndarray
    obb_extents: np.ndarray
    obb_transform: np.ndarray
    obb_method: str = "minimum"
    margins: dict = field(default_factory=dict)
    min_box_extents: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    depth_mm: float | None = None
    accuracy: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        arr = np.array(self.min_box_extents, dtype=float)
        if arr.shape != (3,):
            raise StarforgeError(f"star {self.id}: min_box_extents must be 3 numbers")
        arr.setflags(write=False)
        object.__setattr__(self, "min_box_extents", arr)
        for name, shape in (
            ("lengths", (6,)),
            ("vertices", (4, 3)),
            ("obb_extents", (3,)),
            ("obb_transform", (4, 4)),
        ):
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != shape or not np.isfinite(arr).all():
                raise StarforgeError(f"star {self.id}: {name} must be {shape} finite numbers")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def faces(self) -> np.ndarray:
        """(4, 3) sorted side lengths of faces ABC, ABD, ACD, BCD, mm."""
        return face_sides(self.lengths)

    @property
    def lengths_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in zip(LENGTH_NAMES, self.lengths, strict=True)}

    def to_json(self) -> dict:
        obb = {
            "extents": _rounded(self.obb_extents),
            "transform": _rounded(self.obb_transform),
            "method": self.obb_method,
        }
        if np.isfinite(self.min_box_extents).all():
            obb["min_extents"] = _rounded(self.min_box_extents)
        out = {
            "id": int(self.id),
            "lengths": {k: round(v, 9) for k, v in self.lengths_dict.items()},
            "vertices": _rounded(self.vertices),
            "obb": obb,
        }
        if self.depth_mm is not None:
            out["depth_mm"] = round(float(self.depth_mm), 9)
        out["faces"] = _rounded(self.faces)
        out["margins"] = {k: round(float(v), 9) for k, v in self.margins.items()}
        if self.accuracy:
            out["accuracy"] = {
                k: (round(float(v), 9) if not isinstance(v, str) else v) for k, v in self.accuracy.items()
            }
        return out


@dataclass(frozen=True)
class Family:
    """A verified family of stars with the spec that made it."""

    spec: StarSpec
    stars: tuple[Star, ...]
    summary: dict = field(default_factory=dict)
    #: wall-clock seconds per stage (not part of family.json, which depends only on the spec)
    timings: dict = field(default_factory=dict, compare=False)

    def __len__(self) -> int:
        return len(self.stars)

    def by_id(self, ids) -> list[Star]:
        """The stars with these ids, in the given order; unknown ids raise StarforgeError."""
        table = {s.id: s for s in self.stars}
        missing = [i for i in ids if i not in table]
        if missing:
            shown = ", ".join(map(str, missing[:5])) + (f" and {len(missing) - 5:,} more" if len(missing) > 5 else "")
            raise StarforgeError(
                f"star id{'s' if len(missing) > 1 else ''} {shown} not in the family; --ids takes ids in {min(table)}..{max(table)}"
            )
        return [table[i] for i in ids]

    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "units": "mm",
            "spec": to_mapping(self.spec),
            "summary": self.summary,
            "stars": [s.to_json() for s in self.stars],
        }


def _rounded(a) -> list:
    # 1e-9 mm is far below any physical meaning and keeps the JSON byte-stable across platforms
    return (np.round(np.asarray(a, dtype=float), 9) + 0.0).tolist()  # + 0.0 turns -0.0 into 0.0


def family_csv(family: Family) -> str:
    """The family table (in the spirit of the paper's Pro/ENGINEER family table), one row per star.

    Columns: id, u, U, v, V, w, W, x1, y1, z1, ..., x4, y4, z4 (mm, placement frame).
    """
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["id", *LENGTH_NAMES, *[f"{c}{i}" for i in range(1, 5) for c in "xyz"]])
    for s in family.stars:
        w.writerow(
            [s.id, *[f"{x + 0.0:.6f}" for x in s.lengths], *[f"{x:.6f}" for x in s.vertices.ravel() + 0.0]]
        )
    return buf.getvalue()


def family_from_json(data: dict, where: str = "family.json", verify: bool = True) -> Family:
    """Parse family.json data with one-line errors for a wrong format, version or content.

    With ``verify`` (the default) the family is re-checked before anything uses it: units,
    lengths against vertices, distinct non-overlapping markers, depth, every star inside its
    box and the box inside the size limit, and the uniqueness rule
    (:func:`starforge.stars.verify.check_family`).  A file edited by hand cannot slip through.
    """
    if not isinstance(data, dict):
        raise StarforgeError(f"{where} is not a starforge family file (a JSON object is expected)")
    if data.get("format") != FORMAT:
        raise StarforgeError(f"{where} is not a starforge family file (format {data.get('format')!r})")
    if data.get("version") not in READABLE:
        raise StarforgeError(
            f"{where} has family format version {data.get('version')!r}; this starforge reads versions "
            f"{', '.join(map(str, READABLE))}"
        )
    if data.get("units") != "mm":
        raise StarforgeError(
            f'{where} gives units {data.get("units")!r}; family files are in millimetres: convert its numbers to mm and write "units": "mm"'
        )
    if "spec" not in data:
        raise StarforgeError(f"{where} has no spec")
    try:
        spec = spec_from_mapping(data["spec"])
    except StarforgeError as exc:
        raise StarforgeError(f"{where}: spec: {exc}") from None
    raw = data.get("stars")
    if not isinstance(raw, list):
        raise StarforgeError(f"{where}: stars must be a list of stars")
    if len(raw) > MAX_STARS:
        raise StarforgeError(
            f"{where} holds {len(raw):,} stars; a family file holds at most {MAX_STARS:,} (no tracker tells more apart)"
        )
    stars = [_star_from_json(s, k, where) for k, s in enumerate(raw)]
    if not stars:
        raise StarforgeError(f"{where} holds no stars; make a family with `starforge stars`")
    ids = [s.id for s in stars]
    if len(set(ids)) != len(ids):
        raise StarforgeError(f"{where} has duplicate star ids")
    if verify:
        from starforge.runtime.budget import require_time
        from starforge.stars.verify import check_family, verify_seconds

        require_time(
            verify_seconds(len(stars)),
            f"verifying the {len(stars):,} stars of {where} (every pair of stars is compared)",
            "give a smaller family (starforge stars --count N) or raise --max-seconds",
        )
        problems = check_family({**data, "spec": to_mapping(spec)})  # defaults filled in
        if problems:
            more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
            raise StarforgeError(f"{where} fails verification: {problems[0]}{more}; was it edited by hand? make it again with `starforge stars`")
    return Family(spec=spec, stars=tuple(stars), summary=dict(data.get("summary", {})))


#: stars a family file may hold (the verification is quadratic in it)
MAX_STARS = 20_000
#: largest star id (ids name files: star_000001 ... star_999999)
MAX_STAR_ID = 999_999


def _star_from_json(s, k: int, where: str) -> Star:
    """One star of family.json, with errors that name the star and the key."""
    at = f"{where}: stars[{k}]"
    if not isinstance(s, dict):
        raise StarforgeError(f"{at} must be an object")
    sid = s.get("id")
    if isinstance(sid, bool) or not isinstance(sid, int | float) or not float(sid).is_integer():
        raise StarforgeError(f"{at}.id must be an integer, got {sid!r}")
    if not 1 <= sid <= MAX_STAR_ID:
        raise StarforgeError(f"{at}.id must be an integer from 1 to {MAX_STAR_ID:,}, got {sid!r}")
    at = f"{at} (id {int(sid)})"
    lengths, obb = s.get("lengths"), s.get("obb")
    for obj, key, what in (
        (s, "lengths", "lengths"),
        (s, "vertices", "vertices"),
        (s, "obb", "obb"),
        (lengths, None, "lengths"),
        (obb, "extents", "obb.extents"),
        (obb, "transform", "obb.transform"),
    ):
        if not isinstance(obj, dict) or (key is not None and key not in obj):
            raise StarforgeError(f"{at} has no {what}" if key else f"{at}: {what} must be an object")
    for name in LENGTH_NAMES:
        if name not in lengths:
            raise StarforgeError(f"{at} has no lengths.{name}")
    try:
        return Star(
            id=int(sid),
            lengths=[float(lengths[name]) for name in LENGTH_NAMES],
            vertices=s["vertices"],
            obb_extents=obb["extents"],
            obb_transform=obb["transform"],
            obb_method=str(obb.get("method", "minimum")),
            margins=dict(s["margins"]) if isinstance(s.get("margins"), dict) else {},
            min_box_extents=obb.get("min_extents", [np.nan] * 3),
            depth_mm=float(s["depth_mm"]) if "depth_mm" in s else None,
            accuracy=dict(s["accuracy"]) if isinstance(s.get("accuracy"), dict) else {},
        )
    except StarforgeError as exc:
        raise StarforgeError(f"{at}: {str(exc).split(': ', 1)[-1]}") from None
    except (TypeError, ValueError) as exc:
        raise StarforgeError(f"{at} has a value that is not a number ({exc})") from None


def load_family(path: str | Path) -> Family:
    """Read ``family.json`` (or a folder holding one) back into a verified :class:`Family`."""
    path = Path(path)
    if path.is_dir():
        path = path / "family.json"
    return family_from_json(read_json(path, what="family file"), where=str(path))
