"""``starforge place-batch``: marker placement on many props, or one prop under many rigs."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._jobs import job_progress


@app.command(
    "place-batch",
    help="Optimize marker placement for every PROP under every --rig (each one `starforge place` run, "
    "without pictures), in parallel on the engine: in process for a single job, else a local dask "
    "cluster, or the one at --scheduler.  Writes OUT/<prop>[-<rig>]/ per job and OUT/batch.csv.",
)
def place_batch_cmd(
    props: list[str] = typer.Argument(..., help="Mesh files or built-in prop names."),
    rig: list[str] = typer.Option(None, "--rig", help="Rig template name or TOML file; repeat for several."),
    spec: str = typer.Option("default", "--spec", help="Settings template name or TOML file."),
    units: str = typer.Option("m", "--units", help="Units of the mesh files: m, cm or mm."),
    seed: int = typer.Option(0, "--seed", help="Random seed of every job (same seed, same result)."),
    workers: int = typer.Option(0, "--workers", help="Local worker processes (0: every core; 1: in this process)."),
    scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
    out: str = typer.Option("out/place-batch", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    import json

    from starforge.errors import StarforgeError
    from starforge.io import atomic_write_bytes, atomic_write_text, check_writable, staged_output
    from starforge.props.batch import check_props, job_bytes, jobs, place_job
    from starforge.runtime import engine

    use_scheduler(scheduler)
    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if workers < 0:
        raise StarforgeError(f"workers must be >= 0, got {workers}")
    todo = jobs(props, rig or [], units, spec, seed)
    out = Path(out)
    check_writable(out, [name for name, _ in todo] + ["batch.csv"], force)
    # every input read before a cluster starts: the spec and rigs (the estimates), then the props
    est = [job_bytes(spec, job[3]) for _, job in todo]
    check_props(props, units)
    with job_progress("place-batch", "placements", len(todo), quiet) as (tick, where):
        results = engine.map_tasks(
            place_job,
            [job for _, job in todo],
            task_bytes=est,
            seconds=float("inf") if len(todo) > 1 else 0.0,  # each placement takes seconds
            workers=workers or None,
            scheduler=scheduler,
            progress=tick,
            what=f"a batch of {len(todo)} placements",
            advice="lower the spec's sites, resolution or orientations, or use workers with more memory",
            on_plan=where,
        )
    lines = ["job,prop,rig,markers,total_cost"]
    with staged_output(out, force) as stage:
        for (name, job), files in zip(todo, results, strict=True):
            (stage / name).mkdir()
            for fname, data in files.items():
                atomic_write_bytes(stage / name / fname, data)
            doc = json.loads(files["placement.json"])
            cost = doc.get("cost", {})
            lines.append(f"{name},{job[0]},{job[3] or ''},{cost.get('markers', '')},{cost.get('total', '')}")
        atomic_write_text(stage / "batch.csv", "\n".join(lines) + "\n")
    if not quiet:
        con = console()
        for line in lines[1:]:
            con.print(line)
        con.print(f"wrote {out}/: {len(todo)} placement folders and batch.csv")
