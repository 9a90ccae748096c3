"""Rigid bodies from any file starforge reads into any tracker format, keeping what both carry.

Sources: every format of the registry (:mod:`starforge.tracking.formats`), a folder of such
files, a ``family.json`` or a ``placement.json`` (through
:func:`starforge.tracking.bodies.load_bodies`).  Each body keeps its name, its marker order and
coordinates, and whatever else the source states that the target format can hold
(:data:`starforge.tracking.formats.FIELDS`: marker names, ids, normals, marker size,
tolerances, minimum markers); what the target cannot hold is named in
:attr:`Conversion.lost`.  Tolerances the source does not state are derived for the marker noise
as ``starforge export`` derives them (:func:`starforge.tracking.tolerances.export_tolerances`).

Coordinates pass unchanged: text formats write the shortest round-trip text of each double,
Motive shifts that text to metres exactly, an NDI ``.rom`` holds float32.  So a conversion
A -> B -> A gives A's doubles again when B is a text format, and A's values rounded to float32
when B is ``rom``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.stars.spec import MAX_NOISE_MM
from starforge.tracking.bodies import check_body, load_bodies, safe_name
from starforge.tracking.formats import FORMATS, Record, WriteContext, check_id_start, get_format, sniff_format

#: the words a user reads for each carried field
FIELD_WORDS = {
    "marker_names": "marker names",
    "body_id": "ids",
    "normals": "marker normals",
    "marker_mm": "marker size",
    "bone_length_tolerance_mm": "bone-length tolerance",
    "maximum_residual_mm": "maximum residual",
    "max_marker_error_mm": "maximum marker error",
    "min_markers": "minimum markers",
}
#: files a folder may hold at most (a lab's body files, not a recording archive)
MAX_FOLDER_FILES = 10_000


@dataclass(frozen=True)
class Source:
    """Body records read from the inputs.

    records : tuple of Record        every body, names made unique, in reading order
    sources : tuple of str           the files read
    carried : tuple of str           fields any source stated (:data:`FIELD_WORDS` keys)
    warnings : tuple of str          what reading left out
    origins : tuple of str           the file each record was read from
    """

    records: tuple[Record, ...]
    sources: tuple[str, ...]
    carried: tuple[str, ...]
    warnings: tuple[str, ...] = ()
    origins: tuple[str, ...] = ()


@dataclass(frozen=True)
class Conversion:
    """What :func:`convert_records` made.

    files : dict of str -> bytes     relative output path -> content
    format : str                     the target format
    lost : tuple of str              fields the sources state that the target cannot hold
    derived : tuple of str           tolerance fields the target holds that were derived, not read
    """

    files: dict[str, bytes]
    format: str
    lost: tuple[str, ...]
    derived: tuple[str, ...]

    def lost_line(self) -> str | None:
        """One line naming what the target cannot carry (None: nothing is lost)."""
        if not self.lost:
            return None
        return f"{self.format} cannot carry: {', '.join(FIELD_WORDS[f] for f in self.lost)}"


def expand_inputs(paths) -> list[Path]:
    """Files behind ``paths``: a folder means its family.json or placement.json when it holds
    one, else every tracker file directly inside it (sorted by name)."""
    out: list[Path] = []
    for p in (Path(x) for x in ([paths] if isinstance(paths, str | Path) else paths)):
        if not p.is_dir():
            out.append(p)
            continue
        for cand in ("family.json", "placement.json"):
            if (p / cand).is_file():
                out.append(p / cand)
                break
        else:
            files = sorted(f for f in p.iterdir() if f.is_file() and not f.name.startswith("."))
            if len(files) > MAX_FOLDER_FILES:
                raise StarforgeError(
                    f"{p} holds {len(files):,} files; give at most {MAX_FOLDER_FILES:,} at once"
                )
            found = [f for f in files if f.stat().st_size > 0 and sniff_format(f) is not None]
            if not found:
                raise StarforgeError(
                    f"{p} holds no tracker file ({', '.join(FORMATS)}), family.json or placement.json; "
                    "give a family.json, a placement.json or a tracker file (or a folder that holds one)"
                )
            out.extend(found)
    if not out:
        raise StarforgeError("no input file given")
    return out


def _json_records(path: Path) -> list[Record]:
    bs = load_bodies([path])
    size = bs.marker_mm if bs.marker_mm else None
    return [Record(b.name, b.points_mm, normals=b.normals, marker_mm=size) for b in bs.bodies]


def read_records(paths) -> Source:
    """Body records of every input (see :func:`expand_inputs`), each checked as a rigid body a
    tracker could hold (:func:`starforge.tracking.bodies.check_body`); bodies with fewer than 3
    markers are left out and named in a warning.  Raises StarforgeError (one line)."""
    from starforge.io import check_input_file

    files = expand_inputs(paths)
    records: list[Record] = []
    origins: list[str] = []
    warnings: list[str] = []
    seen: dict[Path, Path] = {}
    for p in files:
        check_input_file(p, "input file")
        key = p.resolve()
        if key in seen:
            raise StarforgeError(f"{p} is given twice (as {seen[key]} before): give each file once")
        seen[key] = p
        fmt = sniff_format(p)
        if fmt is None or p.suffix.lower() == ".json":
            got = _json_records(p)
        else:
            got = []
            for r in FORMATS[fmt].load(p):
                if len(r.points_mm) < 3:
                    warnings.append(
                        f"{p}: left out {r.name} ({len(r.points_mm)} markers; a rigid body needs 3)"
                    )
                    continue
                check_body(p, r.name, r.points_mm)
                got.append(r)
            if not got:
                raise StarforgeError(f"{p}: no body with 3 or more markers (a rigid body needs at least 3)")
        records.extend(got)
        origins.extend([str(p)] * len(got))
    names: dict[str, int] = {}
    unique = []
    for r in records:
        n = names.get(r.name, 0)
        names[r.name] = n + 1
        unique.append(r if not n else _renamed(r, f"{r.name}_{n + 1}"))
    carried = sorted(set().union(*(r.carried() for r in unique)), key=list(FIELD_WORDS).index)
    return Source(tuple(unique), tuple(map(str, files)), tuple(carried), tuple(warnings), tuple(origins))


def _renamed(r: Record, name: str) -> Record:
    return Record(
        name, r.points_mm, r.marker_names, r.body_id, r.normals, r.marker_mm, r.tolerances, r.min_markers
    )


def file_stems(names) -> list[str]:
    """File names (without suffix) for body ``names``: safe characters, unique regardless of case."""
    taken: dict[str, int] = {}
    out = []
    for name in names:
        stem = safe_name(name)
        n = taken.get(stem.lower(), 0)
        taken[stem.lower()] = n + 1
        out.append(f"{stem}_{n + 1}" if n else stem)
    return out


def convert_records(source: Source, fmt: str, noise_mm: float = 0.2, id_start: int = 1) -> Conversion:
    """Every body of ``source`` as a file of format ``fmt``: ``<name><suffix>`` (the name made
    safe for files).  Refuses (StarforgeError) a body the format cannot hold."""
    from starforge.tracking.tolerances import export_tolerances

    f = get_format(fmt)
    recs = source.records
    check_id_start(id_start, len(recs))
    if f.max_markers is not None:
        big = [r for r in recs if len(r.points_mm) > f.max_markers]
        if big:
            raise StarforgeError(
                f"a {f.vendor} {f.name} file holds at most {f.max_markers} markers; {big[0].name} has "
                f"{len(big[0].points_mm)}: choose another --format"
            )
    derived_tol = export_tolerances([r.points_mm for r in recs], noise_mm)
    files: dict[str, bytes] = {}
    stems = file_stems([r.name for r in recs])
    derived: set[str] = set()
    for k, r in enumerate(recs):
        tol = dict(derived_tol)
        if r.tolerances:  # the file's own: no note about a noise it did not assume
            tol = {key: v for key, v in tol.items() if key not in ("noise_mm", "keep")} | r.tolerances
        derived |= {key for key in f.carries if key.endswith("_mm") and key not in r.tolerances}
        ctx = WriteContext(
            index=k,
            geometry_id=r.body_id if r.body_id is not None else id_start + k,
            marker_radius_mm=(r.marker_mm or 4.0) / 2.0,
            normals=r.normals,
            tolerances=tol,
            min_markers=min(r.min_markers or 3, len(r.points_mm)),
            marker_names=r.marker_names,
        )
        files[f"{stems[k]}{f.suffix}"] = f.write(r.name, np.asarray(r.points_mm), ctx)
    lost = tuple(c for c in source.carried if c not in f.carries)
    return Conversion(files, f.name, lost, tuple(sorted(derived)))


def convert_to(
    source: Source, fmt: str, noise_mm: float = 0.2, id_start: int = 1, mount=None, reserve_for=None
) -> Conversion:
    """:func:`convert_records`, or with ``fmt`` ``family`` a ``family.json`` of the bodies
    (4 markers each; :func:`starforge.tracking.asfamily.family_from_bodies`, with ``mount`` and
    ``reserve_for``)."""
    if not (np.isfinite(noise_mm) and 0 < noise_mm <= MAX_NOISE_MM):
        raise StarforgeError(f"noise must be in (0, {MAX_NOISE_MM:g}] mm (sigma per axis), got {noise_mm:g}")
    if str(fmt).strip().lower() != "family":
        if str(fmt).strip().lower() not in FORMATS:
            raise StarforgeError(f"unknown --format {fmt!r}; known: {', '.join(FORMATS)}, family")
        return convert_records(source, fmt, noise_mm, id_start)
    import json

    from starforge.tracking.asfamily import family_from_bodies

    sizes = {r.marker_mm for r in source.records if r.marker_mm}
    data = family_from_bodies(
        [(r.name, r.points_mm, r.marker_names) for r in source.records],
        name=safe_name(Path(source.sources[0]).stem) if len(source.sources) == 1 else "bodies",
        marker_mm=min(sizes) if sizes else None,
        noise_mm=noise_mm,
        mount=mount,
        reserve_for=reserve_for,
    )
    lost = tuple(c for c in source.carried if c not in ("marker_names", "marker_mm"))
    text = json.dumps(data, indent=1) + "\n"
    return Conversion({"family.json": text.encode("utf-8")}, "family", lost, ())
