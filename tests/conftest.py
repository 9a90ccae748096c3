"""Shared fixtures.  Tests write only under tmp_path / tmp_path_factory."""

from __future__ import annotations

import json
import os

import pytest
from hypothesis import HealthCheck, settings

from starforge.cli import main

# One fixed hypothesis profile: the same examples on every run and machine (derandomize), a fixed
# number of them (a test's own @settings may ask for fewer or more), no example database carried
# between runs, no wall-clock deadlines on a loaded CI machine.  Loaded unless HYPOTHESIS_PROFILE
# names another.
settings.register_profile(
    "ci",
    derandomize=True,
    max_examples=100,
    database=None,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

FINGER = ["--box", "20.8", "12.6", "48.3", "--marker", "4", "--delta", "1.5"]


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
