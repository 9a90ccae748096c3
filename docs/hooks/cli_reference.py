"""The command reference, generated from the CLI itself: one page per command.

Used two ways:

* as an MkDocs hook (``hooks:`` in mkdocs.yml): every build walks the click command tree of
  ``starforge.cli`` and adds ``reference/index.md`` (the global options and the list of
  commands) and ``reference/<command>.md`` (usage, help text, arguments, options; subcommands
  on their parent's page) as generated pages, and puts them in the navigation in place of the
  ``reference/index.md`` entry.  A command added to ``starforge/cli/`` appears on its own, and
  the pages say exactly what ``--help`` says;
* as a script, ``python docs/hooks/cli_reference.py OUT_DIR``: writes the same pages into
  ``OUT_DIR`` to read them without building the site.

The checkout that holds this file comes first on ``sys.path``, so the pages describe the code
beside them, not another installed copy.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = "reference"
NAV_TITLE = "Command reference"
PROG = "starforge"

#: the hand-written pages a command's generated page points to (a command not named here gets none)
SEE_ALSO = {
    "stars": [
        ("star families", "methods/stars.md"),
        ("the fit decision", "methods/fit.md"),
        ("selection and its bound", "methods/selection.md"),
        ("finger stars for my box and screws", "recipes/finger-stars.md"),
        ("family.json", "formats.md#familyjson"),
    ],
    "export": [
        ("printable bodies", "methods/bodies.md"),
        ("bodies.json", "formats.md#bodiesjson"),
        ("tracker files", "formats.md#tracker-files"),
    ],
    "mounts": [("mounts", "methods/bodies.md#mounts")],
    "preview": [("printable bodies", "methods/bodies.md")],
    "check": [
        ("what a tracker sees", "methods/identification.md"),
        ("30 drones on my tracker", "recipes/drones.md"),
        ("check.json", "formats.md#checkjson"),
    ],
    "sweep": [
        ("capacity curves", "methods/identification.md#capacity-curves-the-family-papers-fig-8"),
        ("scale-out", "scale-out.md"),
    ],
    "place": [
        ("prop placement", "methods/placement.md"),
        ("markers on my prop", "recipes/prop.md"),
        ("placement.json", "formats.md#placementjson"),
    ],
    "place-batch": [("prop placement", "methods/placement.md"), ("scale-out", "scale-out.md")],
    "templates": [("getting started", "getting-started.md#templates-start-from-one-that-is-close")],
}


def _cli():
    """The root click command of ``starforge`` and its Context class."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from starforge.cli import click_command

    root = click_command()
    return root, root.context_class


def _markdown_text(text: str) -> str:
    """A help string as Markdown: rich's escaped ``\\[`` back to ``[``, and ``<`` / ``>`` outside
    code spans as entities (``star_<id>.png`` is not an HTML tag)."""
    text = text.replace("\\[", "[")
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(
        p if p.startswith("`") else p.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        for p in parts
    )


def _paragraphs(help_text: str | None) -> list[str]:
    """The help text's paragraphs, each joined onto one line."""
    if not help_text:
        return []
    text = help_text.replace("\b", "")
    blocks = re.split(r"\n\s*\n", text.strip())
    return [" ".join(b.split()) for b in blocks if b.strip()]


def _cell(text: str) -> str:
    """Text for a Markdown table cell: pipes outside code spans escaped."""
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(p if p.startswith("`") else p.replace("|", "\\|") for p in parts)


def _params_tables(command, ctx) -> list[str]:
    """The arguments' and the options' tables of ``command``, as ``--help`` lists them."""
    args, opts = [], []
    for param in command.get_params(ctx):
        if getattr(param, "hidden", False):
            continue
        record = param.get_help_record(ctx)
        if record is None:
            continue
        names, help_text = record
        row = f"| `{names}` | {_cell(_markdown_text(' '.join(help_text.split())))} |"
        (args if param.param_type_name == "argument" else opts).append(row)
    lines: list[str] = []
    for title, rows in (("Arguments", args), ("Options", opts)):
        if rows:
            lines += ["", f"**{title}**", "", "| name | description |", "| --- | --- |", *rows]
    return lines


