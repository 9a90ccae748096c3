"""A newcomer's path: the README's commands (what .ci/run runs) parse against the CLI, caches stay
out of the installed package, and export's refusal names the command that fits."""

from __future__ import annotations

import importlib.util
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _readme_commands():
    spec = importlib.util.spec_from_file_location("readme_commands", ROOT / ".ci" / "readme_commands.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_comment_stripping_keeps_quoted_hashes():
    rc = _readme_commands()
    assert rc.strip_comment('pip install -e ".[test]"   # the extra') == 'pip install -e ".[test]"'
    assert rc.strip_comment("echo 'a # b' # c") == "echo 'a # b'"
    assert rc.strip_comment("x#y") == "x#y"
    lines = ["## A five-minute tour", "```bash", "starforge a \\", "  --b 1   # c", "", "starforge d", "```"]
    assert rc.readme_commands("\n".join(lines), "tour") == ["starforge a --b 1", "starforge d"]



def test_docs_page_commands_come_from_every_shell_block_only():
    rc = _readme_commands()
    page = ["# t", "```bash", "# only a comment", "starforge a \\", "    --b 1  # c", "```", "text",
            "```python", "print(1)", "```", "```sh", "starforge x > y.toml", "#   k = 2", "```",
            "```text", "starforge not-run", "```", "```", "starforge unlabelled", "```"]
    assert rc.page_commands("\n".join(page)) == [["starforge a --b 1"], ["starforge x > y.toml"]]
    assert [lang for lang, _ in rc.fenced_blocks(page)] == ["bash", "python", "sh", "text", ""]

def test_readme_opens_with_the_two_commands_and_a_tour_that_parses():
    """Every tour command names a real command and real options with valid values (parsed by the
    CLI itself, not run), and reads only families that the README's earlier commands write."""
    import click

    from starforge.cli import click_command

    rc = _readme_commands()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    setup = rc.readme_commands(readme, "setup")
    assert len(setup) == 2
    assert setup[0].startswith("pip install . && starforge")
    assert setup[1].startswith('pip install -e ".[test]"') and "pytest" in setup[1]
    tour = rc.readme_commands(readme, "tour")
    assert len(tour) >= 3
    group = click_command()
    made: set[str] = set()
    for line in [setup[0].split("&&", 1)[1].strip(), *tour]:
        words = shlex.split(line)
        assert words[0] == "starforge", line
        cmd = group.commands[words[1]]
        try:
            ctx = cmd.make_context(words[1], words[2:])
        except click.exceptions.UsageError as exc:  # pragma: no cover - the failure message
            pytest.fail(f"README command does not parse: {line}: {exc.format_message()}")
        p = ctx.params
        if p.get("file") is not None:
            folder = Path(p["file"]).parent if Path(p["file"]).suffix else Path(p["file"])
            assert folder.as_posix() in made, f"{line}: reads {p['file']}, which no earlier command writes"
        if words[1] == "stars":  # the tour runs where the first command ran: no collision, no --force
            target = Path(p["out"]) if p.get("out") else Path("out") / (p.get("name") or "finger")
            assert target.as_posix() not in made, f"{line}: {target} is already written by an earlier command"
            assert not p.get("force"), f"{line}: the tour must not need --force"
            made.add(target.as_posix())
    assert "out/finger" in made


@pytest.mark.slow
def test_caches_live_outside_the_package(tmp_path):
    """After a kernel compile, no numba cache file is inside the starforge package, and the
    cache folder is the one STARFORGE_CACHE_DIR names."""
    import starforge

    pkg = Path(starforge.__file__).parent
    before = {p for p in pkg.rglob("*.nb[ic]")}
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["STARFORGE_CACHE_DIR"] = str(tmp_path / "sfcache")
    code = (
        "import json, os, starforge\n"
        "from starforge.geometry.sym3 import sym3_eigvals\n"
        "sym3_eigvals(2.0, 1.0, 3.0, 0.1, 0.2, 0.3)\n"
        "print(json.dumps([starforge.cache_dir(), os.environ['NUMBA_CACHE_DIR']]))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    cache, numba_dir = json.loads(res.stdout)
    assert Path(cache) == tmp_path / "sfcache"
    assert Path(numba_dir) == tmp_path / "sfcache" / "numba"
    assert list((tmp_path / "sfcache" / "numba").rglob("*.nbi")), "the compile wrote no cache index there"
    assert {p for p in pkg.rglob("*.nb[ic]")} - before == set()
    assert not before, f"cache files inside the package: {sorted(before)[:3]}"


def test_cache_dir_defaults_to_the_user_cache_folder(monkeypatch):
    from platformdirs import user_cache_dir

    import starforge

    monkeypatch.delenv("STARFORGE_CACHE_DIR", raising=False)
    assert starforge.cache_dir() == user_cache_dir("starforge", appauthor=False)
    monkeypatch.setenv("STARFORGE_CACHE_DIR", "/somewhere/else")
    assert starforge.cache_dir() == "/somewhere/else"


def test_export_refusal_names_the_stars_command_that_fits():
    from starforge.cad.describe import stars_command_for
    from starforge.catalog import load_template
    from starforge.stars.spec import spec_from_mapping

    finger = spec_from_mapping({**load_template("stars", "finger")[1], "count": 25}, name="f25")
    assert stars_command_for(finger, "flat") == "starforge stars --count 25 --name f25-flat --mount flat"
    other = spec_from_mapping({"box_mm": [30, 20, 50], "delta_mm": 2.0}, name="big")
    cmd = stars_command_for(other, "strap")
    assert "--box 30 20 50" in cmd and "--delta 2" in cmd and cmd.endswith("--name big-strap --mount strap")
    # the command it prints parses, and makes that spec again (save the name and mount)
    from starforge.cli import click_command

    ctx = click_command().commands["stars"].make_context("stars", shlex.split(cmd)[2:])
    assert tuple(ctx.params["box"]) == (30, 20, 50) and ctx.params["delta"] == 2.0


def test_plain_progress_lines_without_a_terminal(capsys):
    """Off a terminal the library's progress becomes plain lines: one when a stage starts and one
    every interval from a thread (so that work which never calls back, numba's first compile,
    still shows it is alive), with counts in thousands and no line repeated."""
    import time

    from starforge.cli._progress import Plain, listener_for
    from starforge.runtime import progress

    shown = listener_for("stars", quiet=False)
    shown.close()
    assert isinstance(shown, Plain)  # pytest's stderr is not a terminal
    listener = Plain("stars", interval_s=0.05, hold_s=0.0)
    try:
        with progress.reporting(listener):
            time.sleep(0.12)
            with progress.stage("enumerate", total=20_000, unit="candidates") as st:
                st.update(5_000)
                time.sleep(0.12)
                st.update(advance=5_000)
                time.sleep(0.12)
            with progress.stage("select"):
                time.sleep(0.12)
    finally:
        listener.close()
    lines = capsys.readouterr().err.splitlines()
    assert lines and all(line.startswith("starforge stars: ") for line in lines)
    assert any(line.endswith("s, working") for line in lines)
    assert any("enumerate started, 20,000 candidates" in line for line in lines)
    assert any("enumerate: 5,000/20,000 candidates (25 %)" in line for line in lines)
    assert any("enumerate: 10,000/20,000 candidates (50 %)" in line for line in lines)
    starts = [line.split(", ", 1)[1] for line in lines if "started" in line]
    assert starts == ["enumerate started, 20,000 candidates", "select started"]
    assert not any("enumerate" in line for line in lines[lines.index(next(x for x in lines if "select started" in x)):])
    assert len(set(lines)) == len(lines)
    time.sleep(0.15)
    assert len(capsys.readouterr().err.splitlines()) == 0  # stopped


def test_stars_table_fits_80_columns(small_family, monkeypatch, capsys):
    """The stars table at 80 columns: every length whole (no `12.…`), one row per star."""
    import re

    from starforge import load_family
    from starforge.cli.stars import _report

    out, fam = small_family
    import dataclasses

    family = dataclasses.replace(load_family(out / "family.json"), timings={"enumerate": 0.5, "select": 0.5})
    monkeypatch.setenv("COLUMNS", "80")
    _report(family, out, 1.0, quiet=False)
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80
    assert "…" not in text
    rows = [line for line in lines if re.match(r"^\s*\d+\s+\d", line)]
    assert len(rows) == (len(fam["stars"]) if len(fam["stars"]) <= 30 else 25)
    for line, st in zip(rows, fam["stars"], strict=False):
        words = line.split()
        assert words[0] == str(st["id"])
        assert [float(w) for w in words[1:7]] == [round(x, 2) for x in st["lengths"].values()]


def test_pictures_are_framed_and_scaled(small_family, tmp_path):
    """The star preview fills most of its frame, and family.png's scale bar
    is a round length no longer than half the limit's width."""
    from matplotlib.image import imread

    from starforge import load_family
    from starforge.cad.body import BodySpec
    from starforge.cad.export import family_bodies
    from starforge.cad.mounts import load_mount
    from starforge.render.bodies import render_body_png
    from starforge.render.stars import _nice_length

    out, _ = small_family
    family = load_family(out / "family.json")
    (body,) = family_bodies(family, [family.stars[0].id], load_mount("flat"), BodySpec())
    img = imread(render_body_png(body, tmp_path / "b.png"))
    ink = np.argwhere(img[..., :3].min(axis=2) < 0.9)  # not white
    rows = img.shape[0] * 0.1  # below the title
    body_px = ink[ink[:, 0] > rows]
    span = (body_px.max(axis=0) - body_px.min(axis=0)) / np.array(img.shape[:2])
    assert span.max() > 0.7, f"the body spans only {span.max():.0%} of the frame"
    for width, bar in ((6.3, 5.0), (10.4, 10.0), (19.9, 10.0), (25.0, 20.0), (0.9, 0.5)):
        assert _nice_length(width) == bar
