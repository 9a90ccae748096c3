"""``starforge export``: printable bodies (STEP, STL, 3MF, plate) and tracker rigid-body files.

``FILE`` is a family.json (CAD and tracker formats) or a placement.json (tracker formats); one
run either publishes every file or none (:func:`starforge.api.run_export`).
"""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import app, console
from starforge.markers import CLEARANCE_HOLES_MM, THREADS

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


_FILE = typer.Argument(
    ...,
    help="family.json (or its folder); a tracker file (QTM, VSK, Atracsys, ROM, Motive, CSV) whose bodies of 3 to "
    "16 markers print as tools; or a placement.json for tracker formats.",
)
_OUT = typer.Option(
    None,
    "--out",
    help="Output folder (default: <FILE's folder>/bodies with a CAD format, else <FILE's folder>/tracker).",
)


FORMATS = typer.Option(
    "step,stl,3mf",
    "--format",
    help="Comma list: step, stl, 3mf (CAD, family files) and qtm, vsk, atracsys, rom (NDI), motive (OptiTrack), csv.",
)
BED = typer.Option("200x200", "--bed", help="Print bed WIDTHxDEPTH in mm for the plate.")
GAP = typer.Option(5.0, "--gap", help="Gap between bodies on the plate, mm.")
NO_PLATE = typer.Option(False, "--no-plate", help="Skip plate.stl / plate.3mf.")
PREVIEW = typer.Option(False, "--preview", help="Also write preview/<star>.png and preview/sheet.png.")
ALLOW_OVERSIZE = typer.Option(
    False,
    "--allow-oversize",
    help="Export bodies that exceed the family's size limit (recorded in bodies.json).",
)
ID_START = typer.Option(
    1,
    "--id-start",
    help="First Atracsys geometry id (ids run on from it; give each family its own range).",
)
NOISE = typer.Option(
    0.2,
    "--noise",
    help="Marker noise, sigma per axis, mm, that the tracker files' tolerances assume (QTM, NDI).",
)
FORCE = typer.Option(False, "--force", help="Overwrite existing outputs.")
QUIET = typer.Option(
    False, "--quiet", "-q", help="Print nothing but errors (warnings are in bodies.json and trackers.json)."
)


@app.command("export")
def export_cmd(
    file: Path = _FILE,
    formats: str = FORMATS,
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
    bed: str = BED,
    gap: float = GAP,
    no_plate: bool = NO_PLATE,
    preview: bool = PREVIEW,
    allow_oversize: bool = ALLOW_OVERSIZE,
    id_start: int = ID_START,
    noise: float = NOISE,
    out: Path = _OUT,
    force: bool = FORCE,
    quiet: bool = QUIET,
) -> None:
    """Write printable star bodies (one file per star per format, plus a print plate) and/or
    tracker rigid-body files, all or nothing."""
    from starforge import api

    run = api.run_export(
        file, formats, out=out, mount=mount, ids=ids, sets=sets, bed=bed, gap_mm=gap, plate=not no_plate,
        preview=preview, allow_oversize=allow_oversize, id_start=id_start, noise_mm=noise, force=force,
        seat=seat, marker=marker, nozzle_mm=nozzle_mm, coating_mm=coating_mm, stem_mm=stem_mm,
        min_stem_mm=min_stem_mm, post_mm=post_mm, label=False if no_label else None,
    )  # fmt: skip
    if quiet:  # the warnings are in bodies.json / trackers.json
        return
    err = console(stderr=True)
    for w in run.tracker_warnings:
        err.print(f"warning: {w}", soft_wrap=True, markup=False)
    if run.tolerance_note:
        err.print(f"note: tracker file tolerances: {run.tolerance_note}", soft_wrap=True, markup=False)
    for w in run.warnings:
        err.print(f"warning: {w}")
    con = console()
    for line in api.describe_export(run):
        con.print(line)
