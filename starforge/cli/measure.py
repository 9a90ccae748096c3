"""``starforge measure``: rigid bodies, their geometry and scatter, from a recording."""

from __future__ import annotations

import typer

from starforge.cli._app import FAMILY_MOUNT, app
from starforge.words import counted


@app.command(
    "measure",
    help="Measure rigid bodies from a recording of labelled markers (C3D; QTM, Motive or Vicon CSV export): "
    "the bodies named with --body, else every group of markers that keeps its distances.  Writes "
    "bodies.csv, family.json (the 4-marker bodies: export, check, convert and --avoid take it) and "
    "measure.json (geometry, per-marker scatter, and how often the bodies are identified in the recording).",
)
def measure_cmd(
    recording: str = typer.Argument(..., help="A .c3d file or a QTM (.tsv), Motive or Vicon CSV export."),
    out: str = typer.Option(..., "--out", help="Output folder."),
    body: list[str] = typer.Option(
        None,
        "--body",
        help="A body as NAME=M1,M2,M3[,...] (marker labels; repeatable). Default: every rigid group.",
    ),
    rigid: float = typer.Option(
        0.5, "--rigid", help="A pair of markers is rigid when its distance varies by at most this, mm (std)."
    ),
    noise: float = typer.Option(
        0.2, "--noise", help="Marker noise the family's accuracy is predicted for, mm."
    ),
    mount: str = FAMILY_MOUNT,
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing but errors."),
) -> None:
    from starforge.cad.reserve import mount_reserve_mm
    from starforge.io import check_writable, staged_output
    from starforge.spec import in_range
    from starforge.stars.spec import MAX_NOISE_MM
    from starforge.tracking.measure import measure_bodies, measure_outputs, parse_body_option
    from starforge.tracking.recording import read_recording

    in_range("--noise", noise, 0.0, MAX_NOISE_MM)  # before the recording is read
    named = [parse_body_option(b) for b in body] if body else None
    check_writable(out, ["bodies.csv", "family.json", "measure.json"], force)
    traj = read_recording(recording)
    bodies = measure_bodies(traj, named, rigid)
    reserve = (lambda marker: mount_reserve_mm(mount, marker)) if mount else None
    result = measure_outputs(traj, bodies, noise, mount, reserve)
    with staged_output(out, force) as stage:
        for rel, data in result.files.items():
            (stage / rel).write_bytes(data)
    if quiet:
        return
    typer.echo(f"{counted(len(bodies), 'body')} from {counted(traj.points_mm.shape[0], 'frame')} of {recording} -> {out}")
    for b in bodies:
        typer.echo(
            f"  {b.name}: {len(b.labels)} markers ({', '.join(b.labels)}), scatter <= {b.scatter_mm.max():.3f} mm, "
            f"identified in {100 * result.identified[b.name]:.1f} % of frames"
        )
    if result.family_note:
        typer.echo(result.family_note)
