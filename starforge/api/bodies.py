"""Printable bodies and tracker files of a family or placement.

``starforge export`` is :func:`run_export` (CAD and tracker formats in one staged output: every
file or none); a notebook calls :func:`export_bodies` and :func:`write_tracker_files`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from starforge.cad.tools import ToolSet
from starforge.errors import StarforgeError
from starforge.io import check_writable, read_json, staged_output
from starforge.markers import marker_diameter_mm
from starforge.stars.model import Family
from starforge.words import counted

__all__ = [
    "ExportResult",
    "default_out",
    "describe_export",
    "export_bodies",
    "load_printable",
    "parse_bed",
    "run_export",
    "split_formats",
    "write_tracker_files",
]


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_bodies` or :func:`run_export` wrote.

    Attributes
    ----------
    folder : Path
        The output folder.
    files : tuple of str
        Every file written, relative to ``folder``.
    bodies : int
        Printable bodies written (0 without a CAD format).
    entries : tuple of dict
        ``bodies.json``'s entry of each body (files, size, fit, visibility, volumes).
    warnings : tuple of str
        About the printable bodies.
    mount, mount_kind : str or None
        The bodies' mount and its kind (None without a CAD format).
    seconds : float
        Time the bodies took, s.
    size_limited : bool
        Whether the bodies have a size limit (a family's; tools from a tracker file have none).
    tracker_warnings : tuple of str
        About the bodies read for tracker files (left out, renamed).
    tolerance_note : str or None
        How the tracker files' tolerances follow from the noise, when they need a word.
    """

    folder: Path
    files: tuple[str, ...]
    bodies: int = 0
    entries: tuple[dict, ...] = field(default=(), repr=False)
    warnings: tuple[str, ...] = ()
    mount: str | None = None
    mount_kind: str | None = None
    seconds: float = 0.0
    size_limited: bool = True
    tracker_warnings: tuple[str, ...] = ()
    tolerance_note: str | None = None


def split_formats(text: str) -> tuple[list[str], list[str]]:
    """``"step,stl,qtm"`` -> (CAD formats, tracker formats); unknown ones list every known one.

    Examples
    --------
    >>> split_formats("step, qtm,stl,step")
    (['step', 'stl'], ['qtm'])
    """
    from starforge.cad.export import CAD_FORMATS
    from starforge.tracking.formats import TRACKER_FORMATS

    known = f"{', '.join(CAD_FORMATS)} (CAD), {', '.join(TRACKER_FORMATS)} (tracker)"
    cad, trk = [], []
    for f in str(text).split(","):
        f = f.strip().lower()
        if not f:
            continue
        if f in CAD_FORMATS:
            if f not in cad:
                cad.append(f)
        elif f in TRACKER_FORMATS:
            if f not in trk:
                trk.append(f)
        else:
            raise StarforgeError(f"format must be one or more of {known}, comma-separated, got {f!r}")
    if not cad and not trk:
        raise StarforgeError(f"format is empty: give one or more of {known}, comma-separated")
    return cad, trk


#: the widest print bed a plate is laid out for, mm (far beyond any printer's)
MAX_BED_MM = 10_000.0


def parse_bed(text: str) -> tuple[float, float]:
    """``"200x250"`` -> (200.0, 250.0) mm.

    Examples
    --------
    >>> parse_bed("200x250")
    (200.0, 250.0)
    """
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 2 or not all(0 < v <= MAX_BED_MM for v in vals):  # also refuses nan
        raise StarforgeError(
            f"--bed must be WIDTHxDEPTH in mm, each in (0, {MAX_BED_MM:,.0f}], e.g. 200x250, got {text!r}"
        )
    return vals


def default_out(file: Path, cad: bool) -> Path:
    """``<folder of FILE>/bodies`` for CAD formats, ``<folder of FILE>/tracker`` otherwise.

    Examples
    --------
    >>> default_out(Path("out/f/family.json"), True).as_posix()
    'out/f/bodies'
    """
    folder = file.parent if file.suffix else file
    return folder / ("bodies" if cad else "tracker")


