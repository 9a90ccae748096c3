"""``starforge stars``: generate a verified family of unique 4-marker stars."""

from __future__ import annotations

from pathlib import Path

import typer

from starforge.cli._app import app, console, progress
from starforge.cli._multi import MULTI, more_values


@app.command("stars", context_settings=MULTI)
def stars_cmd(
    ctx: typer.Context,
    spec: str = typer.Option(
        None, "--spec", help="Template name (see `starforge templates stars`) or a TOML path."
    ),
    box: tuple[float, float, float] = typer.Option(
        None, "--box", help="Size limit X Y Z in mm (physical star)."
    ),
    marker: str = typer.Option(
        None,
        "--marker",
        help="Marker diameter in mm, or a bought marker from the catalogue (`starforge templates markers`) "
        "or a TOML file: its diameter, and with --mount its seat's room.",
    ),
    delta: float = typer.Option(None, "--delta", help="Minimal length variation (pool step), mm."),
    gap: float = typer.Option(None, "--gap", help="Minimum clear gap between spheres, mm."),
    rule: str = typer.Option(None, "--rule", help="face (default) or pair (the paper's)."),
    select: str = typer.Option(None, "--select", help="max (default) or greedy (the paper's)."),
    count: int = typer.Option(
        None, "--count", help="Exactly N stars: the most accurate distinguishable ones."
    ),
    tolerance: float = typer.Option(None, "--tolerance", help="Face/edge tolerance, mm (default: delta)."),
    box_method: str = typer.Option(
        None,
        "--box-method",
        help="exact (default: some rotation fits, decided to 0.01 mm) or covariance (the paper's OBB).",
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
        help="Marker noise sigma per axis, mm (default 0.2): the predicted accuracy, and with it (or --preset) "
        "the face tolerance, twice the tracker's window at this noise (unless --tolerance).",
    ),
    avoid: list[Path] = typer.Option(
        None,
        "--avoid",
        help="Bodies the lab already owns (family.json, placement.json, QTM .xml, .vsk, Atracsys .ini, NDI .rom, .motive, "
        ".csv), one or several after one flag (--avoid A.xml B.vsk) or the flag repeated: no new face comes "
        "within the tolerance of theirs.",
    ),
    work: int = typer.Option(
        None,
        "--work",
        help="Work budget of the exact selection, nonzeros x solver nodes (default 8000000): deterministic, so the "
        "family and its proven bound are the same at any load; raise it to prove a larger spec optimal.",
    ),
    reserve: tuple[float, float, float] = typer.Option(
        None,
        "--reserve",
        help="mm kept free for a mount on the shortest, middle, longest side, by hand (--mount computes it; `starforge mounts` lists each mount's).",
    ),
    preset: str = typer.Option(
        None,
        "--preset",
        help="Design for a tracker (art, ndi, qualisys, optitrack, vicon, atracsys, or a TOML file): its rules, "
        "and faces apart by twice its window at --noise.",
    ),
    mount: str = typer.Option(
        None,
        "--mount",
        help="Design for this mount (see `starforge mounts`): reserve its room, check every body.",
    ),
    seat: str = typer.Option(
        None,
        "--seat",
        help="With --mount: what each stem ends in, sphere (printed), glue, post, screw or insert "
        "(default: the catalogue marker's attachment, else sphere); its room is reserved.",
    ),
    name: str = typer.Option(None, "--name", help="Family name (default: the spec's name)."),
    out: Path = typer.Option(None, "--out", help="Output folder (default: out/<name>)."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing outputs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No table, just the summary line."),
    preview: bool = typer.Option(False, "--preview", help="Also draw family.png (the first 40 stars)."),
) -> None:
    """Generate a family of unique marker stars; writes family.json (source of truth) and family.csv.

    With no options it runs the paper's finger case (template `finger`).
    """
    import json
    import time

    from starforge.cli._app import allow_quick_exit, pause_gc

    # every file goes through staged_output, and the helper and threads are done on return
    allow_quick_exit()
    pause_gc()  # its objects are nearly all acyclic: no collector passes over numba's and scipy's heap
    from starforge import __version__
    from starforge.catalog import load_template
    from starforge.io import check_name, check_writable, staged_output
    from starforge.stars.enumerate import check_memory, check_size
    from starforge.stars.family import make_family
    from starforge.stars.model import family_csv
    from starforge.stars.spec import spec_from_mapping
    from starforge.stars.verify import check_family

    t0 = time.perf_counter()
    data: dict = {}
    spec_name = None
    if spec is not None:
        spec_name, data = load_template("stars", spec)
    elif box is None:
        spec_name, data = load_template("stars", "finger")
    else:
        spec_name = "custom"
    from starforge.tracking.presets import star_spec_overrides

    if preset is not None:
        data.update(star_spec_overrides(preset))
    if (preset is not None or noise is not None) and tolerance is None:
        # designed for the tracker: faces apart by twice its window at this noise
        from starforge.tracking.presets import design_tolerance_mm

        nz = noise if noise is not None else float(data.get("noise_mm", 0.2))
        floor = star_spec_overrides(preset).get("tolerance_mm") if preset is not None else None
        data["tolerance_mm"] = round(design_tolerance_mm(preset, nz, floor), 6)
    marker_name = None
    if marker is not None:
        from starforge.catalog import marker_diameter_mm

        try:
            float(str(marker).strip().removesuffix("mm"))
        except ValueError:
            marker_name = str(marker).strip()
        marker = marker_diameter_mm(marker)
    overrides = {
        "box_mm": list(box) if box is not None else None,
        "marker_mm": marker,
        "marker": marker_name,
        "seat": seat,
        "delta_mm": delta,
        "gap_mm": gap,
        "rule": rule,
        "select": select,
        "count": count,
        "tolerance_mm": tolerance,
        "box_method": box_method,
        "min_depth_mm": min_depth,
        "tip_mm": list(tip) if tip is not None else None,
        "noise_mm": noise,
        "work": work,
        "reserve_mm": list(reserve) if reserve is not None else None,
        "mount": mount,
        "name": name,
    }
    data.update({k: v for k, v in overrides.items() if v is not None})
    data.setdefault("name", spec_name)
    star_filter = None
    if data.get("mount") is not None:
        from starforge.cad.body import body_spec_for
        from starforge.cad.mounts import load_mount
        from starforge.cad.reserve import bodies_fit, mount_reserve_mm

        m = load_mount(data["mount"])
        body = body_spec_for(data.get("marker"), data.get("seat"), float(data.get("marker_mm", 4.0)))
        if reserve is None:
            data["reserve_mm"] = list(mount_reserve_mm(m, float(data.get("marker_mm", 4.0)), body))

        def star_filter(V, _m=m, _d=data, _b=body):
            return bodies_fit(V, float(_d.get("marker_mm", 4.0)), _d["box_mm"], _m, _b)
    elif seat is not None:
        from starforge.errors import StarforgeError

        raise StarforgeError("--seat shapes the printed body: give --mount too (see `starforge mounts`)")

    s = spec_from_mapping(data)
    check_name(s.name, "--name")
    out_dir = out if out is not None else Path("out") / s.name
    names = ["family.json", "family.csv", "run.json"] + (["family.png"] if preview else [])
    check_writable(out_dir, names, force)  # fail before the long work
    from starforge.stars import warmup

    check_memory(s, allow_stream=True)  # a spec too large is refused before anything compiles
    helper = warmup.start()  # a first run compiles on two cores (nothing on a warm cache)
    try:
        if helper is not None:
            warmup.compile_fit_decision()
            warmup.ready("enumerate")  # the helper's kernels: loaded, not compiled a second time
        check_size(s, allow_stream=True)  # memory and time estimated before the long work
        family = _make(s, ctx, avoid, star_filter, make_family)
    except BaseException:
        warmup.finish(helper, 0.0)  # an error or Ctrl-C does not wait for the helper
        raise
    warmup.finish(helper)
    text = json.dumps(family.to_json(), indent=2) + "\n"  # what is written is what is checked
    problems = check_family(json.loads(text))
    if problems:  # the generator and the independent checker disagree: a bug, never a user error
        raise RuntimeError(f"internal error: the family failed its independent check: {problems[0]}")
    with staged_output(out_dir, force) as stage:
        (stage / "family.json").write_text(text, encoding="utf-8")
        (stage / "family.csv").write_text(family_csv(family), encoding="utf-8")
        run = {"seconds": family.timings, "verified": True, "starforge": __version__}
        (stage / "run.json").write_text(json.dumps(run, indent=2) + "\n", encoding="utf-8")
        if preview:
            from starforge.render.stars import family_sheet

            family_sheet(family, stage / "family.png")
    _report(family, out_dir, time.perf_counter() - t0, quiet)


def _make(s, ctx, avoid, star_filter, make_family):
    """The bodies to avoid, then the family, with a progress bar."""
    avoid = more_values("--avoid", avoid, ctx.args)
    avoid_faces, avoid_sources = None, None
    if avoid:
        from starforge.stars.avoid import faces_to_avoid

        avoid_faces, avoid_sources = faces_to_avoid(avoid)
        for src in avoid_sources:
            for w in src.get("warnings", ()):
                console(stderr=True).print(f"warning: {w}", soft_wrap=True, markup=False)

    with progress() as bar:
        task = bar.add_task("enumerating", total=None)

        def tick(done, total):
            bar.update(task, completed=done, total=total)

        return make_family(
            s, progress=tick, avoid_faces_mm=avoid_faces, avoid_sources=avoid_sources, star_filter=star_filter
        )


def _report(family, out_dir: Path, seconds: float, quiet: bool) -> None:
    c = console()
    sm = family.summary
    if not quiet:
        from rich import box
        from rich.table import Table  # (0.01 s of imports a quiet run does without)

        # fits 80 columns: no vertical rules, one space between columns, nothing wraps
        t = Table(
            title=f"{family.spec.name}: {len(family)} stars, most accurate first (mm)",
            box=box.SIMPLE_HEAD,
            pad_edge=False,
            padding=(0, 0),
            collapse_padding=True,
            show_lines=False,
        )
        for col in ("id", "u", "U", "v", "V", "w", "W", "box x y z", "depth", "face\nmargin", "tip TRE\n1 hidden"):
            t.add_column(col, justify="right", no_wrap=True)
        shown = family.stars if len(family) <= 30 else family.stars[:25]
        for st in shown:
            e = st.obb_extents
            t.add_row(
                str(st.id),
                *[f"{x:.2f}" for x in st.lengths],
                f"{e[0]:.1f} {e[1]:.1f} {e[2]:.1f}",
                f"{st.depth_mm:.2f}" if st.depth_mm is not None else "",
                f"{st.margins['family_face_mm']:.2f}",
                f"{st.accuracy.get('tip_tre_hidden_mm', float('nan')):.2f}",
            )
        if len(family) > len(shown):
            t.add_row("...", *[""] * 10)
        c.print(t)
        if len(family) > len(shown):
            c.print(f"({len(family) - len(shown)} more stars in family.csv)")
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
