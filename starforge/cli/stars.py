"""``starforge stars``: generate a verified family of unique 4-marker stars."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import SCHEDULER_HELP, app, console, use_scheduler
from starforge.cli._args import retyped
from starforge.cli._multi import MULTI, more_values
from starforge.errors import StarforgeError
from starforge.runtime import progress
from starforge.stars.spec import STAR_CHOICES, STAR_DEFAULTS

_D, _C = STAR_DEFAULTS, STAR_CHOICES


def _default(key: str, unit: str = "mm") -> str:
    """``"default 1.5 mm"``: the value StarSpec uses when neither the option nor the spec sets it."""
    v = _D[key]
    return f"default {v:g} {unit}".rstrip() if isinstance(v, float) else f"default {v}"


@app.command("stars", context_settings=MULTI)
def stars_cmd(
    ctx: typer.Context,
    spec: str = typer.Option(
        None,
        "--spec",
        help="Template name (see `starforge templates stars`) or a TOML path; its values are the defaults of "
        "the options below (default: finger when --box is not given either).",
    ),
    box: tuple[float, float, float] = typer.Option(
        None,
        "--box",
        help="Size limit X Y Z in mm (the physical star), e.g. 20.8,12.6,48.3 (default: the spec's).",
    ),
    marker: str = typer.Option(
        None,
        "--marker",
        help="Marker diameter in mm, or a bought marker from the catalogue (`starforge templates markers`) "
        f"or a TOML file: its diameter, and with --mount its seat's room ({_default('marker_mm')}).",
    ),
    delta: float = typer.Option(
        None, "--delta", help=f"Minimal length variation (pool step), mm ({_default('delta_mm')})."
    ),
    gap: float = typer.Option(
        None, "--gap", help=f"Minimum clear gap between spheres, mm ({_default('gap_mm')})."
    ),
    rule: str = typer.Option(
        None, "--rule", help=f"{' or '.join(_C['rule'])} (the paper's: pair; {_default('rule')})."
    ),
    select: str = typer.Option(
        None, "--select", help=f"{' or '.join(_C['select'])} (the paper's: greedy; {_default('select')})."
    ),
    count: int = typer.Option(
        None,
        "--count",
        help="Exactly N stars: the most accurate distinguishable ones (default: as many as fit).",
    ),
    tolerance: float = typer.Option(None, "--tolerance", help="Face/edge tolerance, mm (default: delta)."),
    box_method: str = typer.Option(
        None,
        "--box-method",
        help=f"{' or '.join(_C['box_method'])}: exact: some rotation fits, decided to 0.01 mm; covariance: the "
        f"paper's OBB ({_default('box_method')}).",
    ),
    min_depth: float = typer.Option(
        None,
        "--min-depth",
        help="Smallest star depth (width of the centres), mm (default: half the marker; 0: flat stars allowed).",
    ),
    tip: tuple[float, float, float] = typer.Option(
        None,
        "--tip",
        help="Tip X Y Z in the placement frame, mm, for the predicted accuracy (default 0 0 -longest side).",
    ),
    noise: float = typer.Option(
        None,
        "--noise",
        help=f"Marker noise sigma per axis, mm ({_default('noise_mm')}): the predicted accuracy, and with it (or --preset) "
        "the face tolerance, twice the tracker's window at this noise (unless --tolerance).",
    ),
    avoid: list[Path] = typer.Option(
        None,
        "--avoid",
        help="Bodies the lab already owns (family.json, placement.json, QTM .xml, .vsk, Atracsys .ini, NDI .rom, .motive, "
        ".csv), one or several after one flag (--avoid A.xml B.vsk) or the flag repeated: no new face comes "
        "within the tolerance of theirs (default: none).",
    ),
    work: int = typer.Option(
        None,
        "--work",
        help=f"Work budget of the exact selection, nonzeros x solver nodes ({_default('work')}): deterministic, so the "
        "family and its proven bound are the same at any load; raise it to prove a larger spec optimal.",
    ),
    reserve: tuple[float, float, float] = typer.Option(
        None,
        "--reserve",
        help="mm kept free for a mount on the shortest, middle, longest side, by hand (default: what --mount "
        "needs, else 0,0,0; `starforge mounts` lists each mount's).",
    ),
    preset: str = typer.Option(
        None,
        "--preset",
        help="Design for a tracker (art, ndi, qualisys, optitrack, vicon, atracsys, or a TOML file): its rules, "
        "and faces apart by twice its window at --noise (`starforge templates presets`; default: none).",
    ),
    mount: str = typer.Option(
        None,
        "--mount",
        help="Design for this mount (see `starforge mounts`): reserve its room, check every body (default: none).",
    ),
    seat: str = typer.Option(
        None,
        "--seat",
        help="With --mount: how each marker sits on the end of its stem (the marker's seat, not the body's "
        "mount): sphere (printed), glue, post, screw (the marker's stud in a tap-drill bore) or insert (in a "
        "heat-set insert); its room is reserved (default: the catalogue marker's attachment, else sphere).",
    ),
    name: str = typer.Option(None, "--name", help="Family name (default: the spec's name)."),
    out: Path = typer.Option(None, "--out", help="Output folder (default: out/<name>)."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
    preview: bool = typer.Option(False, "--preview", help="Also draw family.png (the first 40 stars)."),
    scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
) -> None:
    """Generate a family of unique marker stars; writes family.json (source of truth) and family.csv.

    With no options it runs the paper's finger case (template `finger`).
    """
    import time

    from starforge import api
    from starforge.io import check_writable
    from starforge.runtime.process import allow_quick_exit, pause_gc
    from starforge.stars import warmup

    use_scheduler(scheduler)
    if avoid or ctx.args:  # the files to avoid exist and are readable before any work starts
        from starforge.tracking.bodies import check_body_files

        check_body_files(more_values("--avoid", avoid, ctx.args), "--avoid file")
    # every file goes through staged_output, and the helper and threads are done on return
    allow_quick_exit()
    pause_gc()  # its objects are nearly all acyclic: no collector passes over numba's and scipy's heap
    t0 = time.perf_counter()
    if seat is not None and mount is None and spec is None:
        raise StarforgeError(
            "--seat shapes the printed body, so it needs --mount (see `starforge mounts`), e.g. "
            + retyped(ctx.meta, {"--mount": "flat"})
        )
    given = dict(
        box_mm=box, marker=marker, mount=mount, seat=seat, preset=preset, reserve_mm=reserve,
        delta_mm=delta, gap_mm=gap, rule=rule, select=select, count=count, tolerance_mm=tolerance,
        box_method=box_method, min_depth_mm=min_depth, tip_mm=list(tip) if tip is not None else None,
        noise_mm=noise, work=work, name=name,
    )  # fmt: skip
    plan = _plan(spec, given, ctx)
    out_dir = out if out is not None else Path("out") / plan.spec.name
    check_writable(out_dir, [*api.FAMILY_FILES, *(["family.png"] if preview else [])], force)  # before the work
    avoid = more_values("--avoid", avoid, ctx.args)
    _check_memory(plan.spec, spec, given, ctx)  # a spec too large is refused before anything compiles
    helper = warmup.start()  # a first run compiles on two cores (nothing on a warm cache)
    try:
        if helper is not None:
            with progress.stage("compile"):
                warmup.compile_fit_decision()
                warmup.ready("enumerate")  # the helper's kernels: loaded, not compiled a second time
        enumerate_ = progress.stage("enumerate", unit="candidates")
        try:
            family = api.make_family(
                plan,
                avoid=avoid or (),
                progress=lambda done, total: enumerate_.update(done, total),
                on_stage=warmup.ready,  # a first run's helper may still be compiling the selection
                warn=None if quiet else _warn,
            )
        except StarforgeError as exc:  # the time estimate, no star, a count not achievable
            raise StarforgeError(as_options(str(exc))) from None
    except BaseException:
        warmup.finish(helper, 0.0)  # an error or Ctrl-C does not wait for the helper
        raise
    warmup.finish(helper)
    api.write_family(family, out_dir, preview=preview, force=True)
    _report(family, out_dir, time.perf_counter() - t0, quiet)


def _warn(text: str) -> None:
    console(stderr=True).print(f"warning: {text}", soft_wrap=True, markup=False)


#: the option that sets each StarSpec field, for messages
_OPTION_OF = {
    "box_mm": "--box",
    "marker_mm": "--marker",
    "delta_mm": "--delta",
    "gap_mm": "--gap",
    "tolerance_mm": "--tolerance",
    "min_depth_mm": "--min-depth",
    "tip_mm": "--tip",
    "noise_mm": "--noise",
    "work": "--work",
    "reserve_mm": "--reserve",
}


def as_options(message: str) -> str:
    """A library message with each StarSpec field named by its option: ``delta_mm`` -> ``--delta``,
    ``box_mm[0]`` -> ``--box's value 1``."""
    import re

    def one(m) -> str:
        flag = _OPTION_OF[m.group(1)]
        return f"{flag}'s value {int(m.group(2)) + 1}" if m.group(2) is not None else flag

    return re.sub(r"\b(" + "|".join(_OPTION_OF) + r")\b(?:\[(\d)\])?", one, message)


