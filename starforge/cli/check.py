"""``starforge check``: how well a tracker tells the bodies of a family or placement apart."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from starforge.cli._app import app, console
from starforge.runtime import progress


def _tip(text: str | None):
    from starforge.errors import StarforgeError

    if text is None:
        return None
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise StarforgeError(f"tip must be three numbers x,y,z in mm, got {text!r}") from None
    if len(v) != 3:
        raise StarforgeError(f"tip must be three numbers x,y,z in mm, got {text!r}")
    if not all(math.isfinite(x) and abs(x) <= MAX_TIP_MM for x in v):
        raise StarforgeError(f"tip must be three finite numbers within {MAX_TIP_MM:,.0f} mm of the body, got {text!r}")
    return v


#: how far from the body's frame a --tip may be, mm (10 m: past any tool's tip)
MAX_TIP_MM = 10_000.0


_FILES = typer.Argument(
    ...,
    help="Star families, prop placements (or their folders) and a lab's tracker files (QTM .xml, Vicon .vsk, "
    "Atracsys .ini, NDI .rom, OptiTrack .motive, body .csv), in any mix.",
)


@app.command(
    "check",
    help="Simulate tracker frames for star families, prop placements and a lab's tracker files (noise, hidden "
    "markers, ghosts), "
    "identify the bodies the way trackers do, and write check.json (identification and mislabel rates, "
    "confusions, flips, TRE) and check.png (rates against noise).",
)
def check_cmd(
    files: list[str] = _FILES,
    noise: float = typer.Option(0.2, "--noise", help="Marker centre noise, sigma per axis, mm (>= 0)."),
    drop: int = typer.Option(
        1, "--drop", help="Up to this many markers hidden per body and frame (<= markers - 3)."
    ),
    ghosts: int = typer.Option(0, "--ghosts", help="Random extra points near each body per frame (<= 20)."),
    frames: int = typer.Option(10000, "--frames", help="Simulated frames."),
    world: str = typer.Option(
        "open",
        "--world",
        help="open: each point cluster identified on its own, as a tracker must when bodies come and go; "
        "closed: each label once per frame (assumes every body is in every frame).",
    ),
    presence: float = typer.Option(
        1.0,
        "--presence",
        help="Probability that a body is in a frame (0..1]; changes rates only in the closed world.",
    ),
    choose: str = typer.Option(
        None,
        "--choose",
            help="Simulate one rule only: fit (gate every distance by the window, then the best rigid fit), sides "
        "(then the smallest sorted-distance difference) or the stress model window (one match inside the "
        "window at random). Default: all on the same frames, headlined by the worst of fit and sides.",
    ),
    ambiguity: float = typer.Option(
        None,
        "--ambiguity",
        help="Report a match only when every rival explanation of its points fits this many times worse "
        "(default 2: a missed frame rather than a wrong body or pose; 1: always the best match).",
    ),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same result)."),
    preset: str = typer.Option(
        None,
        "--preset",
        help="Vendor rules and tracker windows: art, ndi, qualisys, optitrack (or a TOML file; default: none).",
    ),
    match: float = typer.Option(
        None,
        "--match",
        help="Distance matching window, mm (default: the preset's, else the family tolerance, else 2).",
    ),
    residual: float = typer.Option(None, "--residual", help="Rigid-fit RMS limit, mm (default: match / 2)."),
    tip: str = typer.Option(
        None,
        "--tip",
        help="Target point x,y,z in the body frame, mm, for the TRE (default: the family's tip).",
    ),
    exact_drop: bool = typer.Option(False, "--exact-drop", help="Hide exactly --drop markers (not 0..drop)."),
    curve: int = typer.Option(7, "--curve", help="Noise levels on the rates-vs-noise curve (0: none)."),
    out: str = typer.Option("out/check", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.errors import StarforgeError
    from starforge.io import atomic_write_json, check_writable, staged_output
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.check import CheckSettings, run_check

    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    settings = CheckSettings(
        noise_mm=noise,
        drop=drop,
        ghosts=ghosts,
        frames=frames,
        seed=seed,
        match_mm=match,
        residual_mm=residual,
        tip_mm=_tip(tip),
        preset=preset,
        drop_exact=exact_drop,
        curve_points=curve,
        world=world,
        presence=presence,
        choose=choose,
        ambiguity=ambiguity,
    )
    if preset is not None:
        from starforge.tracking.presets import load_preset

        load_preset(preset)  # unknown name: one line before any work
    bodyset = load_bodies(files)
    out = Path(out)
    names = ["check.json"] + (["check.png"] if curve > 0 else [])
    check_writable(out, names, force)
    doc = run_check(bodyset, settings, progress=progress.report({"simulate": "frames", "curve": "noise levels"}))
    with staged_output(out, force) as stage:
        atomic_write_json(stage / "check.json", doc)
        if curve > 0:
            from starforge.render.tracking import rates_plot

            with progress.stage("render", total=1, unit="pictures") as st:
                rates_plot(doc, stage / "check.png")
                st.update(1)
    if quiet:
        return
    err = console(stderr=True)
    for w in doc["input"]["warnings"]:
        err.print(f"warning: {w}", soft_wrap=True, markup=False)
    con = console()
    s = doc["settings"]
    con.print(
        f"{doc['input']['bodies']} bodies, {s['frames']} frames, {s['world']} world, presence {s['presence']:g}, "
        f"noise {s['noise_mm']} mm, drop {s['drop']} ({s['drop_mode']}), ghosts {s['ghosts']}, "
        f"match {s['match_mm']:.3g} mm ({s['window_source']}), residual {s['residual_mm']:.3g} mm, "
        f"identify from {s['identify_from_markers']} markers"
    )
    if doc["input"]["bodies_never_hiding_a_marker"]:
        few = doc["input"]["bodies_never_hiding_a_marker"]
        con.print(
            f"{len(few)} bodies keep all their markers in every frame (3 markers: no hidden-marker case): "
            f"{', '.join(few[:5])}{' ...' if len(few) > 5 else ''}"
        )
    for note in doc["input"]["notes"]:
        con.print(f"note: {note}")
    con.print(_headline(doc), soft_wrap=True)
    for rule, r in doc["by_rule"].items():
        kind = "stress model" if r["kind"] == "stress" else "rule"
        con.print(
            f"  {kind} {rule} ({r['means']}): identified {100 * r['identification_rate']:.3f} %, "
            f"wrong body {100 * r['wrong_body_rate']:.3f} %, wrong pose {100 * r['flip_rate']:.3f} %"
        )
    for w in doc["worst_pairs"][:5]:
        what = (
            f"labels swapped: wrong pose: {w['true']}"
            if w["kind"] == "flip"
            else f"wrong body: {w['true']} seen as {w['reported']}"
        )
        con.print(f"  {what}: {w['count']} ({100 * w['rate']:.3f} %)")
    fam = doc["accuracy"]["family"]
    at = doc["accuracy"]["tip_mm"]
    tip = ", ".join(f"{x:.3g}" for x in at) + " mm" if at is not None else "each body's tip"
    hidden = (
        f"one marker hidden: median {fam['tip_tre_hidden_mm_median']:.3f} mm, worst {fam['tip_tre_hidden_mm_worst']:.3f} mm"
        if fam["tip_tre_hidden_mm_median"] is not None
        else "no body has a hidden-marker case"
    )
    con.print(
        f"TRE at {tip}, {doc['accuracy']['tip_source']}: median {fam['tip_tre_mm_median']:.3f} mm, "
        f"worst {fam['tip_tre_mm_worst']:.3f} mm; {hidden}"
    )
    if "rules" in doc:
        v = doc["rules"]["violations"]
        con.print(f"{doc['rules']['vendor']}: {len(v)} rule violation{'s' if len(v) != 1 else ''}")
        for x in v[:10]:
            con.print(f"  {x['rule']}: {x['body']}: {x['message']}")
        if len(v) > 10:
            con.print(f"  ... {len(v) - 10} more in check.json")
    con.print(f"wrote {out}/: {', '.join(names)} ({doc['seconds']['total']:.1f} s)")


def _headline(doc: dict) -> str:
    """One line: the headline's rates, the rule they are under and what that rule does, and the
    rules under which no frame gave a wrong body or a wrong pose."""
    s = doc["settings"]
    head = doc["headline_rule"]
    rules = doc["headline_rules"]
    worst = f"the worse of {' and '.join(rules)}" if len(rules) > 1 else "the rule simulated"
    safe = doc["safe_under"]
    verdict = (
        f"no wrong body or pose under {', '.join(safe)}"
        if safe
        else "wrong bodies or poses under every headline rule"
    )
    w = doc.get("withheld_rate", 0.0)
    withheld = f" ({100 * w:.3f} % withheld: a rival explanation fit alike)" if w > 0 else ""
    return (
        f"identified {100 * doc['identification_rate']:.3f} %, wrong body {100 * doc['wrong_body_rate']:.3f} %, "
        f"wrong pose {100 * doc['flip_rate']:.3f} %, missed {100 * doc['missed_rate']:.3f} %{withheld} under rule {head}, "
        f"{worst}; {verdict}\n  rule {head}: {doc['headline_means']}; window {s['match_mm']:.3g} mm, "
        f"residual {s['residual_mm']:.3g} mm; a match is withheld when a rival fits within x{s['ambiguity_ratio']:g}"
    )
