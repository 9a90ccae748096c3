"""Outputs appear all or nothing; every limit is estimated and refused in one line."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from starforge.errors import StarforgeError
from starforge.io import check_input_file, check_name, check_writable, publish, staged_output
from starforge.runtime import budget


def _tree(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_new_folder_appears_whole(tmp_path):
    out = tmp_path / "a" / "b"
    with staged_output(out) as stage:
        (stage / "x.txt").write_text("x")
        (stage / "sub").mkdir()
        (stage / "sub" / "y.txt").write_text("y")
        assert not out.exists()
    assert _tree(out) == {"sub/y.txt": b"y", "x.txt": b"x"}
    assert [p.name for p in tmp_path.rglob("*staging*")] == []


def test_failure_inside_leaves_nothing(tmp_path):
    out = tmp_path / "new"
    with pytest.raises(KeyboardInterrupt), staged_output(out) as stage:
        (stage / "x.txt").write_text("x")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_directory_in_the_way_is_refused_before_anything_moves(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "family.csv").write_text("old csv")
    (out / "run.json").mkdir()  # a folder where a file must go
    before = _tree(out)
    with pytest.raises(StarforgeError, match="is a folder where an output file goes"):
        with staged_output(out, force=True) as stage:
            (stage / "family.csv").write_text("new")
            (stage / "run.json").write_text("{}")
    assert _tree(out) == before and (out / "run.json").is_dir()


def test_failed_move_rolls_back_every_file(tmp_path, monkeypatch):
    out = tmp_path / "run"
    out.mkdir()
    for n in ("a", "b", "c"):
        (out / n).write_text(f"old {n}")
    (out / "keep").write_text("other")
    before = _tree(out)
    stage = tmp_path / "stage"
    stage.mkdir()
    for n in ("a", "b", "c"):
        (stage / n).write_text(f"new {n}")
    real = os.replace
    calls = {"n": 0}

    def flaky(src, dst):
        calls["n"] += 1
        if calls["n"] == 4:  # a's backup, a in, b's backup, then b in fails
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", flaky)
    with pytest.raises(OSError):
        publish(stage, out, force=True)
    monkeypatch.setattr(os, "replace", real)
    assert _tree(out) == before


def test_force_replaces_only_the_named_files(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "a").write_text("old")
    (out / "mine.txt").write_text("user file")
    with pytest.raises(StarforgeError, match="--force"):
        with staged_output(out) as stage:
            (stage / "a").write_text("new")
    with staged_output(out, force=True) as stage:
        (stage / "a").write_text("new")
    assert _tree(out) == {"a": b"new", "mine.txt": b"user file"}


def test_unwritable_place_is_found_before_the_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(StarforgeError, match="not a folder"):
        check_writable(blocker / "out", ["a"], False)
    if os.path.isdir("/proc/self"):
        with pytest.raises(StarforgeError, match="cannot write"):
            check_writable("/proc/self/starforge-out", ["a"], False)


def _in_the_way(tmp_path: Path, fault: str) -> tuple[Path, str]:
    """An output folder path with ``fault`` in its way, and what the refusal calls the obstacle."""
    (tmp_path / "file").write_text("the user's")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    return {
        "is-a-file": (tmp_path / "file", "is a file, not a folder"),
        "under-a-file": (tmp_path / "file" / "sub" / "out", "file is a file, not a folder"),
        "a-looping-link": (tmp_path / "loop", "is a symbolic link that loops or leads nowhere"),
        "under-a-looping-link": (tmp_path / "loop" / "out", "loop is a symbolic link"),
        "under-a-device": (Path("/dev/null/out"), "/dev/null is a device, not a folder"),
    }[fault]


@pytest.mark.parametrize("fault", ["is-a-file", "under-a-file", "a-looping-link", "under-a-looping-link",
                                   "under-a-device"])
def test_an_output_folder_in_the_way_is_one_line_naming_out(tmp_path, fault):
    """The check before the work and the stage itself refuse alike: the path, what is in its
    way, and ``--out`` to give a folder; nothing is created anywhere."""
    out, says = _in_the_way(tmp_path, fault)
    before = sorted(p.name for p in tmp_path.iterdir())
    for attempt in (lambda: check_writable(out, ["a"], False), lambda: staged_output(out).__enter__()):
        with pytest.raises(StarforgeError, match=r"give --out a folder path") as err:
            attempt()
        assert str(out) in str(err.value) and says in str(err.value)
        assert "\n" not in str(err.value)
        assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("bad", ["../x", "a/b", ".hidden", "", "-x", "x" * 101, "a\\b", "a b"])
def test_names_cannot_leave_the_output_folder(bad):
    with pytest.raises(StarforgeError, match="must be 1-100 letters"):
        check_name(bad)


def test_input_files_say_what_is_wrong(tmp_path):
    with pytest.raises(StarforgeError, match="not found"):
        check_input_file(tmp_path / "nope.json", "family")
    with pytest.raises(StarforgeError, match="is a folder"):
        check_input_file(tmp_path, "family")
    if os.path.exists("/dev/null"):
        with pytest.raises(StarforgeError, match="not a regular file"):
            check_input_file("/dev/null", "spec file")
    (tmp_path / "empty.toml").write_text("")
    with pytest.raises(StarforgeError, match="is empty"):
        check_input_file(tmp_path / "empty.toml", "spec file")


def test_sizes_parse_and_print():
    assert budget.parse_bytes("2G") == 2 * 1024**3
    assert budget.parse_bytes("1500M") == 1500 * 1024**2
    assert budget.parse_bytes("1.5GiB") == int(1.5 * 1024**3)
    for bad in ("lots", "-2G", "2X", "1K", "nan"):
        with pytest.raises(StarforgeError):
            budget.parse_bytes(bad)
    assert budget.format_bytes(17.6 * 1024**3) == "17.6 GiB"
    assert budget.format_seconds(1e20).endswith("years")


def test_limits_come_from_the_environment(monkeypatch):
    monkeypatch.setenv(budget.ENV_MEMORY, "1G")
    assert budget.memory_limit_bytes() == 1024**3
    budget.require_memory(0.9 * 1024**3, "x", "y")
    with pytest.raises(StarforgeError, match=r"needs about 9 PiB .* limit of 1 GiB .*lower the scale"):
        budget.require_memory(9 * 1024**5, "the mesh", "lower the scale")
    with pytest.raises(StarforgeError):
        budget.require_memory(float("nan"), "x", "y")
    monkeypatch.setenv(budget.ENV_SECONDS, "60")
    with pytest.raises(StarforgeError, match="would take about .* years"):
        budget.require_time(1e20 * 1e-4, "1e20 frames", "lower --frames")
    monkeypatch.delenv(budget.ENV_MEMORY)
    assert 0 < budget.memory_limit_bytes() <= budget.machine_memory_bytes()
    with pytest.raises(StarforgeError, match="ghosts must be at most"):
        budget.require_count("ghosts", 1e6, 50)


@pytest.mark.parametrize("make", ["stage", "scratch"])
def test_an_interrupt_while_the_folder_is_made_leaves_no_folder(tmp_path, monkeypatch, make):
    """A Ctrl-C that lands just after the folder exists, before the code that owns it has its
    name, still removes it."""
    from starforge.io import scratch_folder, staged_output

    real_mkdir = Path.mkdir

    def mkdir_then_interrupt(self, *args, **kwargs):
        real_mkdir(self, *args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(Path, "mkdir", mkdir_then_interrupt)
    folder = staged_output(tmp_path / "o") if make == "stage" else scratch_folder("scratch-", tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with folder:
            pass
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []



@pytest.mark.parametrize("before", [None, ("3G", "100", "")], ids=["unset", "set"])
def test_a_commands_limits_do_not_outlive_it(before, tmp_path, monkeypatch, capsys):
    """``--max-memory``, ``--max-seconds`` and ``--scheduler`` hold for their command only: a
    program that calls the CLI again (a notebook, the tests) gets the environment it had."""
    from starforge.cli import main
    from starforge.runtime.engine import ENV_SCHEDULER

    for k, key in enumerate((budget.ENV_MEMORY, budget.ENV_SECONDS, ENV_SCHEDULER)):
        if before is None:
            monkeypatch.delenv(key, raising=False)
        else:
            monkeypatch.setenv(key, before[k])
    env = {k: os.environ.get(k) for k in (budget.ENV_MEMORY, budget.ENV_SECONDS, ENV_SCHEDULER)}
    args = ["--max-memory", "1G", "--max-seconds", "5", "stars", "--box", "14", "10", "30", "--delta", "2",
            "--count", "2", "--out", tmp_path / "o", "-q"]
    assert main([str(a) for a in args]) == 0
    assert main(["--max-memory", "1G", "stars", "--delta", "-1"]) == 2  # a refusal, too
    capsys.readouterr()
    assert {k: os.environ.get(k) for k in env} == env
