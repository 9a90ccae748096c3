"""``starforge place-batch``: marker placement on many props, one prop under many rigs, or copies of
one prop, made into a fleet a tracker tells apart."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.api.place import distinct_tolerance_mm
from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._jobs import job_progress
from starforge.cli.place import NOISE, PRESET

CSV_HEADER = "job,prop,rig,markers,total_cost,tracked,self_margin_mm,closest,closest_margin_mm,wrong_rate_3_seen,placed_again"


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
    from starforge.errors import StarforgeError
    from starforge.io import atomic_write_bytes, atomic_write_text, check_writable, staged_output
    from starforge.props.batch import check_props, fleet, job_bytes, jobs, place_job
    from starforge.props.spec import load_spec
    from starforge.runtime import engine
    from starforge.tracking.fleet import fleet_report

    use_scheduler(scheduler)
    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if workers < 0:
        raise StarforgeError(f"workers must be >= 0, got {workers}")
    if not 1 <= copies <= 100:
        raise StarforgeError(f"--copies must be in [1, 100], got {copies}")
    if not 1 <= frames <= 1_000_000:
        raise StarforgeError(f"--frames must be in [1, 1000000], got {frames}")
    faces = None
    if avoid:  # the files to avoid exist and are readable before any work starts
        from starforge.tracking.avoid import faces_to_avoid
        from starforge.tracking.bodies import check_body_files

        check_body_files(avoid, "--avoid file")
        faces = faces_to_avoid(avoid)[0] / 1000.0  # mm -> m
    s = load_spec(spec)
    if copies > 1 and s.objective != "tracked":
        raise StarforgeError(
            f"--copies needs the tracked objective; --spec {spec} uses {s.objective!r} (try --spec default)"
        )
    distinct = distinct_tolerance_mm(s, preset, noise)
    todo = jobs(props, rig or [], units, spec, seed, copies, faces, distinct)
    out = Path(out)
    # a layout's folder may be there from an earlier run: its placement.json is what --force replaces
    check_writable(out, [f"{f}/placement.json" for names, _ in todo for f in names] + ["batch.csv"], force)
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
    rows, redone = fleet(todo, results, distinct, faces)
    reports = {
        r: fleet_report(
            [x[0] for x in rows if x[1][3] == r],
            [x[3] * 1000.0 for x in rows if x[1][3] == r],
            noise,
            preset,
            frames,
            seed,
        )
        for r in dict.fromkeys(x[1][3] for x in rows)
    }  # fmt: skip  (one fleet per rig: a room)
    lines = [CSV_HEADER] + [_csv_row(x, reports[x[1][3]], i in redone) for i, x in enumerate(rows)]
    with staged_output(out, force) as stage:
        for name, _, files, _ in rows:
            (stage / name).mkdir()  # staged: published beside (or over, with --force) what is there
            for fname, data in files.items():
                atomic_write_bytes(stage / name / fname, data)
        atomic_write_text(stage / "batch.csv", "\n".join(lines) + "\n")
    if quiet:
        return
    con = console()
    for line in lines[1:]:
        con.print(line)
    if redone:
        con.print(f"placed again to keep clear of the others: {', '.join(rows[i][0] for i in redone)}")
    for r, rep in reports.items():
        p = rep["closest_pair"]
        con.print(
            f"fleet{f' (rig {r})' if r else ''}: triangles kept {distinct:.2f} mm apart; closest pair {p['a']} / "
            f"{p['b']} {p['margin_mm']:.2f} mm; worst wrong body + wrong pose with 3 markers seen "
            f"{100 * rep['worst']['wrong_rate']:.3f} % ({rep['worst']['name']}, rule {rep['headline_rule']}, window "
            f"{rep['window_mm']:.2f} mm at {noise:g} mm noise, {frames} frames)"
        )
    con.print(f"wrote {out}/: {len(rows)} placement folders and batch.csv")


def _csv_row(row, report: dict, again: bool) -> str:
    """One layout's batch.csv line: its placement's cost and tracked fraction on fresh poses, from
    the fleet check its self-margin, closest other layout and wrong rate with 3 seen, and whether
    it was placed again to keep clear of the others."""
    import json

    name, job, files, _ = row
    doc = json.loads(files["placement.json"])
    cost, ev = doc.get("cost", {}), (doc.get("evaluation") or {}).get("default") or {}
    b = next(x for x in report["bodies"] if x["name"] == name)
    closest = "" if b["closest"] is None else f"{b['closest_margin_mm']:.4f}"
    return (
        f"{name},{job[0]},{job[3] or ''},{cost.get('markers', '')},{cost.get('total', '')},{ev.get('tracked', '')},"
        f"{b['self_margin_mm']:.4f},{b['closest'] or ''},{closest},{b['wrong_rate']:.6f},{int(again)}"
    )
