"""Markers on many props, on one prop under many rigs, or on copies of one prop: a fleet a tracker
tells apart (``starforge place-batch``).

:func:`plan_place_batch` checks every input and names every job before any work;
:func:`run_place_batch` places them on the engine, makes the fleet distinct, checks it and
writes the folders and ``batch.csv``; :func:`describe_place_batch` says what it made.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.api.place import NOISE_MM, distinct_tolerance_mm, distinct_tolerances_mm
from starforge.errors import StarforgeError
from starforge.io import atomic_write_bytes, atomic_write_text, check_writable, staged_output

__all__ = [
    "BATCH_CSV_HEADER",
    "PlaceBatchPlan",
    "PlaceBatchRun",
    "describe_place_batch",
    "plan_place_batch",
    "run_place_batch",
]

#: the columns of ``batch.csv``
BATCH_CSV_HEADER = (
    "job,prop,rig,markers,total_cost,tracked,self_margin_mm,closest,closest_margin_mm,wrong_rate_3_seen,placed_again"
)


@dataclass(frozen=True)
class PlaceBatchPlan:
    """The jobs of a batch, every input checked (:func:`plan_place_batch`).

    Attributes
    ----------
    jobs : tuple
        ``(folder names, job)`` per prop x rig in the order given
        (:func:`starforge.props.batch.jobs`; one folder per copy).
    task_bytes : tuple of float
        Each job's estimated peak memory, bytes.
    avoid_m : (k, 3) float, m, or None
        Sorted side lengths of the marker triangles of the bodies already in the room.
    distinct_mm : float
        How far every marker triangle keeps from every other layout's, mm (layouts of the spec's
        target count).
    tolerances_mm : tuple of float
        The tolerance for each marker count (:func:`starforge.api.place.distinct_tolerances_mm`),
        mm: a layout grown past the target, and the room it is in, keep the entry of its count.
    noise_mm, preset, frames : float, str or None, int
        The fleet check's marker noise (sigma per axis, mm), tracker and simulated frames.
    seed, workers : int
        The seed of every job; local worker processes (0: every core).
    folder : Path
        The output folder.
    force : bool
        Replace existing placements there.
    """

    jobs: tuple
    task_bytes: tuple[float, ...]
    avoid_m: np.ndarray | None = field(repr=False)
    distinct_mm: float
    tolerances_mm: tuple[float, ...]
    noise_mm: float
    preset: str | None
    frames: int
    seed: int
    workers: int
    folder: Path
    force: bool


def plan_place_batch(
    props: Sequence[str],
    *,
    rigs: Sequence[str] = (),
    spec: str = "default",
    copies: int = 1,
    avoid: Sequence[str | Path] = (),
    preset: str | None = None,
    noise_mm: float = NOISE_MM,
    frames: int = 2000,
    units: str = "m",
    seed: int = 0,
    workers: int = 0,
    out: str | Path = "out/place-batch",
    force: bool = False,
    standoff_mm: float | None = None,
) -> PlaceBatchPlan:
    """Check every input of a batch and name its jobs, before any work: the options' ranges, the
    files to avoid, the spec and rigs (with each job's memory estimate), every prop, and that the
    output folder takes the placements (``force`` replaces them).  ``standoff_mm``: every marker
    of every layout on a printed post this long (the spec's ``standoff_mm`` when None).

    Examples
    --------
    >>> import tempfile
    >>> plan = plan_place_batch(["hammer", "box"], copies=2, out=Path(tempfile.mkdtemp()) / "batch")
    >>> [names for names, _ in plan.jobs]
    [['hammer-01', 'hammer-02'], ['box-01', 'box-02']]
    """
    from starforge.props.batch import check_props, job_bytes, jobs
    from starforge.props.spec import load_spec, with_overrides

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

        check_body_files([Path(a) for a in avoid], "--avoid file")
        faces = faces_to_avoid([Path(a) for a in avoid])[0] / 1000.0  # mm -> m
    s = load_spec(spec)
    if standoff_mm is not None:
        s = with_overrides(s, standoff_mm=standoff_mm)
    s.marker_seat()  # a post too short for its marker is refused here, not on a worker
    if copies > 1 and s.objective != "tracked":
        raise StarforgeError(
            f"--copies needs the tracked objective; --spec {spec} uses {s.objective!r} (try --spec default)"
        )
    distinct = distinct_tolerance_mm(s, preset, noise_mm)
    table = distinct_tolerances_mm(s, preset, noise_mm)
    todo = jobs(props, list(rigs), units, s, seed, copies, faces, distinct, table)
    folder = Path(out)
    # a layout's folder may be there from an earlier run: its placement.json is what force replaces
    check_writable(folder, [f"{f}/placement.json" for names, _ in todo for f in names] + ["batch.csv"], force)
    # every input read before a cluster starts: the spec and rigs (the estimates), then the props
    est = tuple(job_bytes(s, job[3]) for _, job in todo)
    check_props(props, units)
    return PlaceBatchPlan(
        tuple(todo), est, faces, distinct, table, noise_mm, preset, frames, seed, workers, folder, force
    )


@dataclass(frozen=True)
class PlaceBatchRun:
    """What :func:`run_place_batch` placed and wrote.

    Attributes
    ----------
    plan : PlaceBatchPlan
        What was run.
    rows : tuple
        ``(folder name, job, files, centres m)`` per layout (:func:`starforge.props.batch.fleet`).
    redone : tuple of int
        The rows placed again to keep clear of the others.
    reports : dict
        Rig (None: the spec's) -> its fleet's check (:func:`starforge.tracking.fleet.fleet_report`).
    csv_lines : tuple of str
        ``batch.csv``, its header first.
    """

    plan: PlaceBatchPlan
    rows: tuple = field(repr=False)
    redone: tuple[int, ...]
    reports: dict = field(repr=False)
    csv_lines: tuple[str, ...]


def run_place_batch(
    plan: PlaceBatchPlan,
    *,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_plan: Callable | None = None,
) -> PlaceBatchRun:
    """Place every job of ``plan`` on the engine (in process for a single job, else a local dask
    cluster or the one at ``scheduler``), place again every layout a tracker seeing 3 markers
    could mistake for another, check each rig's fleet and write ``<folder>/<job>/`` and
    ``batch.csv`` at once.  ``progress(done, total)`` and ``on_plan(engine plan)`` are
    :func:`starforge.runtime.engine.map_tasks`'s."""
    from starforge.props.batch import fleet, place_job
    from starforge.runtime import engine
    from starforge.tracking.fleet import fleet_report

    todo = plan.jobs
    results = engine.map_tasks(
        place_job,
        [job for _, job in todo],
        task_bytes=list(plan.task_bytes),
        seconds=float("inf") if len(todo) > 1 else 0.0,  # each placement takes seconds
        workers=plan.workers or None,
        scheduler=scheduler,
        progress=progress,
        what=f"a batch of {len(todo)} placements",
        advice="lower the spec's sites, resolution or orientations, or use workers with more memory",
        on_plan=on_plan,
    )
    rows, redone = fleet(todo, results, plan.distinct_mm, plan.avoid_m, plan.tolerances_mm)
    reports = {
        r: fleet_report(
            [x[0] for x in rows if x[1][3] == r],
            [x[3] * 1000.0 for x in rows if x[1][3] == r],
            plan.noise_mm,
            plan.preset,
            plan.frames,
            plan.seed,
        )
        for r in dict.fromkeys(x[1][3] for x in rows)
    }  # fmt: skip  (one fleet per rig: a room)
    lines = [BATCH_CSV_HEADER] + [_csv_row(x, reports[x[1][3]], i in redone) for i, x in enumerate(rows)]
    with staged_output(plan.folder, plan.force) as stage:
        for name, _, files, _ in rows:
            (stage / name).mkdir()  # staged: published beside (or over, with force) what is there
            for fname, data in files.items():
                atomic_write_bytes(stage / name / fname, data)
        atomic_write_text(stage / "batch.csv", "\n".join(lines) + "\n")
    return PlaceBatchRun(plan, tuple(rows), tuple(redone), reports, tuple(lines))


def _csv_row(row, report: dict, again: bool) -> str:
    """One layout's batch.csv line: its placement's cost and tracked fraction on fresh poses, from
    the fleet check its self-margin, closest other layout and wrong rate with 3 seen, and whether
    it was placed again to keep clear of the others."""
    name, job, files, _ = row
    doc = json.loads(files["placement.json"])
    cost, ev = doc.get("cost", {}), (doc.get("evaluation") or {}).get("default") or {}
    b = next(x for x in report["bodies"] if x["name"] == name)
    closest = "" if b["closest"] is None else f"{b['closest_margin_mm']:.4f}"
    return (
        f"{name},{job[0]},{job[3] or ''},{cost.get('markers', '')},{cost.get('total', '')},{ev.get('tracked', '')},"
        f"{b['self_margin_mm']:.4f},{b['closest'] or ''},{closest},{b['wrong_rate']:.6f},{int(again)}"
    )


def describe_place_batch(run: PlaceBatchRun) -> list[str]:
    """The lines ``starforge place-batch`` prints: every ``batch.csv`` row, the layouts placed
    again, and each rig's fleet check."""
    from starforge.props.batch import room_tolerance_mm

    p = run.plan
    lines = list(run.csv_lines[1:])
    if run.redone:
        lines.append(f"placed again to keep clear of the others: {', '.join(run.rows[i][0] for i in run.redone)}")
    for r, rep in run.reports.items():
        pair = rep["closest_pair"]
        kept = room_tolerance_mm([len(x[3]) for x in run.rows if x[1][3] == r], p.distinct_mm, p.tolerances_mm)
        lines.append(
            f"fleet{f' (rig {r})' if r else ''}: triangles kept {kept:.2f} mm apart; closest pair {pair['a']} / "
            f"{pair['b']} {pair['margin_mm']:.2f} mm; worst wrong body + wrong pose with 3 markers seen "
            f"{100 * rep['worst']['wrong_rate']:.3f} % ({rep['worst']['name']}, rule {rep['headline_rule']}, window "
            f"{rep['window_mm']:.2f} mm at {p.noise_mm:g} mm noise, {p.frames} frames)"
        )
    return lines
