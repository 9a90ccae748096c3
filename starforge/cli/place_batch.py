"""``starforge place-batch``: marker placement on many props, one prop under many rigs, or copies of
one prop, made into a fleet a tracker tells apart."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge import api
from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._jobs import job_progress
from starforge.cli.place import NOISE, PRESET, STANDOFF


@app.command(
    "place-batch",
    help="Optimize marker placement for every PROP under every --rig (each one `starforge place` run, "
    "without pictures), in parallel on the engine: in process for a single job, else a local dask "
    "cluster, or the one at --scheduler; then every layout that a tracker seeing 3 markers could mistake "
    "for another is placed again avoiding the others.  --copies N puts N such layouts on each prop.  "
    "Writes OUT/<prop>/ per layout (its name followed by -<rig> and -<copy> where given) and OUT/batch.csv "
    "(each layout's closest other layout "
    "and its wrong body + wrong pose rate with exactly 3 markers seen).",
)
def place_batch_cmd(
    props: list[str] = typer.Argument(..., help="Mesh files or built-in prop names."),
    rig: list[str] = typer.Option(None, "--rig", help="Rig template name or TOML file; repeat for several."),
    spec: str = typer.Option("default", "--spec", help="Settings template name or TOML file."),
    copies: int = typer.Option(
        1, "--copies", help="Distinct layouts per prop (drones of one airframe, tools a lab owns several of)."
    ),
    avoid: list[Path] = typer.Option(
        None,
        "--avoid",
        help="Placements, star families or tracker files of bodies already in the room (repeat the flag for "
        "several): no layout comes within the tolerance of theirs (default: none).",
    ),
    standoff: float = STANDOFF,
    preset: str = PRESET,
    noise: float = NOISE,
    frames: int = typer.Option(
        2000, "--frames", help="Simulated frames of the fleet check (exactly 3 markers of every layout seen)."
    ),
    units: str = typer.Option("m", "--units", help="Units of the mesh files: m, cm or mm."),
    seed: int = typer.Option(0, "--seed", help="Random seed of every job (same seed, same result)."),
    workers: int = typer.Option(
        0, "--workers", help="Local worker processes (0: every core; 1: in this process)."
    ),
    scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
    out: str = typer.Option("out/place-batch", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    use_scheduler(scheduler)
    plan = api.plan_place_batch(
        props, rigs=rig or (), spec=spec, copies=copies, avoid=avoid or (), preset=preset, noise_mm=noise,
        frames=frames, units=units, seed=seed, workers=workers, out=out, force=force, standoff_mm=standoff,
    )  # fmt: skip
    with job_progress("place-batch", "placements", len(plan.jobs), quiet) as (tick, where):
        run = api.run_place_batch(plan, scheduler=scheduler, progress=tick, on_plan=where)
    if quiet:
        return
    con = console()
    for line in api.describe_place_batch(run):
        con.print(line)
    con.print(f"wrote {plan.folder}/: {len(run.rows)} placement folders and batch.csv")
