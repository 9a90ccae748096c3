"""``starforge export``: printable bodies (STEP, STL, 3MF, plate) and tracker rigid-body files.

``FILE`` is a family.json (CAD and tracker formats) or a placement.json (tracker formats).
CAD formats are built here (:mod:`starforge.cad`); tracker formats are routed to
:func:`starforge.tracking.formats.write_rigid_bodies` inside the same staged output, so one
run either publishes every file or none.
"""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import app, console
from starforge.markers import CLEARANCE_HOLES_MM, THREADS

CAD_FORMATS = ("step", "stl", "3mf")
TRACKER_FORMATS_DOC = ("qtm", "vsk", "atracsys", "rom", "motive", "csv")


def split_formats(text: str) -> tuple[list[str], list[str]]:
    """``"step,stl,qtm"`` -> (CAD formats, tracker formats); unknown ones list every known one."""
    from starforge.errors import StarforgeError

    try:
        from starforge.tracking.formats import TRACKER_FORMATS
    except ImportError:
        TRACKER_FORMATS = TRACKER_FORMATS_DOC
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
            raise StarforgeError(
                f"unknown format {f!r}; known: {', '.join(CAD_FORMATS)} (CAD), {', '.join(TRACKER_FORMATS)} (tracker)"
            )
    if not cad and not trk:
        raise StarforgeError(f"no format given; known: {', '.join(CAD_FORMATS + tuple(TRACKER_FORMATS))}")
    return cad, trk


def parse_bed(text: str) -> tuple[float, float]:
    """``"200x250"`` -> (200.0, 250.0) mm."""
    from starforge.errors import StarforgeError

    parts = str(text).lower().replace("*", "x").split("x")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 2 or min(vals) <= 0:
        raise StarforgeError(f"--bed must be WIDTHxDEPTH in mm, e.g. 200x250, got {text!r}")
    return vals


def default_out(file: Path, cad: bool) -> Path:
    """``<folder of FILE>/bodies`` for CAD formats, ``<folder of FILE>/tracker`` otherwise."""
    folder = file.parent if file.suffix else file
    return folder / ("bodies" if cad else "tracker")


# options shared with `starforge preview`
MOUNT = typer.Option(
    None,
    "--mount",
    help="Mount template name (see `starforge mounts`) or a TOML path (default: the family's, else flat).",
)
IDS = typer.Option(None, "--ids", help="Star ids, e.g. 1,2,5 or 1-4 (default: all).")
SETS = typer.Option(
    None,
    "--set",
    help="Mount parameter override KEY=VALUE (repeatable; `starforge mounts NAME` lists them), e.g. --set holes=2 "
    f"or --set hole_mm=M3 (a metric size: its ISO 273 clearance hole, M3: {CLEARANCE_HOLES_MM['M3']:g} mm).",
)
SEAT = typer.Option(
    None,
    "--seat",
    help="How each marker sits on the end of its stem (the marker's seat, not the body's mount): sphere "
    "(printed with the body), glue (a pad), post, screw (the bought marker's stud in a tap-drill bore, M3: "
    f"{THREADS['M3'].tap_drill_mm:g} mm) or insert (its stud in a heat-set insert, M3: a "
    f"{THREADS['M3'].insert_hole_mm:g} mm hole); default: the --marker's own attachment, else the family's, "
    "else sphere.",
)
MARKER = typer.Option(
    None,
    "--marker",
    help="A bought marker from the catalogue (see `starforge templates markers`) or a TOML file (default: the "
    "family's).",
)
NOZZLE = typer.Option(
    None, "--nozzle-mm", help="Printer nozzle, mm: engraved strokes and counters are 2 x wider (default 0.4)."
)
COATING = typer.Option(
    None, "--coating-mm", help="Coating allowance on the diameter (default 0.2: 3.8 printed, 4 finished)."
)
STEM = typer.Option(None, "--stem-mm", help="Stem diameter, mm (default: 0.45 x the marker, at least 0.8).")
MIN_STEM = typer.Option(None, "--min-stem-mm", help="Printable minimum stem diameter, mm (default 0.8).")
POST = typer.Option(None, "--post-mm", help="Post diameter for --seat post, mm (default 1.5).")
NO_LABEL = typer.Option(False, "--no-label", help="Do not engrave the star id.")


_FILE = typer.Argument(..., help="family.json (or its folder), or a placement.json for tracker formats.")
_OUT = typer.Option(
    None,
    "--out",
    help="Output folder (default: <FILE's folder>/bodies with a CAD format, else <FILE's folder>/tracker).",
)


