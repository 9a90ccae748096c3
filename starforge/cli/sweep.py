"""``starforge sweep``: capacity curves (stars against minimal variation and cubic box size)."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._jobs import job_progress
from starforge.words import counted


@app.command(
    "sweep",
    help="Capacity curves (the family paper's Fig. 8): the number of stars against the minimal length "
    "variation and the cube side, for both rules; writes sweep.csv and sweep.png.  Small pools are "
    "enumerated exhaustively (maximum family and certified bound); large ones get a certified interval "
    "(a verified family and an upper bound; the CSV says which).",
)
def sweep_cmd(
    marker: float = typer.Option(4.0, "--marker", help="Marker sphere diameter, mm."),
    delta: str = typer.Option(
        "0.5:3:0.5", "--delta", help="Minimal variations, mm: start:stop:step or a,b,c."
    ),
    cube: str = typer.Option("10:50:5", "--cube", help="Cube sides, mm: start:stop:step or a,b,c."),
    rule: str = typer.Option("face,pair", "--rule", help="Rules: face, pair or face,pair."),
    exhaustive: str = typer.Option(
        "20000000",
        "--exhaustive",
        help="Largest cell (labelled candidates) enumerated exhaustively; larger: an interval.  "
        "auto: every cell whose enumeration fits one worker's memory.",
    ),
    samples: int = typer.Option(200_000, "--samples", help="Random candidates per interval cell (its verified family)."),
    min_depth: float = typer.Option(None, "--min-depth", help="Smallest star depth, mm (default: half the marker)."),
    workers: int = typer.Option(
        0, "--workers", help="Local worker processes (0: every core; 1: in this process). Small sweeps run in process."
    ),
    scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
    seed: int = typer.Option(0, "--seed", help="Random seed for the sampled cells."),
    out: str = typer.Option("out/sweep", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.errors import StarforgeError
    from starforge.io import atomic_write_text, check_writable, staged_output

    use_scheduler(scheduler)
    from starforge.tracking.sweep import parse_range, rows_csv, sweep

    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if workers < 0:
        raise StarforgeError(f"workers must be >= 0, got {workers}")
    if exhaustive.strip().lower() == "auto":
        exhaustive_n = None
    else:
        try:
            exhaustive_n = int(exhaustive.replace("_", "").replace(",", ""))
        except ValueError:
            raise StarforgeError(f"exhaustive must be a count of labelled candidates or auto, got {exhaustive!r}") from None
    deltas = parse_range(delta, "delta")
    cubes = parse_range(cube, "cube")
    rules = [r.strip() for r in rule.split(",") if r.strip()]
    bad = [r for r in rules if r not in ("face", "pair")]
    if bad or not rules:
        raise StarforgeError(f"rule must be face, pair or face,pair, got {rule!r}")
    out = Path(out)
    names = ["sweep.csv", "sweep.png"]
    check_writable(out, names, force)
    n = len(deltas) * len(cubes)
    with job_progress("sweep", "cells", n, quiet) as (tick, where):
        rows = sweep(
            marker,
            deltas,
            cubes,
            tuple(rules),
            exhaustive_n,
            samples,
            workers or None,
            seed,
            min_depth,
            progress=tick,
            scheduler=scheduler,
            on_plan=where,
        )
    with staged_output(out, force) as stage:
        atomic_write_text(stage / "sweep.csv", rows_csv(rows))
        from starforge.render.tracking import sweep_plot

        sweep_plot(rows, stage / "sweep.png", marker)
    if quiet:
        return
    con = console()
    ex = sum(r["method"] == "exhaustive" for r in rows)
    lb = sum(r["method"] == "interval" for r in rows)
    con.print(f"{counted(n, 'cell')} x {counted(len(rules), 'rule')}: {ex} exhaustive, {counted(lb, 'certified interval')}")
    for r in rules:
        best = max((x for x in rows if x["rule"] == r), key=lambda x: x["stars"])
        con.print(
            f"  {r}: most stars found {best['stars']} (delta {best['delta_mm']:g} mm, cube {best['cube_mm']:g} mm, "
            f"{best['method']}, upper bound {best['upper_bound']})"
        )
    con.print(f"wrote {out}/: {', '.join(names)}")
