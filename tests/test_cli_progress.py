"""Progress by stage (starforge.runtime.progress) and how the command line shows it."""

from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starforge.cli._progress import Bars, clock_text, count_text, eta_text, stage_text
from starforge.runtime import progress


class Clock:
    """A clock the test moves by hand, s."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Record:
    """A listener that keeps every call."""

    def __init__(self) -> None:
        self.calls: list = []

    def started(self, s):
        self.calls.append(("started", s.name))

    def changed(self, s):
        self.calls.append(("changed", s.name, s.done))

    def ended(self, s):
        self.calls.append(("ended", s.name))

    def note(self, text):
        self.calls.append(("note", text))


@given(
    setup_s=st.floats(0.0, 60.0),
    rate=st.floats(1.0, 1e7),
    chunks=st.integers(3, 40),
    jitter=st.lists(st.floats(0.6, 1.4), min_size=40, max_size=40),
)
def test_eta_is_within_a_factor_of_two_of_the_time_really_left(setup_s, rate, chunks, jitter):
    """A stage whose first count carries a one-off cost (a compile, a first chunk's set-up) and
    whose later chunks each take their size over the rate, +-40 %: from the third count on,
    the estimate is within a factor of 2 of the time the remaining chunks really take."""
    clock = Clock()
    total = chunks * 1000
    s = progress.Stage(None, "enumerate", total, "candidates", clock)
    durations = [1000 / rate * j for j in jitter[:chunks]]
    clock.t = setup_s + durations[0]
    s.update(1000)
    for k in range(1, chunks - 1):
        clock.t += durations[k]
        s.update(advance=1000)
        if k >= 2:
            really_left = sum(durations[k + 1 :])
            eta = s.eta_s()
            assert eta is not None and really_left / 2 <= eta <= 2 * really_left


def test_eta_counts_down_between_counts_and_is_unknown_without_a_rate():
    clock = Clock()
    s = progress.Stage(None, "mesh", 10, "bodies", clock)
    assert s.eta_s() is None and eta_text(s) == ""  # nothing counted yet: no estimate
    clock.t = 1.0
    s.update(1)
    clock.t = 2.0
    s.update(2)  # 1 body/s after the first: 8 s left
    assert s.eta_s() == pytest.approx(8.0)
    clock.t = 5.0
    assert s.eta_s() == pytest.approx(5.0)
    assert eta_text(s) == "about 5 s left"
    u = progress.Stage(None, "select", None, "", clock)
    u.update(5)
    assert u.eta_s() is None


def test_a_counted_out_stage_keeps_its_clock_and_promises_no_time():
    """Past its total a stage wraps up: no "about 1 s left" that never comes, and its clock
    still moves (the screen shows the command is alive)."""
    clock = Clock()
    s = progress.Stage(None, "STEP", 25, "bodies", clock)
    for k, t in ((1, 1.0), (2, 2.0), (25, 25.0)):
        clock.t = t
        s.update(k)
    shown = []
    for t in (25.0, 26.0, 27.5, 3725.0):
        clock.t = t
        shown.append(clock_text(s))
        assert eta_text(s) == ""
    assert shown == ["0:25", "0:26", "0:27", "1:02:05"]


def test_the_bars_go_with_the_last_open_stage():
    bars = Bars()
    with progress.reporting(bars, Clock()):
        a = progress.stage("mesh", 3)
        b = progress.stage("STEP", 3, parallel=True)
        zero = progress.stage("plate", 0)  # ends mesh; a total of 0 is drawn as no total
        assert bars.live is not None and len(bars.tasks) == 2 and a.ended
        assert bars.live.tasks[-1].total is None
        zero.end()
        assert bars.live is not None
        b.end()
        assert bars.live is None and not bars.tasks
        progress.stage("preview", 1)
        assert bars.live is not None
    assert bars.live is None


def test_counts_read_with_separators_and_never_none():
    clock = Clock()
    s = progress.Stage(None, "enumerate", None, "candidates", clock)
    assert count_text(s) == ""  # not "0/None"
    clock.t = 3.0
    assert stage_text(s) == "enumerate: 3 s in"
    s.update(70_778_880, 211_771_560)
    assert count_text(s) == "70,778,880/211,771,560 candidates (33 %)"


def test_a_count_of_one_reads_in_the_singular():
    clock = Clock()
    one = progress.Stage(None, "render", 1, "pictures", clock)
    assert count_text(one) == "0/1 picture (0 %)"
    many = progress.Stage(None, "mesh", None, "bodies", clock)
    many.update(1)
    assert count_text(many) == "1 body"
    many.update(2)
    assert count_text(many) == "2 bodies"


def test_a_stage_ends_the_one_before_unless_it_runs_beside_it():
    rec = Record()
    with progress.reporting(rec, Clock()) as rep:
        mesh = progress.stage("mesh", 3)
        step = progress.stage("STEP", 3, parallel=True)
        assert not mesh.ended  # beside it
        plate = progress.stage("plate", 1)
        assert mesh.ended and not step.ended
        step.update(3)
        step.end()
        progress.note("compiling")
        assert rep.open == [plate]
    assert plate.ended  # the reporter closes what is left
    assert [c[:2] for c in rec.calls] == [
        ("started", "mesh"),
        ("started", "STEP"),
        ("ended", "mesh"),
        ("started", "plate"),
        ("changed", "STEP"),
        ("ended", "STEP"),
        ("note", "compiling"),
        ("ended", "plate"),
    ]
    assert progress.current() is None


def test_a_stage_callback_starts_each_named_stage_once():
    rec = Record()
    with progress.reporting(rec, Clock()):
        cb = progress.report()
        cb("rays", 0, None)
        cb("rays", 5, 10)
        cb("optimise", 1, 4)
        cb("optimise", 2, 4)
    assert [c for c in rec.calls if c[0] == "started"] == [("started", "rays"), ("started", "optimise")]


def test_a_stage_callback_counts_each_stage_in_its_own_unit():
    units = []

    class Units(Record):
        def started(self, st):
            units.append((st.name, st.unit))

    with progress.reporting(Units(), Clock()):
        cb = progress.report({"simulate": "frames", "curve": "noise levels"})
        cb("simulate", 1, 10)
        cb("curve", 1, 8)
        cb("render", 0, 1)
    assert units == [("simulate", "frames"), ("curve", "noise levels"), ("render", "")]


def test_nobody_listening_costs_nothing():
    assert progress.current() is None
    with progress.stage("alone", 2) as s:
        s.update(advance=1)
    progress.note("nobody hears this")
    assert s.done == 1 and s.ended


def _stages(err: str) -> list[str]:
    """The stage names of the 'NAME started' lines, in order."""
    return re.findall(r"^starforge [a-z-]+: \d+ s, (\S+) started", err, flags=re.M)


@pytest.fixture
def no_hold(monkeypatch):
    """Plain progress lines from a command's first moment (a test's commands are short)."""
    from starforge.cli import _progress

    monkeypatch.setattr(_progress, "HOLD_S", 0.0)


def test_a_command_refused_at_once_writes_only_its_error(tmp_path, capsys):
    from conftest import run_cli

    assert run_cli(["stars", "--box", "5,5,5", "--out", tmp_path / "s"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("error: ")


@pytest.mark.slow
def test_quiet_prints_nothing_and_otherwise_stages_come_in_order(tmp_path, capsys, no_hold):
    from conftest import run_cli

    args = ["stars", "--box", "16,12,24", "--delta", "2", "--out", tmp_path / "q"]
    assert run_cli([*args, "-q"]) == 0
    out, err = capsys.readouterr()
    assert out == "" and err == ""
    assert run_cli([*args[:-1], tmp_path / "v"]) == 0
    out, err = capsys.readouterr()
    assert _stages(err) == ["load", "enumerate", "select", "verify"]
    assert "None" not in err
    assert "wrote" in out


@pytest.mark.slow
def test_quiet_before_the_command_and_global_options_after_it(tmp_path, capsys):
    from conftest import run_cli

    args = ["--box", "16", "12", "24", "--delta", "2", "--out", tmp_path / "a"]
    assert run_cli(["-q", "stars", *args, "--max-seconds", "600", "--max-memory", "2G"]) == 0
    out, err = capsys.readouterr()
    assert out == "" and err == ""


def test_check_stages_and_quiet(small_family, tmp_path, capsys, no_hold):
    from conftest import run_cli

    fam, _ = small_family
    args = ["check", fam, "--frames", "300", "--curve", "2", "--out", tmp_path / "c"]
    assert run_cli([*args, "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")
    assert run_cli([*args, "--out", tmp_path / "d"]) == 0
    assert _stages(capsys.readouterr().err) == ["load", "simulate", "curve", "render"]


@pytest.mark.slow
def test_export_stages_and_quiet(small_family, tmp_path, capsys, no_hold):
    from conftest import run_cli

    fam, _ = small_family
    args = ["export", fam, "--format", "stl,3mf", "--ids", "1", "--preview", "--allow-oversize"]
    assert run_cli([*args, "-q", "--out", tmp_path / "q"]) == 0
    assert capsys.readouterr() == ("", "")
    assert run_cli([*args, "--out", tmp_path / "v"]) == 0
    assert _stages(capsys.readouterr().err) == ["load", "mesh", "plate", "preview", "sheet"]


@pytest.mark.parametrize("compiled", [False, True])
def test_a_first_placement_says_once_that_it_compiles(compiled, monkeypatch):
    """A placement whose kernels are not in this machine's cache says so in a note before its
    first stage; one that loads them says nothing."""
    from starforge.props import placement
    from starforge.runtime.kernels import FIRST_RUN_NOTE, compiled_here

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    assert compiled_here(object())  # not a kernel: in doubt, nothing is said
    monkeypatch.setattr(placement, "kernels_compiled", lambda: compiled)
    monkeypatch.setattr(placement, "prepare", stop)  # the work itself is not needed
    rec = Record()
    with progress.reporting(rec, Clock()), pytest.raises(Stop):
        placement.run_placement("hammer")
    notes = [c for c in rec.calls if c[0] == "note"]
    assert notes == ([] if compiled else [("note", FIRST_RUN_NOTE)])
    assert ("started", "sites") in rec.calls
    if notes:
        assert rec.calls.index(notes[0]) < rec.calls.index(("started", "sites"))
