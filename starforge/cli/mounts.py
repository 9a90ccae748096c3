"""``starforge mounts``: the mount templates (templates/mounts/*.toml) with parameters and ranges."""

from __future__ import annotations

import typer

from starforge.cli._app import app, console


@app.command("mounts")
def mounts_cmd(
    name: str = typer.Argument(None, help="A mount name (or TOML path) to show in detail; all when omitted."),
) -> None:
    """List the mounts a star body can have; with NAME, its parameters, defaults and ranges."""
    from starforge.cad.mounts import list_mounts, load_mount

    con = console()
    mounts = [load_mount(name)] if name else list_mounts()
    for m in mounts:
        con.print(f"[bold]{m.name}[/bold] ({m.kind}): {m.description}")
        if name:
            for k, v in m.params.items():
                lo, hi = m.ranges[k]
                con.print(f"  {k} = {v:g}   range [{lo:g}, {hi:g}]")
    if not name:
        con.print(
            "details: starforge mounts NAME; use: starforge export FAMILY --mount NAME [--set KEY=VALUE]"
        )
