"""Messages name the way out: the option (never a spec-file key) and a command that works, with the
user's other options kept; numbers rounded; no nested parentheses."""

from __future__ import annotations

import io
import re
import shlex
from pathlib import Path

import pytest
from conftest import run_cli

from starforge.cli import main

_KEYS = re.compile(
    r"\b(box_mm|marker_mm|delta_mm|gap_mm|tolerance_mm|min_depth_mm|noise_mm|l_min_mm|l_max_mm)\b"
)


def _error(args, capsys) -> str:
    assert main([str(a) for a in args]) == 2
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.startswith("error: ")]
    assert len(lines) == 1, err
    return lines[0]


def _suggested(line: str) -> list[str]:
    """The arguments of the ``starforge ...`` command a message suggests."""
    m = re.search(r"e\.g\. starforge (.*)$", line)
    assert m, line
    return shlex.split(m.group(1))


def _nesting(text: str) -> int:
    depth = most = 0
    for ch in text:
        depth += ch == "("
        most = max(most, depth)
        depth -= ch == ")"
    return most


def test_a_box_too_small_names_box_and_a_box_that_fits(tmp_path, capsys):
    line = _error(["stars", "--box", "5", "5", "5", "--marker", "4", "--out", tmp_path / "a", "-q"], capsys)
    assert "--box" in line and not _KEYS.search(line) and _nesting(line) <= 1
    args = _suggested(line)
    assert args[:1] == ["stars"] and "--marker" in args and "-q" in args  # the user's options kept
    assert run_cli(args) == 0 and (tmp_path / "a" / "family.json").is_file()  # it works


def test_a_suggested_command_keeps_a_quiet_flag_once_where_it_was_typed(tmp_path, capsys):
    line = _error(["-q", "stars", "--box", "5", "5", "5", "--out", tmp_path / "a"], capsys)
    args = _suggested(line)
    assert args[:2] == ["-q", "stars"] and args.count("-q") == 1, args


def test_a_box_too_small_for_a_catalogue_marker_keeps_the_marker(tmp_path, capsys):
    line = _error(["stars", "--box", "5,5,5", "--marker", "14mm-m4", "--out", tmp_path / "b"], capsys)
    assert "--box" in line and "--marker" in line and not _KEYS.search(line)
    assert "--marker 14mm-m4" in " ".join(_suggested(line))


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--delta", "-1"], "--delta"),
        (["--noise", "-1"], "--noise"),
        (["--gap", "-2"], "--gap"),
        (["--tolerance", "100"], "--tolerance"),
        (["--min-depth", "40"], "--min-depth"),
    ],
)
def test_spec_refusals_name_the_option_not_the_key(args, option, tmp_path, capsys):
    line = _error(["stars", "--box", "20.8", "12.6", "48.3", *args, "--out", tmp_path / "c"], capsys)
    assert option in line and not _KEYS.search(line)


def test_seat_without_mount_suggests_the_same_command_with_a_mount(tmp_path, capsys):
    from starforge.cli import click_command
    from starforge.cli._args import normalise

    line = _error(
        ["stars", "--box", "20.8,12.6,48.3", "--seat", "screw", "--delta", "2", "--out", tmp_path], capsys
    )
    assert "--seat" in line and "--mount" in line
    args = _suggested(line)
    assert args[args.index("--delta") + 1] == "2" and "--mount" in args and "--seat" in args
    root = click_command()
    ctx = root.commands["stars"].make_context("stars", normalise(root, args, {})[1:])  # it parses
    assert ctx.params["mount"] == "flat" and ctx.params["seat"] == "screw"


def _box_stl(path, extents):
    import trimesh

    trimesh.creation.box(extents=extents).export(path)
    return path


@pytest.mark.parametrize(
    ("extents", "units", "want"),
    [
        ((1020, 80, 80), "m", "--units mm"),  # an umbrella in mm read as metres: too large to load
        ((300, 30, 30), "m", "--units mm"),  # a torch in mm read as metres: larger than the volume
        ((30, 3, 3), "m", "--units cm"),  # a torch in cm read as metres
        ((0.3, 0.03, 0.03), "mm", "--units m"),  # a torch in metres read as mm: smaller than 4 markers
    ],
)
def test_units_check_names_the_units_option_in_every_case(extents, units, want, tmp_path, capsys):
    stl = _box_stl(tmp_path / "prop.stl", extents)
    line = _error(["place", stl, "--units", units, "--out", tmp_path / "p"], capsys)
    assert want in line
    assert not (tmp_path / "p").exists()


def test_set_names_a_wrong_key_and_takes_a_metric_hole(capsys, tmp_path):
    from starforge.cad.describe import parse_sets
    from starforge.errors import StarforgeError
    from starforge.markers import CLEARANCE_HOLES_MM

    with pytest.raises(StarforgeError, match=r"mount flat has no parameter hole; its parameters: .*hole_mm"):
        parse_sets(["hole=M3"], "flat")
    with pytest.raises(StarforgeError, match=r"needs a number in mm or a metric screw size such as M3"):
        parse_sets(["hole_mm=abc"], "flat")
    with pytest.raises(StarforgeError, match=r"holes needs a number in mm; got 'M3'"):
        parse_sets(["holes=M3"], "flat")
    assert parse_sets(["hole_mm=M3", "holes=2"], "flat") == {
        "hole_mm": CLEARANCE_HOLES_MM["M3"],
        "holes": 2.0,
    }
    assert CLEARANCE_HOLES_MM["M3"] > 3.0  # a clearance hole is wider than the screw