def load_printable(path: str | Path, marker: str | float | None = None):
    """What ``export`` prints from ``path``: a ``family.json`` (or its folder) as a
    :class:`~starforge.stars.model.Family`, or a tracker file's rigid bodies (QTM, Vicon, Atracsys,
    NDI .rom, Motive, CSV; 3 to 16 markers each) as a :class:`~starforge.cad.tools.ToolSet`, each
    body in its own placement frame, its files named after it.

    ``marker``: the marker (diameter in mm or catalogue name) a tool's spheres are printed for;
    None takes the file's, else 4 mm.  A family keeps the marker it was made for.

    Examples
    --------
    >>> import tempfile
    >>> f = Path(tempfile.mkdtemp()) / "wand.csv"
    >>> _ = f.write_text("body,marker,x_mm,y_mm,z_mm\\n" + "".join(
    ...     f"wand,{i},{x},{y},{z}\\n" for i, (x, y, z) in enumerate([(0, 0, 0), (40, 0, 0), (0, 55, 0), (70, 30, 5), (20, 80, 10)])))
    >>> tools = load_printable(f)
    >>> [(t.name, len(t.vertices)) for t in tools.stars], tools.spec.marker_mm
    ([('wand', 5)], 4.0)
    """
    from starforge.cad.tools import tool_set
    from starforge.stars.model import FORMAT, load_family
    from starforge.tracking.convert import file_stems, read_records

    p = Path(path)
    src = p / "family.json" if p.is_dir() else p
    if src.suffix.lower() == ".json":
        data = read_json(src, what="family file")
        if data.get("format") != FORMAT:
            raise StarforgeError(
                f"CAD formats (step, stl, 3mf) print a family.json or a tracker file's bodies; {src} is "
                f"{data.get('format')!r}"
            )
        return load_family(src)
    records = read_records([src]).records
    stems = file_stems([r.name for r in records])
    bodies = [(s, r.points_mm, r.body_id, r.marker_mm) for s, r in zip(stems, records, strict=True)]
    return tool_set(bodies, name=src.stem, marker_mm=None if marker is None else marker_diameter_mm(marker))


