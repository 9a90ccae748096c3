"""``starforge preview``: pictures of the printable bodies, without writing the CAD files."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import app, console
from starforge.cli.export import (
    COATING,
    IDS,
    MARKER,
    MIN_STEM,
    MOUNT,
    NO_LABEL,
    NOZZLE,
    POST,
    SEAT,
    SETS,
    STEM,
)

_FILE = typer.Argument(..., help="family.json (or its folder).")
_OUT = typer.Option(
    None, "--out", help="Output folder (default: <FILE's folder>/bodies); PNGs go to preview/."
)


@app.command("preview")
def preview_cmd(
    file: Path = _FILE,
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
    allow_oversize: bool = typer.Option(
        False, "--allow-oversize", help="Draw bodies that exceed the size limit."
    ),
    out: Path = _OUT,
    force: bool = typer.Option(False, "--force", help="Overwrite existing pictures."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    """Draw each body (preview/star_<id>.png) and a sheet of all of them with their ids (preview/sheet.png)."""
    from starforge.api.bodies import default_out
    from starforge.cad.describe import describe_bodies
    from starforge.io import staged_output
    from starforge.render.bodies import draw_previews
    from starforge.stars.model import load_family

    src = file / "family.json" if file.is_dir() else file
    family = load_family(src)
    _, _, _, bodies = describe_bodies(
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
    out = out if out is not None else default_out(src, True)
    with staged_output(out, force) as stage:
        draw_previews(bodies, stage / "preview", family.spec.box_mm)
    if not quiet:
        console().print(f"wrote {len(bodies) + 1} pictures to {out}/preview/")
