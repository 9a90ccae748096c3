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

from starforge.cli._app import app, console, progress

_DEFAULT = "run"


class _DefaultGroup(TyperGroup):
    """Dispatch to a subcommand when the first argument names one, else to the default command."""

    def parse_args(self, ctx, args):
        from starforge.cli._multi import spread_flag

        if not args or (args[0] not in self.commands and args[0] not in ctx.help_option_names):
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
    marker_mm=None, base_mm=None, hand=None, cameras_lost=None,
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
    )
    return load_prop(prop, units), s


_PROP = typer.Argument(
    ..., help="Mesh file (STL, OBJ, PLY, GLB, OFF) or built-in prop name (builtin:NAME when a path has that name)."
)


@place_app.command(_DEFAULT, help="Optimize a marker set on PROP (the default command).")
def run_cmd(
    prop: str = typer.Argument(
        "hammer",
        help="Mesh file (STL, OBJ, PLY, GLB, OFF) or built-in prop name (default: hammer; builtin:NAME when a "
        "path has that name).",
    ),
    spec: str = typer.Option(
        "default", "--spec", help="Settings template name (default, paper, long, robust; `starforge templates place`) or TOML file."
    ),
    rig: str = typer.Option(None, "--rig", help="Rig template name or TOML file (default: the spec's)."),
    markers: int = typer.Option(None, "--markers", help="Target number of markers (Table 1: 7), in [4, 20]."),
    resolution: int = typer.Option(None, "--resolution", help="n for n x n x n prop positions (4, 8, 12)."),
    orientations: int = typer.Option(None, "--orientations", help="Prop orientations per position (K)."),
    sites: int = typer.Option(None, "--sites", help="Candidate sites (Poisson-disk samples, default 1000)."),
    restarts: int = typer.Option(None, "--restarts", help="Independent annealing runs; the best is kept."),
    marker_mm: str = typer.Option(
        None,
        "--marker-mm",
        "--marker",
        help="Marker: a catalogue name (4mm-flat, 6.4mm-post, 9.5mm-m3, 12.7mm-m3, 14mm-m4; its base seats it) or a "
        "ball diameter in mm (default: the spec's, 9.5mm-m3).",
    ),
    base_mm: float = typer.Option(
        None, "--base-mm", help="Diameter of the flat base under each marker, mm (a stick-on pad; default: the marker's own)."
    ),
    grip: str = typer.Option(
        None, "--grip", help="The hand's grip: x0,y0,z0,x1,y1,z1[,r] in metres, prop frame (default: the prop's grip)."
    ),
    no_hand: bool = typer.Option(False, "--no-hand", help="No hand holds the prop."),
    cameras_lost: float = typer.Option(
        None, "--cameras-lost", help="Fraction of the cameras lost at random in each scenario, [0, 1] (default 0.5)."
    ),
    bases_stl: bool = typer.Option(
        False, "--bases-stl", help="Also write prop_bases.stl: the prop with a flat pad under every marker (for printing)."
    ),
    avoid: list[Path] = typer.Option(
        None,
        "--avoid",
        help="Placements, star families or tracker files of bodies already in the room; several may follow one "
        "flag (--avoid A B): every value up to the next option is one, so give PROP before --avoid.",
    ),
    units: str = typer.Option("m", "--units", help="Units of a mesh file: m, cm or mm."),
    forbid_mesh: str = typer.Option(None, "--forbid-mesh", help="Mesh of a constrained area (no markers)."),
    mask: str = typer.Option(None, "--mask", help="Per-face mask file (1 = no markers on that face)."),
    mesh_format: str = typer.Option(None, "--mesh-format", help="glb or stl for the prop-with-markers mesh."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same result)."),
    out: str = typer.Option("out/place", "--out", help="Output folder."),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.cli._app import allow_quick_exit, pause_gc
    from starforge.errors import StarforgeError
    from starforge.render.props import BackgroundRenderer

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
        )
        cap = None
        if grip is not None and not no_hand:
            from starforge.props.hand import parse_grip

            cap = parse_grip(grip)
        avoid_faces = None
        if avoid:
            from starforge.stars.avoid import faces_to_avoid

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
        with progress() as bar:
            task = bar.add_task("visibility", total=None)

            def cb(stage, done, total):
                bar.update(task, description=stage, completed=done, total=total)

            with staged_output(out, force) as stage:
                # the pictures are drawn while the layouts are evaluated on fresh poses
                res = place(
                    p, s, seed=seed, progress=cb, avoid=avoid_faces, grip=cap,
                    on_layout=lambda r: renderer.submit(r, stage),
                )  # fmt: skip
                bar.update(task, description="writing")
                # rich imported while the pictures are drawn, not after them
                err, con = console(stderr=True), None if quiet else console()
                write_outputs(res, stage, renderer=renderer, bases_stl=bases_stl)
    from starforge.props.files import summary_lines

    for w in res.warnings:
        err.print(f"warning: {w}")
    if not quiet:
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
    spec: str = typer.Option("default", "--spec", help="Settings template name or TOML file."),
    rig: str = typer.Option(None, "--rig", help="Rig template name or TOML file."),
    resolution: int = typer.Option(None, "--resolution", help="n for n x n x n prop positions."),
    orientations: int = typer.Option(None, "--orientations", help="Prop orientations per position (K)."),
    units: str = typer.Option("m", "--units", help="Units of the mesh file: m, cm or mm."),
    seed: int = typer.Option(0, "--seed", help="Seed for random orientations."),
    as_json: bool = typer.Option(False, "--json", help="Print the costs as JSON."),
) -> None:
    import json

    from starforge.cli._app import allow_quick_exit
    from starforge.props.files import read_markers_csv

    allow_quick_exit()  # writes nothing but stdout
    from starforge.props.placement import score_layout

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