def run_export(
    file: str | Path,
    formats: str = "step,stl,3mf",
    *,
    out: str | Path | None = None,
    mount: str | None = None,
    ids: str | None = None,
    sets: Sequence[str] = (),
    bed: str = "200x200",
    gap_mm: float = 5.0,
    plate: bool = True,
    preview: bool = False,
    allow_oversize: bool = False,
    id_start: int = 1,
    noise_mm: float = 0.2,
    force: bool = False,
    **body_options,
) -> ExportResult:
    """``starforge export`` as one call: printable bodies of a family (``formats`` ``step``,
    ``stl``, ``3mf``) and tracker files of a family or placement (the registry's formats), in
    one staged output.  Every check that can fail (formats, mount, stems, ids, fit, tracker
    ids, existing files) runs before any file is written.

    Parameters
    ----------
    file : path
        A family.json (or its folder), or a placement.json for tracker formats.
    formats : str
        Comma list, e.g. ``"step,stl,qtm"``.
    out : path, optional
        Output folder (default :func:`default_out`).
    bed : str
        Print bed ``WIDTHxDEPTH``, mm.
    **body_options
        :func:`starforge.cad.describe.describe_bodies`'s (``seat``, ``marker``, ``stem_mm``, ``label``...).

    Examples
    --------
    >>> import tempfile
    >>> from starforge.api import make_family, plan_family, write_family
    >>> fam = make_family(plan_family(box_mm=(20.8, 12.6, 48.3), count=2, mount="flat"))
    >>> folder = write_family(fam, Path(tempfile.mkdtemp()) / "f")
    >>> run = run_export(folder / "family.json", "stl,csv", plate=False)
    >>> run.folder.name, run.bodies, sorted(run.files)[:2]
    ('bodies', 2, ['bodies.json', 'csv/custom_001.csv'])
    """
    from starforge.cad.describe import describe_bodies
    from starforge.spec import in_range
    from starforge.stars.spec import MAX_NOISE_MM

    in_range("noise", noise_mm, 0.0, MAX_NOISE_MM)  # checked whatever the formats, before any work
    cad, trk = split_formats(formats)
    worker = None
    file = Path(file)
    try:
        src = file / "family.json" if file.is_dir() else file
        out = Path(out) if out is not None else default_out(src, bool(cad))
        family = None
        if cad:
            if "step" in cad:  # its worker loads the CAD kernel while the family is read and checked
                from starforge.cad.step_worker import launch

                worker = launch()
            family = load_printable(src, body_options.get("marker"))
            from starforge.cad.export import expected_files, export_family, print_layout

            bed_mm = parse_bed(bed)
            # fail before the work, not after: mount, stems, ids, fit, existing files
            m, spec, id_list, bodies = describe_bodies(family, mount, sets, ids, allow_oversize, **body_options)
            _, beds = print_layout(bodies, bed_mm, gap_mm, plate)
            check_writable(out, expected_files(bodies, cad, plate, preview, len(beds)), force)
        elif ids or sets or preview:
            raise StarforgeError("--ids, --set and --preview apply to CAD formats (step, stl, 3mf)")
        if trk:
            from starforge.spec import non_negative
            from starforge.tracking.bodies import load_bodies
            from starforge.tracking.export import check_exportable
            from starforge.tracking.formats import parse_formats

            non_negative("noise", noise_mm)
            trk = parse_formats(trk)
            bodyset = load_bodies(src)  # read and checked before any file is written
            check_exportable(bodyset, trk, id_start)
            if not cad:
                check_writable(
                    out, [f"{f}/{b.name}" for f in trk for b in bodyset.bodies] + ["trackers.json"], force
                )
        rep = summary = None
        written: list = []
        previews = None
        if preview:
            from functools import partial

            from starforge.render.bodies import draw_previews

            previews = partial(draw_previews, box_mm=family.spec.box_mm)  # the sheet draws the limit
        with staged_output(out, force) as stage:
            if cad:
                rep = export_family(
                    family, stage, m, spec, formats=cad, ids=id_list, bed_mm=bed_mm, gap_mm=gap_mm,
                    plate=plate, preview=previews, allow_oversize=allow_oversize, bodies=bodies,
                    step_worker=worker,
                )  # fmt: skip
                written.extend(rep.files)
            if trk:
                from starforge.tracking.export import write_bodies

                summary = write_bodies(bodyset, trk, stage, id_start, noise_mm)
                summary = {
                    "format": "starforge.trackers",
                    "version": 1,
                    "input": str(src),
                    "id_start": id_start,
                    **summary,
                }
                (stage / "trackers.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
                written.extend([*summary["files"], "trackers.json"])
    finally:
        if worker is not None:
            worker.kill()  # ended already, or never given a job (a refusal above)
    return ExportResult(
        folder=out,
        files=tuple(str(f) for f in written),
        bodies=len(rep.bodies) if rep is not None else 0,
        entries=tuple(rep.bodies) if rep is not None else (),
        warnings=tuple(rep.warnings) if rep is not None else (),
        mount=m.name if rep is not None else None,
        mount_kind=m.kind if rep is not None else None,
        seconds=rep.timings["total_s"] if rep is not None else 0.0,
        size_limited=family is None or family.spec.box_mm is not None,
        tracker_warnings=tuple(bodyset.warnings) if trk else (),
        tolerance_note=summary["tolerances"].get("note") if summary is not None else None,
    )


def describe_export(run: ExportResult) -> list[str]:
    """The lines that sum an export up: the bodies, their mount and fit, the least visible
    sphere (with a CAD format), and what was written where."""
    from starforge.cad.stems import sphere_letter

    lines = []
    if run.mount is not None:
        fits = sum(b["fits"] for b in run.entries)
        kind = "" if run.mount_kind == run.mount else f" ({run.mount_kind})"
        lines.append(
            f"{counted(run.bodies, 'body')} with mount {run.mount}{kind}: "
            + (f"{fits} within the family's size limit, " if run.size_limited else "tools without a size limit, ")
            + f"{run.seconds:.1f} s"
        )
        worst = min((v, b["name"], sphere_letter(i)) for b in run.entries for i, v in enumerate(b["visibility"]))
        lines.append(
            f"least visible sphere: {worst[1]} {worst[2]}, {worst[0]:.2f} of its upper hemisphere free "
            "(per sphere in bodies.json)"
        )
    lines.append(f"wrote {counted(len(run.files), 'file')} to {run.folder}/")
    return lines


def export_bodies(
    family: Family | ToolSet | str | Path,
    out: str | Path,
    *,
    mount: str | None = None,
    formats: Sequence[str] = ("step", "stl", "3mf"),
    ids: str | None = None,
    sets: Sequence[str] = (),
    plate: bool = True,
    preview: bool = False,
    allow_oversize: bool = False,
    force: bool = False,
) -> ExportResult:
    """Printable bodies of a family: spheres, stems and the mount, as STEP and watertight
    STL/3MF, and a print plate.

    Parameters
    ----------
    family : Family, ToolSet or path
        A family, or its ``family.json`` (or folder); or a tracker file whose rigid bodies (3 to 16
        markers) are printed as tools (:func:`load_printable`).
    out : path
        Output folder.
    mount : str, optional
        Mount template name or TOML file (``starforge mounts``); default the family's, else ``flat``.
    formats : sequence of str
        Any of ``step``, ``stl``, ``3mf``.
    ids : str, optional
        Star ids, e.g. ``"1,2,5"`` or ``"1-4"`` (default: all).
    sets : sequence of str
        Mount parameters, ``"KEY=VALUE"``.
    allow_oversize : bool
        Write bodies that do not fit the family's size limit (refused otherwise, naming the
        ``starforge stars --mount`` command that makes a family that fits).

    Examples
    --------
    >>> import tempfile
    >>> from starforge.api import make_family, plan_family
    >>> fam = make_family(plan_family(box_mm=(20.8, 12.6, 48.3), count=2, mount="flat"))
    >>> res = export_bodies(fam, Path(tempfile.mkdtemp()) / "bodies", formats=("stl",), plate=False)
    >>> res.bodies, sorted(res.files)[:2]
    (2, ['bodies.json', 'star_001.stl'])
    """
    from starforge.cad.describe import describe_bodies
    from starforge.cad.export import CAD_FORMATS, export_family

    fam = family if isinstance(family, (Family, ToolSet)) else load_printable(family)
    bad = [f for f in formats if f not in CAD_FORMATS]
    if bad:
        raise StarforgeError(f"unknown CAD format {bad[0]!r}; known: {', '.join(CAD_FORMATS)}")
    m, spec, ids, bodies = describe_bodies(fam, mount, sets, ids, allow_oversize)
    folder = Path(out)
    previews = None
    if preview:
        from functools import partial

        from starforge.render.bodies import draw_previews

        previews = partial(draw_previews, box_mm=fam.spec.box_mm)  # the sheet draws the limit
    with staged_output(folder, force) as stage:
        rep = export_family(
            fam, stage, m, spec, formats=tuple(formats), ids=ids, plate=plate, preview=previews, bodies=bodies,
            allow_oversize=allow_oversize,
        )
        files = tuple(sorted(str(p.relative_to(stage)) for p in stage.rglob("*") if p.is_file()))
    return ExportResult(
        folder, files, len(bodies), tuple(rep.bodies), tuple(rep.warnings), m.name, m.kind, rep.timings["total_s"]
    )


def write_tracker_files(
    sources: Sequence[str | Path],
    out: str | Path,
    *,
    formats: Sequence[str] = ("qtm", "vsk", "atracsys", "csv"),
    noise_mm: float = 0.2,
    force: bool = False,
) -> dict:
    """Rigid-body files trackers load, for every body in ``sources`` (family.json,
    placement.json or tracker files); returns ``trackers.json``'s content.

    Parameters
    ----------
    formats : sequence of str
        Any of the registry's (``starforge templates`` lists them): ``qtm``, ``vsk``,
        ``atracsys``, ``rom``, ``motive``, ``csv``.
    noise_mm : float
        Marker noise the written tolerances assume, sigma per axis, mm.
    """
    from starforge.tracking.export import write_rigid_bodies

    folder = Path(out)
    with staged_output(folder, force) as stage:
        doc = write_rigid_bodies([Path(p) for p in sources], list(formats), stage, noise_mm=noise_mm)
    return doc