def _usage(command, ctx) -> str:
    """The usage line as click prints it, without its ``Usage:`` prefix."""
    return command.get_usage(ctx).removeprefix("Usage:").strip()


def _command_section(command, ctx, level: int, subcommands: bool = True) -> list[str]:
    """Usage, help, arguments and options of ``command``, then (``subcommands``) its
    subcommands one heading level down."""
    lines = ["", "```text", _usage(command, ctx), "```", ""]
    lines += [_markdown_text(p) + "\n" for p in _paragraphs(command.help)]
    lines += _params_tables(command, ctx)
    names = command.list_commands(ctx) if subcommands and hasattr(command, "list_commands") else []
    for name in names:
        sub = command.get_command(ctx, name)
        if sub is None or sub.hidden:
            continue
        sub_ctx = type(ctx)(sub, info_name=name, parent=ctx)
        lines += ["", f"{'#' * (level + 1)} `{sub_ctx.command_path}`"]
        lines += _command_section(sub, sub_ctx, level + 1)
    return lines


def _first_paragraph(command) -> str:
    paras = _paragraphs(command.help)
    return _cell(_markdown_text(paras[0])) if paras else ""


def pages() -> dict[str, str]:
    """Every generated page: ``{"reference/index.md": text, "reference/<command>.md": text, ...}``,
    the commands in the order ``starforge --help`` lists them."""
    root, context = _cli()
    root_ctx = context(root, info_name=PROG)
    names = [n for n in root.list_commands(root_ctx) if not root.get_command(root_ctx, n).hidden]
    out: dict[str, str] = {}
    index = [
        f"# `{PROG}`",
        "",
        "Generated from the command line itself at every docs build: each page says what "
        f"`{PROG} COMMAND --help` says.",
    ]
    index += _command_section(root, root_ctx, 1, subcommands=False)
    index += ["", "## Commands", "", "| command | what it does |", "| --- | --- |"]
    for name in names:
        cmd = root.get_command(root_ctx, name)
        index.append(f"| [`{PROG} {name}`]({name}.md) | {_first_paragraph(cmd)} |")
        ctx = context(cmd, info_name=name, parent=root_ctx)
        body = [f"# `{ctx.command_path}`", *_command_section(cmd, ctx, 1)]
        links = ", ".join(f"[{title}](../{target})" for title, target in SEE_ALSO.get(name, []))
        if links:
            body += ["", f"See also: {links}."]
        body += ["", f"Global options (before the command) are on the [`{PROG}`](index.md) page."]
        out[f"{REFERENCE}/{name}.md"] = "\n".join(body) + "\n"
    out[f"{REFERENCE}/index.md"] = "\n".join(index) + "\n"
    return out


# --- MkDocs hook -------------------------------------------------------------------------------

_generated: dict[str, str] = {}


def on_config(config):
    """Generate the pages once per build and put them in the navigation where ``reference/index.md``
    stands (as a section of that name)."""
    _generated.clear()
    _generated.update(pages())
    entries = [f"{REFERENCE}/index.md"] + [
        {f"{PROG} {Path(p).stem}": p} for p in _generated if not p.endswith("/index.md")
    ]

    def replace(items):
        out = []
        for item in items:
            if isinstance(item, dict):
                ((title, value),) = item.items()
                if value == f"{REFERENCE}/index.md":
                    out.append({title: entries})
                    continue
                if isinstance(value, list):
                    out.append({title: replace(value)})
                    continue
            out.append(item)
        return out

    if config.get("nav"):
        config["nav"] = replace(config["nav"])
    return config


def on_files(files, config):
    """Add the generated pages to the build's files."""
    from mkdocs.structure.files import File

    for src_uri, content in _generated.items():
        existing = files.get_file_from_path(src_uri)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, src_uri, content=content))
    return files


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        sys.stderr.write("usage: cli_reference.py OUT_DIR\n")
        return 2
    out = Path(argv[1])
    for rel, text in pages().items():
        path = out / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