def _plan(spec, given: dict, ctx):
    """The family's plan (:func:`starforge.api.plan_family`); a refusal names the options, and when
    a larger --box makes the spec valid, the user's command with that box."""
    from starforge import api
    from starforge.catalog import load_template

    try:
        return api.plan_family(spec, **given)
    except StarforgeError as exc:
        message = as_options(str(exc))
        box = given.get("box_mm") or load_template("stars", spec or "finger")[1].get("box_mm")
        for k in range(1, 17) if box is not None else ():
            bigger = [round(float(x) * 1.25**k, 1) for x in box]
            try:
                api.plan_family(spec, **{**given, "box_mm": bigger})
            except StarforgeError:
                continue
            message += f"; a larger --box fits: e.g. {retyped(ctx.meta, {'--box': [f'{x:g}' for x in bigger]})}"
            break
        raise StarforgeError(message) from None


def _check_memory(s, spec, given: dict, ctx) -> None:
    """Refuse a spec whose enumeration would not fit in memory, naming the options and, when a
    coarser --delta fits, the user's command with it."""
    from starforge import api
    from starforge.stars.enumerate import check_memory

    try:
        check_memory(s, allow_stream=True)
        return
    except StarforgeError as exc:
        message = as_options(str(exc))
    for k in range(1, 12):
        delta = float(f"{s.delta_mm * 1.5**k:.2g}")
        try:
            check_memory(api.plan_family(spec, **{**given, "delta_mm": delta}).spec, allow_stream=True)
        except StarforgeError:
            continue
        message += f"; e.g. {retyped(ctx.meta, {'--delta': f'{delta:g}'})}"
        break
    raise StarforgeError(message)


