"""Shared fixtures.  Tests write only under tmp_path / tmp_path_factory."""

from __future__ import annotations

import json
import os
import re

import pytest
from hypothesis import HealthCheck, settings

from starforge.cli import main

# One fixed hypothesis profile: the same examples on every run and machine (derandomize), no
# example database carried between runs, no wall-clock deadlines on a loaded CI machine.
settings.register_profile(
    "ci",
    derandomize=True,
    database=None,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

FINGER = ["--box", "20.8", "12.6", "48.3", "--marker", "4", "--delta", "1.5"]


@pytest.fixture(autouse=True)
def _no_progress_lines(monkeypatch):
    """In-process commands write no plain progress lines (however slow the machine), so that a
    test sees only what the command says; a test of the progress lines sets HOLD_S itself."""
    from starforge.cli import _progress

    monkeypatch.setattr(_progress, "HOLD_S", float("inf"))


def run_cli(args: list[str]) -> int:
    """Run the CLI in-process; returns the exit code."""
    return main([str(a) for a in args])


@pytest.fixture(scope="session")
def finger_face(tmp_path_factory):
    """The paper's finger case under the face rule, written by the CLI (path, parsed JSON)."""
    out = tmp_path_factory.mktemp("finger_face")
    assert run_cli(["stars", *FINGER, "--rule", "face", "--out", out, "-q"]) == 0
    return out, json.loads((out / "family.json").read_text())


@pytest.fixture(scope="session")
def finger_pair(tmp_path_factory):
    """The paper's finger case under the paper's pair rule, written by the CLI."""
    out = tmp_path_factory.mktemp("finger_pair")
    assert run_cli(["stars", *FINGER, "--rule", "pair", "--out", out, "-q"]) == 0
    return out, json.loads((out / "family.json").read_text())


@pytest.fixture(scope="session")
def small_family(tmp_path_factory):
    """A small family (fast): 16 x 12 x 24 mm, 4 mm markers, delta 2 mm."""
    out = tmp_path_factory.mktemp("small")
    assert run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--out", out, "-q"]) == 0
    return out, json.loads((out / "family.json").read_text())


@pytest.fixture
def cli_error(capsys):
    """Run the CLI on args that must fail: exit code 2 and one ``error:`` line on stderr, no
    traceback; returns that line."""

    def run(args) -> str:
        capsys.readouterr()
        rc = main([str(a) for a in args])
        lines = capsys.readouterr().err.strip().splitlines()
        err = "\n".join(x for x in lines if not re.match(r"starforge \S+: \d+ s", x))  # heartbeat
        assert rc == 2, err
        assert err.startswith("error:") and "\n" not in err and "Traceback" not in err
        return err

    return run
