"""Shared fixtures.  Tests write only under tmp_path / tmp_path_factory."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from starforge.cli import main
from starforge.stars.family import make_family
from starforge.stars.model import family_csv
from starforge.stars.spec import spec_from_mapping

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
#: the same spec as FINGER, as the library takes it (mm)
FINGER_SPEC = {"box_mm": [20.8, 12.6, 48.3], "marker_mm": 4.0, "delta_mm": 1.5}


@pytest.fixture(autouse=True)
def _no_progress_lines(monkeypatch):
    """In-process commands write no plain progress lines (however slow the machine), so that a
    test sees only what the command says; a test of the progress lines sets HOLD_S itself."""
    from starforge.cli import _progress

    monkeypatch.setattr(_progress, "HOLD_S", float("inf"))


def run_cli(args: list[str]) -> int:
    """Run the CLI in-process; returns the exit code."""
    return main([str(a) for a in args])


def family_files(out: Path, spec: dict) -> dict:
    """Make a family for ``spec`` (a spec mapping, named "custom" as ``stars --box`` names it) with
    the library and write ``family.json`` and ``family.csv`` into ``out`` as ``stars`` writes
    them; returns the parsed family.json.  ``test_same_spec_same_bytes`` checks that the CLI
    writes the same bytes."""
    family = make_family(spec_from_mapping({"name": "custom", **spec}))
    text = json.dumps(family.to_json(), indent=2) + "\n"
    (out / "family.json").write_text(text, encoding="utf-8")
    (out / "family.csv").write_text(family_csv(family), encoding="utf-8")
    return json.loads(text)


@pytest.fixture(scope="session")
def finger_face(tmp_path_factory):
    """The paper's finger case under the face rule, made by the library once (path, parsed JSON)."""
    out = tmp_path_factory.mktemp("finger_face")
    return out, family_files(out, {**FINGER_SPEC, "rule": "face"})


@pytest.fixture(scope="session")
def finger_pair(tmp_path_factory):
    """The paper's finger case under the paper's pair rule, made by the library once."""
    out = tmp_path_factory.mktemp("finger_pair")
    return out, family_files(out, {**FINGER_SPEC, "rule": "pair"})


@pytest.fixture(scope="session")
def small_family(tmp_path_factory):
    """A small family (fast): 16 x 12 x 24 mm, 4 mm markers, delta 2 mm, made by the library once."""
    out = tmp_path_factory.mktemp("small")
    return out, family_files(out, {"box_mm": [16.0, 12.0, 24.0], "delta_mm": 2.0})


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
