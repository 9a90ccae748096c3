"""``starforge templates``: list the shipped TOML templates (catalogs as data)."""

from __future__ import annotations

import typer

from starforge.catalog import KINDS
from starforge.cli._app import app


@app.command("templates")
def templates_cmd(
    kind: str = typer.Argument(None, help=f"{', '.join(KINDS)}; all when omitted."),
    show: str = typer.Option(None, "--show", help="Print one template's TOML text (KIND is required)."),
) -> None:
    """List the shipped templates, or print one to copy and edit."""
    from importlib import resources

    from starforge.catalog import list_templates, load_template

    if show:
        if not kind:
            raise ValueError("--show needs KIND, e.g. starforge templates stars --show finger")
        load_template(kind, show, "--show")  # validates the name, lists known ones if unknown
        print(resources.files("starforge.templates").joinpath(kind, f"{show}.toml").read_text(), end="")
        return
    for k in [kind] if kind else KINDS:
        names = list_templates(k)
        print(f"{k}: {', '.join(names) if names else '(none)'}")