@app.command("export")
def export_cmd(
    file: Path = _FILE,
    formats: str = typer.Option(
        "step,stl,3mf",
        "--format",
        help="Comma list: step, stl, 3mf (CAD, family files) and qtm, vsk, atracsys, rom (NDI), motive (OptiTrack), csv.",
    ),
    mount: str = MOUNT,
    ids: str = IDS,
    sets: list[str] = SETS,
    seat: str = SEAT,
    marker: str = MARKER,
    nozzle_mm: float = NOZZLE,
    coating_mm: float = COATING,
    stem_mm: float = STEM,
    min_stem_mm: float = MIN_STEM,
    post_mm: float = POST,
    no_label: bool = NO_LABEL,
    bed: str = typer.Option("200x200", "--bed", help="Print bed WIDTHxDEPTH in mm for the plate."),
    gap: float = typer.Option(5.0, "--gap", help="Gap between bodies on the plate, mm."),
    no_plate: bool = typer.Option(False, "--no-plate", help="Skip plate.stl / plate.3mf."),
    preview: bool = typer.Option(
        False, "--preview", help="Also write preview/<star>.png and preview/sheet.png."
    ),
    allow_oversize: bool = typer.Option(
        False,
        "--allow-oversize",
        help="Export bodies that exceed the family's size limit (recorded in bodies.json).",
    ),
    id_start: int = typer.Option(
        1,
        "--id-start",
        help="First Atracsys geometry id (ids run on from it; give each family its own range).",
    ),
    noise: float = typer.Option(
        0.2,
        "--noise",
        help="Marker noise, sigma per axis, mm, that the tracker files' tolerances assume (QTM, NDI).",
    ),
    out: Path = _OUT,
    force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors (warnings are in bodies.json and trackers.json)."),
) -> None:
    """Write printable star bodies (one file per star per format, plus a print plate) and/or
    tracker rigid-body files, all or nothing."""
    from starforge.cad.describe import describe_bodies
    from starforge.errors import StarforgeError
    from starforge.io import read_json, staged_output

    cad, trk = split_formats(formats)
    worker = None
    try:
        from starforge.spec import in_range
        from starforge.stars.spec import MAX_NOISE_MM

        in_range("noise", noise, 0.0, MAX_NOISE_MM)  # checked whatever the formats, before any work
        src = file / "family.json" if file.is_dir() else file
        out = out if out is not None else default_out(src, bool(cad))
        family = None
        if cad:
            if "step" in cad:  # its worker loads the CAD kernel while the family is read and checked
                from starforge.cad.step_worker import StepProcess

                worker = StepProcess()
            from starforge.stars.model import FORMAT, load_family

            data = read_json(src, what="family file")
            if data.get("format") != FORMAT:
                raise StarforgeError(
                    f"CAD formats ({', '.join(cad)}) need a family.json; {src} is {data.get('format')!r}"
                )
            family = load_family(src)
            from starforge.cad.export import expected_files, export_family, print_layout
            from starforge.io import check_writable

            bed_mm = parse_bed(bed)
            # fail before the work, not after: mount, stems, ids, fit, existing files
            m, spec, id_list, bodies = describe_bodies(
                family,
                mount,
                sets,
                ids,
                allow_oversize,
                seat=seat,
                marker=marker,
                nozzle_mm=nozzle_mm,
                coating_mm=coating_mm,
                stem_mm=stem_mm,
                min_stem_mm=min_stem_mm,
                post_mm=post_mm,
                label=False if no_label else None,
            )
            _, beds = print_layout(bodies, bed_mm, gap)
            check_writable(out, expected_files(bodies, cad, not no_plate, preview, len(beds)), force)
        elif ids or sets or preview:
            raise StarforgeError("--ids, --set and --preview apply to CAD formats (step, stl, 3mf)")
        if trk:
            from starforge.tracking.bodies import load_bodies
            from starforge.tracking.export import check_exportable
            from starforge.tracking.formats import parse_formats

            trk = parse_formats(trk)
            bodyset = load_bodies(src)  # read and checked before any file is written
            check_exportable(bodyset, trk, id_start)
            if not cad:
                from starforge.io import check_writable

                check_writable(
                    out, [f"{f}/{b.name}" for f in trk for b in bodyset.bodies] + ["trackers.json"], force
                )
        rep = None
        written: list = []
        previews = None
        if preview:
            from functools import partial

            from starforge.render.bodies import draw_previews

            previews = partial(draw_previews, box_mm=family.spec.box_mm)  # the sheet draws the limit
        with staged_output(out, force) as stage:
            if cad:
                rep = export_family(
                    family,
                    stage,
                    m,
                    spec,
                    formats=cad,
                    ids=id_list,
                    bed_mm=bed_mm,
                    gap_mm=gap,
                    plate=not no_plate,
                    preview=previews,
                    allow_oversize=allow_oversize,
                    bodies=bodies,
                    step_worker=worker,
                )
                written.extend(rep.files)
            if trk:
                import json

                from starforge.tracking.export import write_bodies

                summary = write_bodies(bodyset, trk, stage, id_start, noise)
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
    if quiet:  # the warnings are in bodies.json / trackers.json
        return
    err = console(stderr=True)
    for w in bodyset.warnings if trk else ():
        err.print(f"warning: {w}", soft_wrap=True, markup=False)
    if trk and summary["tolerances"].get("note"):
        err.print(
            f"note: tracker file tolerances: {summary['tolerances']['note']}", soft_wrap=True, markup=False
        )
    if rep is not None:
        for w in rep.warnings:
            err.print(f"warning: {w}")
    con = console()
    if rep is not None:
        fits = sum(b["fits"] for b in rep.bodies)
        con.print(
            f"{len(rep.bodies)} bodies with mount {m.name}{'' if m.kind == m.name else f' ({m.kind})'}: "
            f"{fits} within the family's size limit, "
            f"{rep.timings['total_s']:.1f} s"
        )
        worst = min(
            ((v, b["name"], "ABCD"[i]) for b in rep.bodies for i, v in enumerate(b["visibility"]))
        )
        con.print(
            f"least visible sphere: {worst[1]} {worst[2]}, {worst[0]:.2f} of its upper hemisphere free "
            "(per sphere in bodies.json)"
        )
    con.print(f"wrote {len(written)} files to {out}/")

