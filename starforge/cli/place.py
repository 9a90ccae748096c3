"""``starforge place``: optimize a marker set on a prop (``place PROP``) or score one (``place score``).

``place`` is a default-command group: ``starforge place hammer`` runs the placement, while
``starforge place score PROP MARKERS.csv`` scores a given layout.  A prop file that happens to be
named ``score`` can be given as ``./score``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from typer.core import TyperGroup

from starforge import api
from starforge.api.place import NOISE_MM
from starforge.catalog import list_templates, load_template
from starforge.cli._app import app, console

_DEFAULT = "run"

#: the settings template ``--spec`` defaults to: the help states its values
_SPEC = "default"
_S = load_template("place", _SPEC)[1]
_T = _S.get("track", {})


def _of_spec(value) -> str:
    """``"default: the spec's; 600 in `default`"``."""
    return f"default: the spec's; {value} in `{_SPEC}`"


# options shared by `place` and `place score`
_RIG = typer.Option(None, "--rig", help=f"Rig template name or TOML file ({_of_spec(_S.get('rig'))}).")
_RESOLUTION = typer.Option(
    None, "--resolution", help=f"n for n x n x n prop positions in the capture volume ({_of_spec(_S['resolution'])})."
)
_ORIENTATIONS = typer.Option(
    None, "--orientations", help=f"Prop orientations per position ({_of_spec(_S['orientations'])})."
)


class _DefaultGroup(TyperGroup):
    """Dispatch to a subcommand when the first argument names one, else to the default command."""

    default_command = _DEFAULT

    def parse_args(self, ctx, args):
        from starforge.cli._multi import spread_flag

        if args and args[0] in ctx.help_option_names:  # the placement's options, and where score is
            args = [_DEFAULT, *args]
        if not args or args[0] not in self.commands:
            args = [_DEFAULT, *args]
        if args[0] == _DEFAULT:  # --avoid A B: every value up to the next option is a file to avoid
            args = [_DEFAULT, *spread_flag("--avoid", list(args[1:]))]
        return super().parse_args(ctx, args)


place_app = typer.Typer(
    cls=_DefaultGroup,
    no_args_is_help=False,
    add_completion=False,
    help="Optimize retroreflective marker placement on a prop: `starforge place PROP \\[OPTIONS]` "
    "(PROP: a mesh file or a built-in: hammer (the default), racket, sword, bottle, box, shield, "
    "umbrella), "
    "or score a layout: `starforge place score PROP MARKERS.csv`.",
)
app.add_typer(place_app, name="place")


PRESET = typer.Option(
    None,
    "--preset",
    help="Design for a tracker (`starforge templates presets`; default: starforge's own, which gates by the "
    "tolerance written into vendor files): every marker triangle keeps twice its window at --noise from the "
    "layout's other triangles, from itself relabelled, and from other bodies' (the larger of that and the "
    "spec's avoid_tolerance_mm).",
)
NOISE = typer.Option(NOISE_MM, "--noise", help="Marker noise sigma per axis, mm, the tracker's window is designed for.")


_PROP = typer.Argument(
    ...,
    help="Mesh file (STL, OBJ, PLY, GLB, OFF) or built-in prop name (builtin:NAME when a path has that name).",
)


PROP = typer.Argument(
    "hammer",
    help="Mesh file (STL, OBJ, PLY, GLB, OFF) or built-in prop name (default: hammer; builtin:NAME when a "
    "path has that name).",
)
SPEC = typer.Option(
    _SPEC,
    "--spec",
    help=f"Settings template name ({', '.join(list_templates('place'))}; `starforge templates place`) or "
    "TOML file: the defaults of the options below.",
)
MARKERS = typer.Option(
    None,
    "--markers",
    help=f"Target number of markers, in [{_T.get('min_markers')}, {_T.get('max_markers')}] "
    f"({_of_spec(_T.get('target_markers'))}).",
)
SITES = typer.Option(
    None, "--sites", help=f"Candidate sites, Poisson-disk samples on the surface ({_of_spec(_S['sites'])})."
)
RESTARTS = typer.Option(
    None,
    "--restarts",
    help=f"Annealing runs from the best random layout; the best layout is kept ({_of_spec(_T.get('restarts'))}).",
)
MARKER = typer.Option(
    None,
    "--marker-mm",
    "--marker",
    help=f"Marker: a catalogue name ({', '.join(list_templates('markers'))}; its base seats it) or a "
    f"ball diameter in mm ({_of_spec(_T.get('marker'))}).",
)
BASE = typer.Option(
    None,
    "--base-mm",
    help="Diameter of the flat base under each marker, mm (a stick-on pad; default: the marker's own).",
)
STANDOFF = typer.Option(
    None,
    "--standoff",
    help="Lift every marker this far off the prop (mm) on a printed post, written as standoff.stl (on a rod too thin "
    "for its foot, on a ring clamped round the rod: clamps.stl): markers stand clear of the hand and of the prop's "
    "bulk, for a small prop that no layout stuck on it keeps tracked (default: the spec's standoff_mm, 0: stuck on).",
)
GRIP = typer.Option(
    None,
    "--grip",
    help="Pin the hand to one grip: N (grip N of the list the run prints) or x0,y0,z0,x1,y1,z1[,r] (a fist around "
    "that segment, metres, prop frame; r the part's radius). Default: every grip of the distribution found from the "
    "prop's shape (either hand, several places along the graspable part, several wraps).",
)
NO_HAND = typer.Option(False, "--no-hand", help="No hand holds the prop.")
PLACEMENT_ERROR = typer.Option(
    None,
    "--placement-error",
    help="How far off its mark (mm) a technician may stick a marker: every marker seats with this much room before "
    "its base overhangs an edge or a surface tilted more than 30 degrees (default 2).",
)
CAMERAS_LOST = typer.Option(
    None,
    "--cameras-lost",
    help=f"Fraction of the cameras lost at random in each scenario, [0, 1] ({_of_spec(_T.get('cameras_lost'))}).",
)
BASES_STL = typer.Option(
    False,
    "--bases-stl",
    help="Also write prop_bases.stl: the prop with a flat pad under every marker (for printing).",
)
AVOID = typer.Option(
    None,
    "--avoid",
    help="Placements, star families or tracker files of bodies already in the room; several may follow one "
    "flag (--avoid A B): every value up to the next option is one, so give PROP before --avoid (default: none).",
)
UNITS = typer.Option("m", "--units", help="Units of a mesh file: m, cm or mm.")
FORBID_MESH = typer.Option(None, "--forbid-mesh", help="Mesh of a constrained area, no markers there (default: none).")
MASK = typer.Option(None, "--mask", help="Per-face mask file, 1 = no markers on that face (default: none).")
KEEP_NOISE = typer.Option(
    False,
    "--keep-noise",
    help="Keep a scanned mesh's noise (default: the repair smooths noise that tilts the faces, and says so).",
)
MESH_FORMAT = typer.Option(
    None,
    "--mesh-format",
    help=f"glb or stl for the prop-with-markers mesh ({_of_spec(_S.get('mesh_format'))}).",
)
SEED = typer.Option(0, "--seed", help="Random seed (same seed, same result).")
OUT = typer.Option("out/place", "--out", help="Output folder.")
FORCE = typer.Option(False, "--force", help="Overwrite existing output files.")
QUIET = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")


@place_app.command(
    _DEFAULT,
    help="Optimize a marker set on PROP; writes placement.json (source of truth), markers.csv, the prop "
    "with its markers and the pictures.  `run` may be left out: `starforge place PROP [OPTIONS]`.  "
    "To score a given layout instead: `starforge place score PROP MARKERS.csv` "
    "(see `starforge place score --help`).",
)
def run_cmd(
    prop: str = PROP,
    spec: str = SPEC,
    rig: str = _RIG,
    markers: int = MARKERS,
    resolution: int = _RESOLUTION,
    orientations: int = _ORIENTATIONS,
    sites: int = SITES,
    restarts: int = RESTARTS,
    marker_mm: str = MARKER,
    base_mm: float = BASE,
    standoff: float = STANDOFF,
    grip: str = GRIP,
    no_hand: bool = NO_HAND,
    placement_error: float = PLACEMENT_ERROR,
    cameras_lost: float = CAMERAS_LOST,
    bases_stl: bool = BASES_STL,
    avoid: list[Path] = AVOID,
    units: str = UNITS,
    forbid_mesh: str = FORBID_MESH,
    mask: str = MASK,
    keep_noise: bool = KEEP_NOISE,
    mesh_format: str = MESH_FORMAT,
    preset: str = PRESET,
    noise: float = NOISE,
    seed: int = SEED,
    out: str = OUT,
    force: bool = FORCE,
    quiet: bool = QUIET,
) -> None:
    from starforge.runtime.process import allow_quick_exit, pause_gc

    allow_quick_exit()  # every file goes through staged_output; the render processes are waited for
    pause_gc()  # before the render process forks (it draws with the collector off too) and the imports
    run = api.run_place(
        prop, out=out, seed=seed, force=force, bases_stl=bases_stl, spec=spec, units=units, rig=rig, markers=markers,
        resolution=resolution, orientations=orientations, sites=sites, restarts=restarts, marker_mm=marker_mm,
        base_mm=base_mm, standoff_mm=standoff, hand=False if no_hand else None, grip=grip, placement_error_mm=placement_error,
        cameras_lost=cameras_lost, avoid=avoid or (), forbid_mesh=forbid_mesh, mask=mask, smooth=not keep_noise,
        mesh_format=mesh_format,
        preset=preset, noise_mm=noise,
        on_layout=None if quiet else lambda _: console(),  # rich imported while the pictures are drawn, if it talks
    )  # fmt: skip
    if quiet:  # the warnings are in placement.json
        return
    err, con = console(stderr=True), console()
    for w in run.result.warnings:
        err.print(f"warning: {w}")
    for line in api.describe_placement(run.result):
        con.print(line)
    con.print(f"wrote {run.folder}/: {', '.join(run.files)}")


@place_app.command("score", help="Score a given marker layout (CSV id,x_m,y_m,z_m,nx,ny,nz) on PROP.")
def score_cmd(
    prop: str = _PROP,
    markers_csv: str = typer.Argument(..., help="Markers CSV (metres, prop frame); normals optional."),
    spec: str = typer.Option(_SPEC, "--spec", help="Settings template name or TOML file."),
    rig: str = _RIG,
    resolution: int = _RESOLUTION,
    orientations: int = _ORIENTATIONS,
    units: str = typer.Option("m", "--units", help="Units of the mesh file: m, cm or mm."),
    seed: int = typer.Option(0, "--seed", help="Seed for random orientations."),
    as_json: bool = typer.Option(False, "--json", help="Print the costs as JSON."),
) -> None:
    from starforge.runtime.process import allow_quick_exit

    allow_quick_exit()  # writes nothing but stdout
    score = api.score_markers(
        prop, markers_csv, spec=spec, units=units, seed=seed, rig=rig, resolution=resolution, orientations=orientations
    )
    if as_json:
        sys.stdout.write(json.dumps(score.to_json(), indent=2) + "\n")
        return
    con = console()
    for line in api.describe_score(score):
        con.print(line)
