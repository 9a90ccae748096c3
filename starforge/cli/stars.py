"""``starforge stars``: generate a verified family of unique 4-marker stars."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.catalog import list_templates
from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._args import retyped
from starforge.cli._multi import MULTI, more_values
from starforge.stars.spec import STAR_CHOICES, STAR_DEFAULTS
from starforge.words import counted, one_of

_D, _C = STAR_DEFAULTS, STAR_CHOICES


def _default(key: str, unit: str = "mm") -> str:
    """``"default 1.5 mm"``: the value StarSpec uses when neither the option nor the spec sets it."""
    v = _D[key]
    return f"default {v:g} {unit}".rstrip() if isinstance(v, float) else f"default {v}"


SPEC = typer.Option(
    None,
    "--spec",
    help="Template name (see `starforge templates stars`) or a TOML path; its values are the defaults of "
    "the options below (default: finger when --box is not given either).",
)
BOX = typer.Option(
    None,
    "--box",
    help="Size limit X Y Z in mm (the physical star), e.g. 20.8,12.6,48.3 (default: the spec's).",
)
MARKER = typer.Option(
    None,
    "--marker",
    help="Marker diameter in mm, or a bought marker from the catalogue (`starforge templates markers`) "
    f"or a TOML file: its diameter, and with --mount its seat's room ({_default('marker_mm')}).",
)
DELTA = typer.Option(
    None, "--delta", help=f"Minimal length variation (pool step), mm ({_default('delta_mm')})."
)
GAP = typer.Option(
    None, "--gap", help=f"Minimum clear gap between spheres, mm ({_default('gap_mm')})."
)
RULE = typer.Option(
    None, "--rule", help=f"{' or '.join(_C['rule'])} (the paper's: pair; {_default('rule')})."
)
SELECT = typer.Option(
    None, "--select", help=f"{' or '.join(_C['select'])} (the paper's: greedy; {_default('select')})."
)
COUNT = typer.Option(
    None,
    "--count",
    help="Exactly N stars: the most accurate distinguishable ones (default: as many as fit).",
)
TOLERANCE = typer.Option(None, "--tolerance", help="Face/edge tolerance, mm (default: delta).")
BOX_METHOD = typer.Option(
    None,
    "--box-method",
    help=f"{' or '.join(_C['box_method'])}: exact: some rotation fits, decided to 0.01 mm; covariance: the "
    f"paper's OBB ({_default('box_method')}).",
)
MIN_DEPTH = typer.Option(
    None,
    "--min-depth",
    help="Smallest star depth (width of the centres), mm (default: half the marker; 0: flat stars allowed).",
)
TIP = typer.Option(
    None,
    "--tip",
    help="Tip X Y Z in the placement frame, mm, for the predicted accuracy (default 0 0 -longest side).",
)
NOISE = typer.Option(
    None,
    "--noise",
    help=f"Marker noise sigma per axis, mm ({_default('noise_mm')}): the predicted accuracy, and with it (or --preset) "
    "the face tolerance, twice the tracker's window at this noise (unless --tolerance).",
)
AVOID = typer.Option(
    None,
    "--avoid",
    help="Bodies the lab already owns (family.json, placement.json, QTM .xml, .vsk, Atracsys .ini, NDI .rom, .motive, "
    ".csv), one or several after one flag (--avoid A.xml B.vsk) or the flag repeated: no new face comes "
    "within the tolerance of theirs (default: none).",
)
WORK = typer.Option(
    None,
    "--work",
    help=f"Work budget of the exact selection, nonzeros x solver nodes ({_default('work')}): deterministic, so the "
    "family and its proven bound are the same at any load; raise it to prove a larger spec optimal.",
)
RESERVE = typer.Option(
    None,
    "--reserve",
    help="mm kept free for a mount on the shortest, middle, longest side, by hand (default: what --mount "
    "needs, else 0,0,0; `starforge mounts` lists each mount's).",
)
PRESET = typer.Option(
    None,
    "--preset",
    help=f"Design for a tracker ({one_of(list_templates('presets'))}, or a TOML file): its rules, "
    "and faces apart by twice its window at --noise (`starforge templates presets`; default: none).",
)
MOUNT = typer.Option(
    None,
    "--mount",
    help="Design for this mount (see `starforge mounts`): reserve its room, check every body (default: none).",
)
SEAT = typer.Option(
    None,
    "--seat",
    help="With --mount: how each marker sits on the end of its stem (the marker's seat, not the body's "
    "mount): sphere (printed), glue, post, screw (the marker's stud in a tap-drill bore) or insert (in a "
    "heat-set insert); its room is reserved (default: the catalogue marker's attachment, else sphere).",
)
NAME = typer.Option(None, "--name", help="Family name (default: the spec's name).")
OUT = typer.Option(None, "--out", help="Output folder (default: out/<name>).")
FORCE = typer.Option(False, "--force", help="Overwrite existing outputs.")
QUIET = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")
PREVIEW = typer.Option(False, "--preview", help="Also draw family.png (the first 40 stars).")
SCHEDULER = typer.Option(None, "--scheduler", help=SCHEDULER_HELP)


@app.command("stars", context_settings=MULTI)
def stars_cmd(
    ctx: typer.Context,
    spec: str = SPEC,
    box: tuple[float, float, float] = BOX,
    marker: str = MARKER,
    delta: float = DELTA,
    gap: float = GAP,
    rule: str = RULE,
    select: str = SELECT,
    count: int = COUNT,
    tolerance: float = TOLERANCE,
    box_method: str = BOX_METHOD,
    min_depth: float = MIN_DEPTH,
    tip: tuple[float, float, float] = TIP,
    noise: float = NOISE,
    avoid: list[Path] = AVOID,
    work: int = WORK,
    reserve: tuple[float, float, float] = RESERVE,
    preset: str = PRESET,
    mount: str = MOUNT,
    seat: str = SEAT,
    name: str = NAME,
    out: Path = OUT,
    force: bool = FORCE,
    quiet: bool = QUIET,
    preview: bool = PREVIEW,
    scheduler: str = SCHEDULER,
) -> None:
    """Generate a family of unique marker stars; writes family.json (source of truth) and family.csv.

    With no options it runs the paper's finger case (template `finger`).
    """
    from starforge import api
    from starforge.runtime.process import allow_quick_exit, pause_gc

    use_scheduler(scheduler)
    avoid = more_values("--avoid", avoid, ctx.args) if avoid or ctx.args else []
    # every file goes through staged_output, and the helper and threads are done on return
    allow_quick_exit()
    pause_gc()  # its objects are nearly all acyclic: no collector passes over numba's and scipy's heap
    run = api.run_stars(
        spec, out=out, avoid=avoid, preview=preview, force=force, warn=None if quiet else _warn,
        retype=lambda changes: retyped(ctx.meta, changes), box_mm=box, marker=marker, mount=mount,
        seat=seat, preset=preset, reserve_mm=reserve, delta_mm=delta, gap_mm=gap, rule=rule, select=select,
        count=count, tolerance_mm=tolerance, box_method=box_method, min_depth_mm=min_depth,
        tip_mm=list(tip) if tip is not None else None, noise_mm=noise, work=work, name=name,
    )  # fmt: skip
    _report(run.family, run.folder, run.seconds, quiet)


def _warn(text: str) -> None:
    console(stderr=True).print(f"warning: {text}", soft_wrap=True, markup=False)


def _report(family, out_dir: Path, seconds: float, quiet: bool) -> None:
    from starforge.api import describe_family, tolerance_warning

    if quiet:
        return
    c = console()
    _star_table(family, c)
    c.print(describe_family(family, seconds))
    c.print(f"wrote {out_dir / 'family.json'}, family.csv and run.json (timings)")
    if text := tolerance_warning(family.spec):  # said once the family is written: a refusal stays one line
        _warn(text)


def _star_table(family, c) -> None:
    """The stars as a table (the first 25 of a large family), every cell whole."""
    from rich import box
    from rich.table import Table  # (0.01 s of imports a quiet run does without)

    heads = ("id", "u", "U", "v", "V", "w", "W", "box x y z", "depth", "face\nmargin", "tip TRE\n1 hidden")
    shown = family.stars if len(family) <= 30 else family.stars[:25]
    rows = []
    for st in shown:
        e = st.obb_extents
        rows.append((
            str(st.id),
            *[f"{x:.2f}" for x in st.lengths],
            f"{e[0]:.1f} {e[1]:.1f} {e[2]:.1f}",
            f"{st.depth_mm:.2f}" if st.depth_mm is not None else "",
            f"{st.margins['family_face_mm']:.2f}",
            f"{st.accuracy.get('tip_tre_hidden_mm', float('nan')):.2f}",
        ))  # fmt: skip
    if len(family) > len(shown):
        rows.append(("...", *[""] * 10))
    # no vertical rules, one space between columns; a cell is never cut: each column is as wide as
    # its longest cell (a terminal narrower than the table folds its lines)
    t = Table(
        title=f"{family.spec.name}: {counted(len(family), 'star')}, most accurate first (mm)",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        padding=(0, 0),
        collapse_padding=True,
        show_lines=False,
    )
    for k, col in enumerate(heads):
        widest = max([len(r[k]) for r in rows] + [max(len(x) for x in col.split("\n"))])
        t.add_column(col, justify="right", no_wrap=True, min_width=widest)
    for r in rows:
        t.add_row(*r)
    c.print(t, crop=False)
    if len(family) > len(shown):
        c.print(f"({len(family) - len(shown)} more stars in family.csv)")
