"""``starforge check``: how well a tracker tells the bodies of a family or placement apart."""

from __future__ import annotations

import typer

from starforge.catalog import list_templates
from starforge.cli._app import app, console
from starforge.words import one_of

_FILES = typer.Argument(
    ...,
    help="Star families, prop placements (or their folders) and a lab's tracker files (QTM .xml, Vicon .vsk, "
    "Atracsys .ini, NDI .rom, OptiTrack .motive, body .csv), in any mix.",
)


NOISE = typer.Option(0.2, "--noise", help="Marker centre noise, sigma per axis, mm (>= 0).")
DROP = typer.Option(
    1, "--drop", help="Up to this many markers hidden per body and frame (<= markers - 3)."
)
GHOSTS = typer.Option(0, "--ghosts", help="Random extra points near each body per frame (<= 20).")
FRAMES = typer.Option(10000, "--frames", help="Simulated frames.")
WORLD = typer.Option(
    "open",
    "--world",
    help="open or closed. open: each point cluster identified on its own, as a tracker must when bodies come and go; "
    "closed: each label once per frame (assumes every body is in every frame).",
)
PRESENCE = typer.Option(
    1.0,
    "--presence",
    help="Probability that a body is in a frame (0..1]; changes rates only in the closed world.",
)
CHOOSE = typer.Option(
    None,
    "--choose",
    help="Simulate one rule only: fit (gate every distance by the window, then the best rigid fit), sides "
    "(then the smallest sorted-distance difference) or window (the stress model: one match inside the "
    "window at random). Default: all on the same frames, headlined by the worst of fit and sides.",
)
AMBIGUITY = typer.Option(
    None,
    "--ambiguity",
    help="Report a match only when it is this many times as likely as every rival explanation of its points "
    "under --noise (default 20: a missed frame rather than a wrong body or pose; 1: always the best match).",
)
SEED = typer.Option(0, "--seed", help="Random seed (same seed, same result).")
PRESET = typer.Option(
    None,
    "--preset",
    help=f"Vendor rules and tracker windows: {one_of(list_templates('presets'))} (or a TOML file; default: none).",
)
MATCH = typer.Option(
    None,
    "--match",
    help="Distance matching window, mm (default: a fixed-window preset's, else the bone-length tolerance "
    "starforge writes into vendor files for these bodies at --noise).",
)
RESIDUAL = typer.Option(
    None,
    "--residual",
    help="Rigid-fit RMS limit, mm (default: a fixed-window preset's, else the maximum residual starforge "
    "writes into vendor files for these bodies at --noise).",
)
TIP = typer.Option(
    None,
    "--tip",
    help="Target point x,y,z in the body frame, mm, for the TRE (default: the family's tip).",
)
EXACT_DROP = typer.Option(False, "--exact-drop", help="Hide exactly --drop markers (not 0..drop).")
CURVE = typer.Option(7, "--curve", help="Noise levels on the rates-vs-noise curve (0: none).")
OUT = typer.Option("out/check", "--out", help="Output folder.")
FORCE = typer.Option(False, "--force", help="Overwrite existing output files.")
QUIET = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")


@app.command(
    "check",
    help="Simulate tracker frames for star families, prop placements and a lab's tracker files (noise, hidden "
    "markers, ghosts), "
    "identify the bodies the way trackers do, and write check.json (identification and mislabel rates, "
    "confusions, flips, TRE) and check.png (rates against noise).",
)
def check_cmd(
    files: list[str] = _FILES,
    noise: float = NOISE,
    drop: int = DROP,
    ghosts: int = GHOSTS,
    frames: int = FRAMES,
    world: str = WORLD,
    presence: float = PRESENCE,
    choose: str = CHOOSE,
    ambiguity: float = AMBIGUITY,
    seed: int = SEED,
    preset: str = PRESET,
    match: float = MATCH,
    residual: float = RESIDUAL,
    tip: str = TIP,
    exact_drop: bool = EXACT_DROP,
    curve: int = CURVE,
    out: str = OUT,
    force: bool = FORCE,
    quiet: bool = QUIET,
) -> None:
    from starforge import api

    run = api.run_check(
        files, out, tip=tip, seed=seed, preset=preset, curve_points=curve, force=force, noise_mm=noise,
        drop=drop, ghosts=ghosts, frames=frames, match_mm=match, residual_mm=residual, drop_exact=exact_drop,
        world=world, presence=presence, choose=choose, ambiguity=ambiguity,
    )  # fmt: skip
    if quiet:
        return
    said = api.describe_check(run)
    err = console(stderr=True)
    for w in said.warnings:
        err.print(f"warning: {w}", soft_wrap=True, markup=False)
    con = console()
    for line in said.settings:
        con.print(line)
    con.print(said.headline, soft_wrap=True)
    for line in said.details:
        con.print(line)