def _report(family, out_dir: Path, seconds: float, quiet: bool) -> None:
    if quiet:
        return
    c = console()
    sm = family.summary
    _star_table(family, c)
    ub = sm.get("upper_bound")
    if family.spec.count is not None:
        bound = f" (any family of this spec has at most {ub})" if ub is not None else ""
    elif sm.get("optimal"):
        bound = f", optimal: proven upper bound {ub}"
    else:
        bound = f", certified upper bound {ub} (gap {sm['gap']})" if ub is not None else ""
    en = sm["enumeration"]
    und = f", {en['undecided']:,} undecided (fit within 0.01 mm, if at all)" if en.get("undecided") else ""
    c.print(
        f"{len(family)} stars, rule {family.spec.rule}, select {sm['select']}{bound}; "
        f"{en['labelled']:,} labelled candidates: {en['realisable']:,} realisable, {en['deep_enough']:,} at least "
        f"{sm['min_depth_mm']:g} mm deep, {en['kyfan_ok']:,} pass the necessary fit tests, {sm['candidates']:,} fit{und}; "
        f"enumerate {family.timings['enumerate']:.2f} s, select {family.timings['select']:.2f} s, "
        f"total {seconds:.2f} s; verified independently"
    )
    c.print(f"wrote {out_dir / 'family.json'}, family.csv and run.json (timings)")


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
        title=f"{family.spec.name}: {len(family)} stars, most accurate first (mm)",
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