def test_thread_words_say_which_drill_and_insert():
    from starforge.markers import THREADS, thread_words

    for size, th in THREADS.items():
        assert f"{th.tap_drill_mm:g} mm tap-drill" in thread_words(size, "screw")
        assert f"{th.insert_hole_mm:g} mm hole" in thread_words(size, "insert")
        assert th.tap_drill_mm < float(size[1:]) < th.insert_hole_mm  # drill under the thread, insert over it


def test_an_oversize_refusal_keeps_the_marker_the_user_chose(small_family):
    from starforge.cad.describe import stars_command_for
    from starforge.stars.model import load_family

    fam, _ = small_family
    spec = load_family(fam / "family.json").spec
    cmd = stars_command_for(spec, "flat", "14mm-m4", "screw")
    assert "--marker 14mm-m4" in cmd and "--seat screw" in cmd and "--mount flat" in cmd
    assert "--marker 4" not in cmd


def test_export_summary_says_the_mount_once(small_family, tmp_path, capsys):
    fam, _ = small_family
    assert (
        run_cli(["export", fam, "--format", "stl", "--ids", "1", "--allow-oversize", "--out", tmp_path]) == 0
    )
    out = capsys.readouterr().out
    assert "1 body with mount flat:" in out and "flat (flat)" not in out
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert f"wrote {len(written)} files to" in out


def test_check_summary_rounds_and_does_not_nest(small_family, tmp_path, capsys):
    fam, _ = small_family
    assert (
        run_cli(["check", fam, "--frames", "200", "--curve", "0", "--match", "1.21776", "--out", tmp_path])
        == 0
    )
    out = capsys.readouterr().out
    assert "match 1.22 mm" in out and "1.21776" not in out
    assert all(_nesting(line) <= 1 for line in out.splitlines()), out


def test_check_summary_names_its_window_without_nesting(small_family, tmp_path, capsys):
    """The window derived from the bodies (its source has a parenthesis of its own) and a single
    picture: every line nests at most one parenthesis, and counts of one read in the singular."""
    fam, doc = small_family
    args = ["check", fam, "--frames", "100", "--curve", "1", "--out", tmp_path]
    assert run_cli(args) == 0
    captured = capsys.readouterr()
    assert "window from the bone tolerance" in captured.out
    assert all(_nesting(line) <= 1 for line in captured.out.splitlines()), captured.out
    assert "1 pictures" not in captured.err and "1 bodies" not in captured.out


def test_star_table_cells_are_whole_on_a_narrow_terminal(small_family):
    from rich.console import Console

    from starforge.cli.stars import _star_table
    from starforge.stars.model import load_family

    fam, doc = small_family
    family = load_family(fam / "family.json")
    buf = io.StringIO()
    _star_table(family, Console(file=buf, width=40, highlight=False))
    text = buf.getvalue()
    assert "…" not in text
    for st in family.stars:
        for x in st.lengths:
            assert f"{x:.2f}" in text


@pytest.mark.parametrize("kind", ["stars", "mounts", "rigs", "place", "presets", "markers"])
def test_an_empty_or_unknown_template_name_leads_with_its_parameter_and_lists_the_known(kind):
    """The refusal starts with the parameter (the CLI puts the option the user typed there), says
    an empty name is empty, and lists every shipped template of the kind (read from the folder
    here) with the command that lists them."""
    import templates
    from starforge.catalog import PARAMETERS, load_template
    from starforge.errors import StarforgeError

    shipped = sorted(p.stem for p in (Path(templates.__file__).parent / kind).glob("*.toml"))
    assert shipped
    for name, says in (("", f"{PARAMETERS[kind]} is empty: give"), (" ", "is empty"), ("nosuch", "got 'nosuch'")):
        with pytest.raises(StarforgeError) as err:
            load_template(kind, name)
        line = str(err.value)
        assert line.startswith(f"{PARAMETERS[kind]} ") and says in line, line
        assert line.endswith(f"known (starforge templates {kind}): {', '.join(shipped)}"), line


def test_a_set_value_out_of_its_range_names_set_and_the_templates_range(small_family, tmp_path, capsys):
    import tomllib

    import templates

    ranges = tomllib.loads((Path(templates.__file__).parent / "mounts" / "flat.toml").read_text())["ranges"]
    lo, hi = ranges["holes"]
    fam = small_family[0] / "family.json"
    for value, says in ((hi + 97, rf"must be in \[{float(lo)}, {float(hi)}\], got {float(hi + 97)}"),
                        ("nan", "must be finite")):
        line = _error(["export", fam, "--mount", "flat", "--set", f"holes={value}", "--format", "stl",
                       "--allow-oversize", "--out", tmp_path / "o"], capsys)
        assert re.match(rf"error: --set holes {says}", line), line
        assert "starforge mounts flat" in line
    assert not (tmp_path / "o").exists()
