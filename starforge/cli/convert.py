"""``starforge convert``: a lab's rigid-body files from one tracker format into another."""

from __future__ import annotations

import typer

from starforge.cli._app import FAMILY_MOUNT, app
from starforge.words import counted

_FILES = typer.Argument(
    ...,
    help="Tracker files (QTM .xml, Vicon .vsk, Atracsys .ini, NDI .rom, OptiTrack .motive, body .csv), "
    "folders of them, a family.json or a placement.json, in any mix.",
)


@app.command(
    "convert",
    help="Convert rigid bodies to another tracker format (one file per body), keeping names, marker order, "
    "marker names, ids and tolerances where the target holds them, and saying in one line what it cannot "
    "hold.  --format family writes a family.json of 4-marker bodies that `starforge export` prints.",
)
def convert_cmd(
    files: list[str] = _FILES,
    fmt: str = typer.Option(
        ..., "--format", help="Target: qtm, vsk, atracsys, rom (NDI), motive (OptiTrack), csv, or family."
    ),
    out: str = typer.Option(..., "--out", help="Output folder."),
    noise: float = typer.Option(
        0.2, "--noise", help="Marker noise, mm per axis, for tolerances the sources do not state (> 0)."
    ),
    id_start: int = typer.Option(1, "--id-start", help="First numeric id for bodies the sources give none."),
    mount: str = FAMILY_MOUNT,
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.io import check_writable, staged_output
    from starforge.tracking.convert import convert_to, read_records

    source = read_records(files)
    reserve = None
    if mount and fmt.strip().lower() == "family":  # the CAD kernel's modules load only for a family
        from starforge.cad.reserve import mount_reserve_mm

        reserve = lambda marker: mount_reserve_mm(mount, marker)  # noqa: E731
    result = convert_to(source, fmt, noise_mm=noise, id_start=id_start, mount=mount, reserve_for=reserve)
    check_writable(out, result.files, force)
    with staged_output(out, force) as stage:
        for rel, data in result.files.items():
            (stage / rel).write_bytes(data)
    if quiet:
        return
    typer.echo(
        f"{counted(len(source.records), 'body')} from {counted(len(source.sources), 'file')} -> "
        f"{counted(len(result.files), result.format + ' file')} in {out}"
    )
    for line in (*source.warnings, result.lost_line()):
        if line:
            typer.echo(line)
