"""The README and the docs site say what the code does: the generated command pages cover every
command and option of the CLI, the file-format page names every key a written family.json and
placement.json hold, the README stays short and its links resolve, and no command a reader types
sits in a block that CI does not run."""

from __future__ import annotations

import importlib.util
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def reference_pages() -> dict[str, str]:
    return _load(ROOT / "docs" / "hooks" / "cli_reference.py", "docs_cli_reference").pages()


def _walk(command, ctx):
    """(context, command) for ``command`` and every subcommand below it, walked here with click's
    own API, apart from the generator."""
    yield ctx, command
    if hasattr(command, "list_commands"):
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            yield from _walk(sub, type(ctx)(sub, info_name=name, parent=ctx))


def test_every_command_and_option_has_its_generated_page(reference_pages):
    from starforge.cli import click_command

    root = click_command()
    root_ctx = root.context_class(root, info_name="starforge")
    top = root.list_commands(root_ctx)
    assert set(reference_pages) == {"reference/index.md"} | {f"reference/{n}.md" for n in top}
    for name in top:
        page = reference_pages[f"reference/{name}.md"]
        cmd = root.get_command(root_ctx, name)
        for ctx, sub in _walk(cmd, root.context_class(cmd, info_name=name, parent=root_ctx)):
            assert f"`{ctx.command_path}`" in page, ctx.command_path
            for param in sub.get_params(ctx):
                for opt in [*param.opts, *param.secondary_opts]:
                    if param.param_type_name == "option":
                        assert re.search(rf"`[^`]*{re.escape(opt)}\b", page), (ctx.command_path, opt)
    index = reference_pages["reference/index.md"]
    for name in top:
        assert f"]({name}.md)" in index
    for opt in ("--max-memory", "--max-seconds", "--scheduler"):
        assert f"`{opt}" in index


def test_generated_help_text_is_markdown_safe(reference_pages):
    """Angle brackets of help text outside code spans (``star_<id>.png``) are entities, never tags."""
    for name, page in reference_pages.items():
        prose = re.sub(r"`[^`]*`", "", re.sub(r"```.*?```", "", page, flags=re.S))
        assert not re.search(r"<[A-Za-z_/]", prose), name


def _key_paths(obj, prefix: str = ""):
    if isinstance(obj, dict):
        for key, value in obj.items():
            yield from _key_paths(value, f"{prefix}.{key}" if prefix else key)
    elif isinstance(obj, list) and obj and isinstance(obj[0], dict):
        yield from _key_paths(obj[0], prefix + "[]")
    else:
        yield prefix


def _documented(path: str, names: set[str]) -> bool:
    """The path or one of its ancestors is a documented key."""
    parts = path.split(".")
    return any(".".join(parts[:k]) in names for k in range(len(parts), 0, -1))


def _section_names(start: str, end: str) -> set[str]:
    """The key names written in backticks in the formats page between two headings."""
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    section = text[text.index(start) : text.index(end)]
    return {m.strip() for cell in re.findall(r"`([^`]+)`", section) for m in cell.split(",")}


def test_formats_page_names_every_family_json_key(small_family):
    _, data = small_family
    names = _section_names("## family.json", "## bodies.json")
    missing = [p for p in _key_paths(data) if not _documented(p, names)]
    assert not missing, missing


@pytest.mark.slow
def test_formats_page_names_every_placement_json_key():
    from starforge.props.files import placement_json
    from starforge.props.placement import run_placement

    data = placement_json(run_placement("box", sites=150, orientations=8))
    names = _section_names("## placement.json", "## check.json")
    missing = [p for p in _key_paths(data) if not _documented(p, names)]
    assert not missing, missing


def test_readme_is_short_and_its_links_resolve():
    """At most 200 lines (its commands are checked against the CLI in test_newcomer.py), and every
    relative link (docs pages, pictures, the changelog, examples/) names a file or folder of the
    repository."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    local = [t for t in targets if "://" not in t]
    assert local
    for target in local:
        assert (ROOT / target).exists(), target


def test_results_page_sections_are_balanced():
    text = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    begins = re.findall(r"<!-- begin (\S+) -->", text)
    ends = re.findall(r"<!-- end (\S+) -->", text)
    assert begins and begins == ends and len(set(begins)) == len(begins)


#: a line of a fenced block that is a command a reader types
COMMAND_LINE = re.compile(r"^\s*(starforge(\s|$)|\$ )")


def _unlabelled_commands(text: str) -> list[str]:
    """The command lines of the fenced blocks of ``text`` that have no language."""
    rc = _load(ROOT / ".ci" / "readme_commands.py", "readme_commands_for_docs")
    return [line.strip() for language, body in rc.fenced_blocks(text.splitlines()) if not language
            for line in body if COMMAND_LINE.match(line)]


def test_no_command_hides_in_an_unlabelled_block():
    """Every fenced block of the README and the docs pages that holds a command (a line starting
    ``starforge`` or ``$ ``) is labelled (```bash: CI runs it; ```text: output or a usage synopsis),
    so no command escapes tests/test_docs_commands.py by a missing label."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    hidden = [f"{page.relative_to(ROOT)}: {line}"
              for page in pages for line in _unlabelled_commands(page.read_text(encoding="utf-8"))]
    assert len(pages) > 10
    assert not hidden, "commands in a fenced block with no language (label it ```bash):\n" + "\n".join(hidden)


def test_the_unlabelled_block_check_sees_commands():
    """The check above finds a command in an unlabelled block and leaves labelled ones alone."""
    page = "```\nstarforge place\n```\n```text\nstarforge stars [--count N]\n```\n```\n$ ls\nC = 1\n```\n"
    assert _unlabelled_commands(page) == ["starforge place", "$ ls"]


def test_ci_runs_the_development_pages_commands():
    """.ci/run runs the commands of docs/development.md as written: they install the dev extra
    (the test extra and ruff), lint with ruff, check the layer contracts, build the site
    strictly and run the slow tests; none of them is .ci/run itself."""
    rc = _load(ROOT / ".ci" / "readme_commands.py", "readme_commands_for_docs")
    page = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    commands = [c for block in rc.page_commands(page) for c in block]
    for needed in ('pip install -e ".[dev]"', "ruff check", "lint-imports", "mkdocs build --strict",
                   "pytest -m slow"):
        assert any(needed in c for c in commands), needed
    assert not any(".ci/run" in c for c in commands)
    assert "readme_commands.py docs docs/development.md" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    assert set(extras["test"]) <= set(extras["dev"]) and any(d.startswith("ruff") for d in extras["dev"])


#: README commands no CI step runs as such: the docs server, which the slow test
#: ``test_the_readmes_docs_server_serves`` starts and fetches from
SERVED = ("mkdocs serve",)


def test_every_readme_command_is_one_ci_runs():
    """Every command of the README's ```bash blocks is one CI runs: a set-up or tour command, a
    command of docs/development.md, a part of one of those joined by ``&&``, or the docs server."""
    rc = _load(ROOT / ".ci" / "readme_commands.py", "readme_commands_for_readme")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    development = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    run = [*rc.readme_commands(readme, "setup"), *rc.readme_commands(readme, "tour"),
           *(c for block in rc.page_commands(development) for c in block)]
    parts = {part.strip() for c in run for part in c.split("&&")}
    commands = [c for block in rc.page_commands(readme) for c in block]
    assert len(commands) > len(rc.readme_commands(readme, "tour"))
    not_run = [c for c in commands if c not in run and c not in parts and c not in SERVED]
    assert not not_run, f"README commands CI does not run: {not_run}"
