"""Helper processes belong to their command: registered, ended with it, never writing into a
stage folder that their command removed."""

from __future__ import annotations

import os
import signal
import time

import pytest

from starforge.io import atomic_write_bytes, staged_output
from starforge.runtime import procs


def _alive(pid: int) -> bool:
    """Running (a zombie waiting to be reaped counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_the_atomic_writer_never_recreates_a_removed_stage(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with staged_output(tmp_path / "out") as stage:
            atomic_write_bytes(stage / "placement.json", b"{}")
            raise KeyboardInterrupt
    for late in (stage / "guide.pdf", stage / "sub" / "guide.pdf"):
        with pytest.raises(FileNotFoundError):
            atomic_write_bytes(late, b"drawn too late")
    assert list(tmp_path.iterdir()) == []
    # an ordinary missing folder is still made
    atomic_write_bytes(tmp_path / "a" / "b" / "c.txt", b"x")
    assert (tmp_path / "a" / "b" / "c.txt").read_bytes() == b"x"


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_end_children_ends_a_helper_group_with_its_grandchildren(tmp_path):
    r, w = os.pipe()
    pid = procs.fork_helper(group=True)
    if pid == 0:  # the helper: fork a grandchild into its group, report it, then sleep
        try:
            os.close(r)
            kid = procs.fork_helper()
            if kid == 0:
                os.close(w)
                time.sleep(60)
                os._exit(0)
            os.write(w, str(kid).encode())
            os.close(w)
            time.sleep(60)
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r) as fh:
        grandchild = int(fh.read())
    assert procs._children == {pid: True}
    assert _alive(pid) and _alive(grandchild)
    procs.end_children()
    os.waitpid(pid, 0)
    procs.release(pid)
    deadline = time.monotonic() + 5
    while _alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _alive(grandchild)
    assert procs._children == {}


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_forked_helper_dies_with_its_parent(tmp_path):
    """A helper whose parent is killed outright (SIGKILL: no clean-up runs) does not live on."""
    r, w = os.pipe()
    mid = os.fork()
    if mid == 0:  # the "command": forks a helper, reports it, waits to be killed
        try:
            os.close(r)
            kid = procs.fork_helper()
            if kid == 0:
                os.close(w)
                time.sleep(60)
                os._exit(0)
            os.write(w, str(kid).encode())
            os.close(w)
            time.sleep(60)
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r) as fh:
        helper = int(fh.read())
    os.kill(mid, signal.SIGKILL)
    os.waitpid(mid, 0)
    deadline = time.monotonic() + 5
    while _alive(helper) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _alive(helper)
