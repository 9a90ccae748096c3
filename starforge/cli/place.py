"""``starforge place``: optimize a marker set on a prop (``place PROP``) or score one (``place score``).

``place`` is a default-command group: ``starforge place hammer`` runs the placement, while
``starforge place score PROP MARKERS.csv`` scores a given layout.  A prop file that happens to be
named ``score`` can be given as ``./score``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer
from typer.core import TyperGroup

from starforge.api.place import distinct_tolerance_mm
from starforge.catalog import list_templates, load_template
from starforge.cli._app import app, console
from starforge.runtime import progress

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


def _prop_and_spec(
    prop, units, spec, rig, markers, resolution, orientations, sites, restarts, forbid_mesh, mask, mesh_format,
    marker_mm=None, base_mm=None, hand=None, cameras_lost=None, placement_error=None,
):
    from dataclasses import replace

    from starforge.props.mesh import load_prop
    from starforge.props.spec import load_spec, with_overrides

    s = load_spec(spec)
    cons = None
    if forbid_mesh or mask:
        from starforge.io import check_input_file

        cons = s.constraints
        if forbid_mesh:
            check_input_file(forbid_mesh, "--forbid-mesh file", "mesh")  # before the long work
            cons = replace(cons, mesh=str(forbid_mesh))
        if mask:
            check_input_file(mask, "--mask file", "mask")
            cons = replace(cons, mask=str(mask))
    s = with_overrides(
        s,
        markers=markers,
        resolution=resolution,
        orientations=orientations,
        sites=sites,
        restarts=restarts,
        rig=rig,
        constraints=cons,
        mesh_format=mesh_format,
        marker_mm=marker_mm,
        base_mm=base_mm,
        hand=hand,
        cameras_lost=cameras_lost,
        placement_error_mm=placement_error,
    )
    return load_prop(prop, units), s



#: the marker noise the layouts' triangles are designed for by default, mm
NOISE_MM = 0.2
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


@place_app.command(
    _DEFAULT,
    help="Optimize a marker set on PROP; writes placement.json (source of truth), markers.csv, the prop "
    "with its markers and the pictures.  `run` may be left out: `starforge place PROP [OPTIONS]`.  "
    "To score a given layout instead: `starforge place score PROP MARKERS.csv` "
    "(see `starforge place score --help`).",
)
def run_cmd(
    prop: str = typer.Argument(
        "hammer",
        help="Mesh file (STL, OBJ, PLY, GLB, OFF) or built-in prop name (default: hammer; builtin:NAME when a "
        "path has that name).",
    ),
    spec: str = typer.Option(
        _SPEC,
        "--spec",
        help=f"Settings template name ({', '.join(list_templates('place'))}; `starforge templates place`) or "
        "TOML file: the defaults of the options below.",
    ),
    rig: str = _RIG,
    markers: int = typer.Option(
        None,
        "--markers",
        help=f"Target number of markers, in [{_T.get('min_markers')}, {_T.get('max_markers')}] "
        f"({_of_spec(_T.get('target_markers'))}).",
    ),
    resolution: int = _RESOLUTION,
    orientations: int = _ORIENTATIONS,
    sites: int = typer.Option(
        None,
        "--sites",
        help=f"Candidate sites, Poisson-disk samples on the surface ({_of_spec(_S['sites'])}).",
    ),
    restarts: int = typer.Option(
        None,
        "--restarts",
        help=f"Annealing runs from the best random layout; the best layout is kept ({_of_spec(_T.get('restarts'))}).",
    ),
    marker_mm: str = typer.Option(
        None,
        "--marker-mm",
        "--marker",
        help=f"Marker: a catalogue name ({', '.join(list_templates('markers'))}; its base seats it) or a "
        f"ball diameter in mm ({_of_spec(_T.get('marker'))}).",
    ),
    base_mm: float = typer.Option(
        None,
        "--base-mm",
        help="Diameter of the flat base under each marker, mm (a stick-on pad; default: the marker's own).",
    ),
    grip: str = typer.Option(
        None,
        "--grip",
        help="Pin the hand to one grip: N (grip N of the list the run prints) or x0,y0,z0,x1,y1,z1[,r] (a fist around "
        "that segment, metres, prop frame; r the part's radius). Default: every grip of the distribution found from the "
        "prop's shape (either hand, several places along the graspable part, several wraps).",
    ),
    no_hand: bool = typer.Option(False, "--no-hand", help="No hand holds the prop."),
    placement_error: float = typer.Option(
        None,
        "--placement-error",
        help="How far off its mark (mm) a technician may stick a marker: every marker seats with this much room before "
        "its base overhangs an edge or a surface tilted more than 30 degrees (default 2).",
    ),
    cameras_lost: float = typer.Option(
        None,
        "--cameras-lost",
        help=f"Fraction of the cameras lost at random in each scenario, [0, 1] ({_of_spec(_T.get('cameras_lost'))}).",
    ),
    bases_stl: bool = typer.Option(
        False,
        "--bases-stl",
        help="Also write prop_bases.stl: the prop with a flat pad under every marker (for printing).",
    ),
    avoid: list[Path] = typer.Option(
        None,
        "--avoid",
        help="Placements, star families or tracker files of bodies already in the room; several may follow one "
        "flag (--avoid A B): every value up to the next option is one, so give PROP before --avoid (default: none).",
    ),
    units: str = typer.Option("m", "--units", help="Units of a mesh file: m, cm or mm."),
    forbid_mesh: str = typer.Option(
        None, "--forbid-mesh", help="Mesh of a constrained area, no markers there (default: none)."
    ),
    mask: str = typer.Option(
        None, "--mask", help="Per-face mask file, 1 = no markers on that face (default: none)."
    ),
    mesh_format: str = typer.Option(
        None,
        "--mesh-format",
        help=f"glb or stl for the prop-with-markers mesh ({_of_spec(_S.get('mesh_format'))}).",
    ),
    preset: str = PRESET,
    noise: float = NOISE,
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same result)."),
    out: str = typer.Option("out/place", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.errors import StarforgeError
    from starforge.render.props import BackgroundRenderer
    from starforge.runtime.process import allow_quick_exit, pause_gc

    allow_quick_exit()  # every file goes through staged_output; the render processes are waited for
    pause_gc()  # before the render process forks (it draws with the collector off too) and the imports
    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    if avoid:  # the files to avoid exist and are readable before any work starts
        from starforge.tracking.bodies import check_body_files

        check_body_files(avoid, "--avoid file")
    # fork the picture-drawing process first, so that its matplotlib import overlaps our work
    with BackgroundRenderer() as renderer:
        from starforge.io import check_writable, staged_output
        from starforge.props.files import write_outputs
        from starforge.props.placement import place

        out = Path(out)
        p, s = _prop_and_spec(
            prop,
            units,
            spec,
            rig,
            markers,
            resolution,
            orientations,
            sites,
            restarts,
            forbid_mesh,
            mask,
            mesh_format,
            marker_mm,
            base_mm,
            False if no_hand else None,
            cameras_lost,
            placement_error,
        )
        from starforge.props.spec import with_overrides

        s = with_overrides(s, distinct_mm=distinct_tolerance_mm(s, preset, noise))
        cap = None if no_hand else grip
        avoid_faces = None
        if avoid:
            from starforge.tracking.avoid import faces_to_avoid

            avoid_faces = faces_to_avoid(avoid)[0] / 1000.0  # mm -> m
        names = [
            "placement.json",
            "markers.csv",
            f"prop_markers.{s.mesh_format}",
            "convergence.png",
            "layout.png",
            "guide.png",
            "guide.pdf",
        ] + (["prop_bases.stl"] if bases_stl else [])
        check_writable(out, names, force)  # fail before the work, not after
        with staged_output(out, force) as stage:
            # the pictures are drawn while the layouts are evaluated on fresh poses
            res = place(
                p, s, seed=seed, avoid=avoid_faces, grip=cap, on_layout=lambda r: renderer.submit(r, stage),
            )  # fmt: skip
            # rich imported while the pictures are drawn, not after them
            err, con = console(stderr=True), None if quiet else console()
            with progress.stage("render", unit="pictures"):
                write_outputs(res, stage, renderer=renderer, bases_stl=bases_stl)
    from starforge.props.files import summary_lines

    if quiet:  # the warnings are in placement.json
        return
    for w in res.warnings:
        err.print(f"warning: {w}")
    for line in summary_lines(res):
        con.print(line)
    t = res.timings
    load = t.get("load_s", 0.0) + t.get("repair_s", 0.0)
    con.print(
        f"time: load {load:.2f} s, sites {t.get('sample_s', 0):.2f} s, visibility {t['visibility_s']:.2f} s, "
        f"optimization {t['optimize_s']:.2f} s, evaluation {t.get('evaluate_s', 0):.2f} s"
    )
    con.print(f"wrote {out}/: {', '.join(names)}")


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
    import json

    from starforge.props.files import read_markers_csv
    from starforge.runtime.process import allow_quick_exit

    allow_quick_exit()  # writes nothing but stdout
    from starforge.props.score import score_layout

    p, s = _prop_and_spec(
        prop, units, spec, rig, None, resolution, orientations, None, None, None, None, None
    )
    pts, nrm = read_markers_csv(markers_csv)
    cost, vis, extra = score_layout(p, pts, nrm, s, seed=seed)
    doc = {**cost.to_json(), "marker_visibility": [round(float(v), 9) for v in vis], **extra}
    if as_json:
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
        return
    con = console()
    con.print(f"{p.name}: {cost.markers} markers, cost {cost.total:.4f}")
    seated = extra.get("seated", [])
    con.print(f"  seated: {sum(seated)} of {len(seated)} markers (their base rests on the surface, clear of sharp edges)")
    if "tracked_fraction" in extra:
        con.print(f"  tracked in {100 * extra['tracked_fraction']:.1f} % of the scenarios, mean visibility {cost.mean_visibility:.3f}")
        m3, m4 = (extra[k] for k in ("self_margin_mm", "self_margin_4_mm"))
        if m3 is not None:
            con.print(
                f"  self-margin {m3:.2f} mm from any 3 markers"
                + (f", {m4:.2f} mm from any 4" if m4 is not None else "")
                + " (under a tracker's window, those markers flip)"
            )
        ev = extra.get("evaluation")
        if ev:
            con.print(
                f"  on fresh poses with cameras lost and the hand: tracked {100 * ev['tracked']:.1f} %, "
                f"markers reconstructed {ev['markers_reconstructed']:.3f}"
            )
        return
    con.print(
        f"  visibility {cost.visibility:.4f} (mean {cost.mean_visibility:.3f}), count {cost.count:.4f}, "
        f"overlap {cost.overlap:.4f} ({cost.overlapping_pairs} pairs), symmetry {cost.symmetry:.0f}"
    )
    if doc["near_symmetry_margin_m"] is not None:
        con.print(f"  near-symmetry margin {cost.margin_m * 1000:.1f} mm")
