"""Capacity curves: the number of stars against the minimal length variation and the cube side.

``starforge sweep`` is :func:`plan_sweep` (every setting checked, nothing run), :func:`run_sweep`
(the cells, ``sweep.csv`` and ``sweep.png``) and :func:`describe_sweep` (its summary).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from starforge.errors import StarforgeError
from starforge.io import atomic_write_text, check_writable, staged_output
from starforge.words import counted

__all__ = ["SweepPlan", "SweepRun", "describe_sweep", "plan_sweep", "run_sweep"]

#: files :func:`run_sweep` writes
SWEEP_FILES = ("sweep.csv", "sweep.png")


@dataclass(frozen=True)
class SweepPlan:
    """A checked sweep (:func:`plan_sweep`).

    Attributes
    ----------
    marker_mm : float
        Marker sphere diameter, mm.
    deltas, cubes : tuple of float, mm
        Minimal length variations and cube sides.
    rules : tuple of str
        ``face``, ``pair`` or both.
    exhaustive : int or None
        Largest cell (labelled candidates) enumerated exhaustively; None: every cell whose
        enumeration fits one worker's memory.
    seed : int
    workers : int or None
        Local worker processes (None: every core).
    folder : Path
        The output folder.
    force : bool
    """

    marker_mm: float
    deltas: tuple[float, ...]
    cubes: tuple[float, ...]
    rules: tuple[str, ...]
    exhaustive: int | None
    seed: int
    workers: int | None
    folder: Path
    force: bool

    @property
    def cells(self) -> int:
        """Cells of the sweep (each run under every rule)."""
        return len(self.deltas) * len(self.cubes)


@dataclass(frozen=True)
class SweepRun:
    """What :func:`run_sweep` wrote: its plan and one row per cell and rule (``sweep.csv``)."""

    plan: SweepPlan
    rows: list[dict] = field(repr=False)


def plan_sweep(
    marker_mm: float = 4.0,
    delta: str = "0.5:3:0.5",
    cube: str = "10:50:5",
    rule: str = "face,pair",
    exhaustive: str | int = 20_000_000,
    *,
    seed: int = 0,
    workers: int = 0,
    out: str | Path = "out/sweep",
    force: bool = False,
) -> SweepPlan:
    """Check a sweep's settings and its output folder before any work.

    Parameters
    ----------
    delta, cube : str
        Ranges in mm, ``start:stop:step`` or ``a,b,c``.
    rule : str
        ``face``, ``pair`` or ``face,pair``.
    exhaustive : str or int
        A count of labelled candidates, or ``auto``.
    workers : int
        Local worker processes (0: every core; 1: in this process).

    Examples
    --------
    >>> p = plan_sweep(delta="1,2", cube="10:20:5", rule="face", out="/nonexistent/sweep")
    >>> p.deltas, p.cubes, p.cells
    ((1.0, 2.0), (10.0, 15.0, 20.0), 6)
    """
    from starforge.tracking.sweep import parse_range

    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if workers < 0:
        raise StarforgeError(f"workers must be >= 0, got {workers}")
    if str(exhaustive).strip().lower() == "auto":
        exhaustive_n = None
    else:
        try:
            exhaustive_n = int(str(exhaustive).replace("_", "").replace(",", ""))
        except ValueError:
            raise StarforgeError(f"exhaustive must be a count of labelled candidates or auto, got {exhaustive!r}") from None
    deltas = parse_range(delta, "delta")
    cubes = parse_range(cube, "cube")
    rules = [r.strip() for r in rule.split(",") if r.strip()]
    bad = [r for r in rules if r not in ("face", "pair")]
    if bad or not rules:
        raise StarforgeError(f"rule must be face, pair or face,pair, got {rule!r}")
    folder = Path(out)
    check_writable(folder, list(SWEEP_FILES), force)
    return SweepPlan(
        float(marker_mm), tuple(deltas), tuple(cubes), tuple(rules), exhaustive_n, seed, workers or None, folder, force
    )


def run_sweep(
    plan: SweepPlan,
    *,
    samples: int = 200_000,
    min_depth_mm: float | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_plan: Callable | None = None,
) -> SweepRun:
    """Run every cell of ``plan`` (:func:`starforge.tracking.sweep.sweep`) and write
    ``sweep.csv`` and ``sweep.png``.

    Parameters
    ----------
    samples : int
        Random candidates per interval cell (its verified family).
    min_depth_mm : float, optional
        Smallest star depth, mm (default: half the marker).
    progress : callable, optional
        ``progress(done, total)`` as cells finish.
    on_plan : callable, optional
        Told where the cells run (:func:`starforge.runtime.engine.map_tasks`'s ``on_plan``).
    """
    from starforge.render.tracking import sweep_plot
    from starforge.tracking.sweep import rows_csv, sweep

    rows = sweep(
        plan.marker_mm, list(plan.deltas), list(plan.cubes), plan.rules, plan.exhaustive, samples, plan.workers,
        plan.seed, min_depth_mm, progress=progress, scheduler=scheduler, on_plan=on_plan,
    )  # fmt: skip
    with staged_output(plan.folder, plan.force) as stage:
        atomic_write_text(stage / "sweep.csv", rows_csv(rows))
        sweep_plot(rows, stage / "sweep.png", plan.marker_mm)
    return SweepRun(plan, rows)


def describe_sweep(run: SweepRun) -> list[str]:
    """The lines that sum a sweep up: cells and how each was decided, the most stars found under
    each rule, and what was written."""
    p, rows = run.plan, run.rows
    ex = sum(r["method"] == "exhaustive" for r in rows)
    lb = sum(r["method"] == "interval" for r in rows)
    lines = [f"{counted(p.cells, 'cell')} x {counted(len(p.rules), 'rule')}: {ex} exhaustive, {counted(lb, 'certified interval')}"]
    for r in p.rules:
        best = max((x for x in rows if x["rule"] == r), key=lambda x: x["stars"])
        lines.append(
            f"  {r}: most stars found {best['stars']} (delta {best['delta_mm']:g} mm, cube {best['cube_mm']:g} mm, "
            f"{best['method']}, upper bound {best['upper_bound']})"
        )
    lines.append(f"wrote {p.folder}/: {', '.join(SWEEP_FILES)}")
    return lines
