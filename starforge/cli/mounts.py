"""``starforge mounts``: the mount templates (templates/mounts/*.toml) with parameters, ranges and
the room each needs in a family's size limit."""

from __future__ import annotations

import math

import typer

from starforge.cli._app import app, console


@app.command("mounts")
def mounts_cmd(
    name: str = typer.Argument(None, help="A mount name (or TOML path) to show in detail; all when omitted."),
    marker: str = typer.Option(
        "4", "--marker", help="Marker sphere diameter, mm, or a catalogue marker, for the room (as `stars --marker`)."
    ),
) -> None:
    """List the mounts a star body can have, with the room each needs in the size limit
    (what `starforge stars --mount NAME` reserves); with NAME, its parameters and ranges."""
    from starforge.cad.mounts import list_mounts, load_mount
    from starforge.cad.reserve import mount_reserve_mm
    from starforge.errors import StarforgeError
    from starforge.markers import marker_diameter_mm

    try:
        marker = marker_diameter_mm(marker)  # the range `stars --marker` accepts
    except StarforgeError as exc:
        raise StarforgeError(f"--marker: {exc}") from None
    con = console()
    mounts = [load_mount(name)] if name else list_mounts()
    for m in mounts:
        # rounded up to 0.01 mm: typed into --reserve, the shown room is never too small
        room = " ".join(f"{math.ceil(v * 100 - 1e-9) / 100:g}" for v in mount_reserve_mm(m, marker))
        con.print(f"[bold]{m.name}[/bold] ({m.kind}): {m.description}; room {room} mm")
        if name:
            for k, v in m.params.items():
                lo, hi = m.ranges[k]
                con.print(f"  {k} = {v:g}   range [{lo:g}, {hi:g}]")
    con.print(
        f"room: mm of the size limit's shortest, middle and longest side the mount needs with {marker:g} mm markers "
        "(`starforge stars --mount NAME` reserves it)"
    )
    if not name:
        con.print(
            "details: starforge mounts NAME; use: starforge export FAMILY --mount NAME [--set KEY=VALUE]"
        )
