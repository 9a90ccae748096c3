"""``starforge drawing``: dimensioned drawings of a lab's rigid bodies, to rebuild a tool."""

from __future__ import annotations

import typer

from starforge.cli._app import app


@app.command(
    "drawing",
    help="Dimensioned drawings of rigid bodies from tracker files (QTM, VSK, Atracsys, NDI .rom, Motive, CSV), "
    "folders of them, a family.json or a placement.json: drawing.pdf (a page per body: three views with "
    "every pairwise distance, marker and distance tables), <body>.png per body and dimensions.csv, in mm.",
)
def drawing_cmd(
    files: list[str] = typer.Argument(..., help="Tracker files, folders, family.json or placement.json."),
    out: str = typer.Option(..., "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.io import check_writable, staged_output
    from starforge.render.drawing import write_drawings
    from starforge.tracking.convert import file_stems, read_records

    source = read_records(files)
    stems = file_stems([r.name for r in source.records])
    check_writable(out, ["drawing.pdf", "dimensions.csv", *(f"{s}.png" for s in stems)], force)
    with staged_output(out, force) as stage:
        bodies = [
            (s, r.points_mm, r.marker_names, src)
            for s, r, src in zip(stems, source.records, source.origins, strict=True)
        ]
        write_drawings(bodies, stage)
    if not quiet:
        typer.echo(f"drawings of {len(stems)} bodies -> {out}/drawing.pdf, {len(stems)} PNG, dimensions.csv")
