"""``starforge sweep``: capacity curves (stars against minimal variation and cubic box size)."""

from __future__ import annotations

import typer

from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._jobs import job_progress

MARKER = typer.Option(4.0, "--marker", help="Marker sphere diameter, mm.")
DELTA = typer.Option("0.5:3:0.5", "--delta", help="Minimal variations, mm: start:stop:step or a,b,c.")
CUBE = typer.Option("10:50:5", "--cube", help="Cube sides, mm: start:stop:step or a,b,c.")
RULE = typer.Option("face,pair", "--rule", help="Rules: face, pair or face,pair.")
EXHAUSTIVE = typer.Option(
    "20000000",
    "--exhaustive",
    help="Largest cell (labelled candidates) enumerated exhaustively; larger: an interval.  "
    "auto: every cell whose enumeration fits one worker's memory.",
)
SAMPLES = typer.Option(200_000, "--samples", help="Random candidates per interval cell (its verified family).")
MIN_DEPTH = typer.Option(None, "--min-depth", help="Smallest star depth, mm (default: half the marker).")
WORKERS = typer.Option(
    0, "--workers", help="Local worker processes (0: every core; 1: in this process). Small sweeps run in process."
)
SCHEDULER = typer.Option(None, "--scheduler", help=SCHEDULER_HELP)
SEED = typer.Option(0, "--seed", help="Random seed for the sampled cells.")
OUT = typer.Option("out/sweep", "--out", help="Output folder.")
FORCE = typer.Option(False, "--force", help="Overwrite existing output files.")
QUIET = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")


@app.command(
    "sweep",
    help="Capacity curves (the family paper's Fig. 8): the number of stars against the minimal length "
    "variation and the cube side, for both rules; writes sweep.csv and sweep.png.  Small pools are "
    "enumerated exhaustively (maximum family and certified bound); large ones get a certified interval "
    "(a verified family and an upper bound; the CSV says which).",
)
def sweep_cmd(
    marker: float = MARKER,
    delta: str = DELTA,
    cube: str = CUBE,
    rule: str = RULE,
    exhaustive: str = EXHAUSTIVE,
    samples: int = SAMPLES,
    min_depth: float = MIN_DEPTH,
    workers: int = WORKERS,
    scheduler: str = SCHEDULER,
    seed: int = SEED,
    out: str = OUT,
    force: bool = FORCE,
    quiet: bool = QUIET,
) -> None:
    from starforge import api

    use_scheduler(scheduler)
    plan = api.plan_sweep(marker, delta, cube, rule, exhaustive, seed=seed, workers=workers, out=out, force=force)
    with job_progress("sweep", "cells", plan.cells, quiet) as (tick, where):
        run = api.run_sweep(
            plan, samples=samples, min_depth_mm=min_depth, scheduler=scheduler, progress=tick, on_plan=where
        )
    if quiet:
        return
    con = console()
    for line in api.describe_sweep(run):
        con.print(line)
