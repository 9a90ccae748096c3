"""Every refusal of the hostile-input suite names what to change and how: its one line names the
option or argument involved (``--box``, the file given, the environment variable) and a remedy
(an option to change, a command to run, a range or a form to use)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from starforge.cli._args import GLOBAL_VALUES as GLOBAL_OPTIONS
from tests import test_hostile_inputs as inputs
from tests import test_hostile_readers as readers
from tests.conftest import run_cli
from tests.test_hostile_inputs import files  # noqa: F401  (the suite's fixture of hostile files)
from tests.test_hostile_readers import tracker_files  # noqa: F401  (and of hostile tracker files)

#: words that tell the user what to do: an option or command to use, a range, a form, a limit
REMEDY = re.compile(
    r"--[a-z]|starforge [a-z]|`[a-z]|\bmust\b|\bneeds?\b|\bexpected\b|\bat most\b|\bat least\b|\bin \[|"
    r"\bwithin\b|\bone of\b|\bknown\b|\be\.g\.|\buse\b|\bpass\b|\blower\b|\braise\b|\bgive\b|\bcheck\b|"
    r"\bsave\b|\bconvert\b|\bwrite\b|\bremove\b|\bfix\b|\bis outside\b|\bonly\b|\bfrom \d|\bsupported\b",
    re.I,
)


def named(args: tuple, env: dict, line: str) -> bool:
    """The line names an option of the command (``--delta``, ``--units``), a value given in the
    place of an argument (a file by its name or stem, a prop, a template kind), or an
    environment variable set for the case."""
    from starforge.cli import click_command
    from starforge.cli._args import leaf_command, option_names

    words = [str(a) for a in args]
    cmd, _ = leaf_command(click_command(), words)
    options = option_names(cmd) | set(GLOBAL_OPTIONS)
    values = [Path(w) for w in words if not w.startswith("-") and w not in _COMMANDS]
    return (
        any(re.search(rf"{o}\b", line) for o in options if o.startswith("--"))
        or any(v.name in line or v.stem in line for v in values if v.name)
        or any(k in line for k in env)
    )


def says_the_way_out(case, line: str) -> None:
    """The refusal ``line`` of ``case`` names what the user typed (:func:`named`) and a way out
    (:data:`REMEDY`); the hostile-input matrix checks each of its refusals with this too."""
    assert named(case.args, case.env, line), f"names nothing the user typed: {line}"
    assert REMEDY.search(line), f"no way out: {line}"


_COMMANDS = {"stars", "export", "check", "place", "run", "score", "sweep", "templates", "mounts", "preview",
             "convert", "drawing", "place-batch", "measure"}


def _all_cases(files, tracker_files) -> dict:  # noqa: F811
    cases = [*inputs._cases(files), *readers._cases(tracker_files)]
    return {c.id: c for c in cases if c.code == 2}


_IDS = [c.id for c in inputs._cases({k: Path(k) for k in inputs._FILE_KEYS}) if c.code == 2] + [
    c.id for c in readers._cases({k: Path(k) for k in readers._KEYS}) if c.code == 2
]


@pytest.mark.slow  # every hostile case once more (the suite runs each in process already)
@pytest.mark.parametrize("case_id", _IDS)
def test_a_refusal_names_the_option_and_the_way_out(case_id, files, tracker_files, tmp_path, monkeypatch, capsys):  # noqa: F811
    from starforge.runtime import budget

    case = _all_cases(files, tracker_files)[case_id]
    work = tmp_path / "work"
    work.mkdir()
    args = list(case.args)
    if case.uses_out:
        args += ["--out", str(work / "out")]
    monkeypatch.setenv(budget.ENV_MEMORY, "1G")
    monkeypatch.setenv(budget.ENV_SECONDS, repr(budget.DEFAULT_SECONDS))
    for k, v in case.env.items():
        monkeypatch.setenv(k, v)
    monkeypatch.chdir(work)
    assert run_cli(args) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if not re.match(inputs.PROGRESS, ln)]
    assert len(lines) == 1, lines
    says_the_way_out(case, lines[0])


def test_another_marker_than_the_familys_suggests_a_family_for_it(small_family, tmp_path, capsys):
    """Export with a bought marker of another size: the refusal says which and gives the stars
    command for that marker, with the family's own options, the mount and the seat kept."""
    from starforge.markers import load_marker

    fam, doc = small_family
    marker = "14mm-m4"
    assert abs(load_marker(marker).diameter_mm - doc["spec"]["marker_mm"]) > 1  # the case: another size
    args = ["export", fam, "--marker", marker, "--seat", "screw", "--mount", "flat", "--out", tmp_path / "o"]
    assert run_cli(args) == 2
    line = capsys.readouterr().err.strip()
    said, command = line.split("; make a family for it: ")
    assert f"marker {marker} is 14 mm" in said and "designed for 4 mm" in said
    words = command.split()
    assert words[:2] == ["starforge", "stars"]
    box = [f"{x:g}" for x in doc["spec"]["box_mm"]]
    assert words[words.index("--box") + 1 : words.index("--box") + 4] == box
    for flag, value in (("--marker", marker), ("--mount", "flat"), ("--seat", "screw")):
        assert words[words.index(flag) + 1] == value
    assert not (tmp_path / "o").exists()
