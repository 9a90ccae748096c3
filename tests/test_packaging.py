"""A plain (non-editable) `pip install .` gets every module, the templates and the kernels built
ahead of time: a wheel built here carries them, and a first `stars` run from it compiles nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed():
    """Each folder of the package with an ``__init__.py`` is named in pyproject's package list
    (an unlisted one is silently left out of the wheel)."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "starforge").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert found and found <= listed, sorted(found - listed)


# a first run that reports every kernel it compiles (numba's compile event is not sent for a
# kernel loaded from the cache); the command may leave with os._exit, so each is written at once
FIRST_RUN = (
    "import sys\n"
    "from numba.core import event\n"
    "class Seen(event.Listener):\n"
    "    def on_start(self, ev):\n"
    "        sys.stderr.write('COMPILED %s\\n' % ev.data.get('dispatcher'))\n"
    "        sys.stderr.flush()\n"
    "    def on_end(self, ev):\n"
    "        pass\n"
    "event.register('numba:compile', Seen())\n"
    "from starforge.cli import main\n"
    "main(sys.argv[1:])\n"
)


@pytest.mark.slow
def test_wheel_carries_code_templates_and_built_kernels(tmp_path):
    pytest.importorskip("setuptools")
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    (whl,) = tmp_path.glob("starforge-*.whl")
    names = set(zipfile.ZipFile(whl).namelist())
    shipped = sorted(p.relative_to(ROOT / "templates").as_posix() for p in (ROOT / "templates").rglob("*.toml"))
    assert shipped, "no templates in the source tree"
    for rel in shipped:
        assert f"starforge/templates/{rel}" in names
        # and each shipped template is valid TOML
        tomllib.loads(zipfile.ZipFile(whl).read(f"starforge/templates/{rel}").decode())
    code = {p.relative_to(ROOT).as_posix() for p in (ROOT / "starforge").rglob("*.py") if "__pycache__" not in p.parts}
    assert code and code <= names, sorted(code - names)
    assert "starforge/kernels.zip" in names

    # installed (unpacked) beside nothing else, with a fresh user cache: the finger default
    # loads every kernel from the shipped zip and compiles none
    site = tmp_path / "site"
    zipfile.ZipFile(whl).extractall(site)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
    env.update(PYTHONPATH=str(site), STARFORGE_CACHE_DIR=str(tmp_path / "cache"))
    res = subprocess.run(
        [sys.executable, "-c", FIRST_RUN, "stars", "--out", str(tmp_path / "out"), "-q"],
        env=env, capture_output=True, text=True, cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert "COMPILED" not in res.stderr, res.stderr
    assert json.loads((tmp_path / "out" / "family.json").read_text())["summary"]["size"] > 0
    # and so does the built-in hammer's placement
    res = subprocess.run(
        [sys.executable, "-c", FIRST_RUN, "place", "--out", str(tmp_path / "hammer"), "-q"],
        env=env, capture_output=True, text=True, cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert "COMPILED" not in res.stderr, res.stderr
    assert (tmp_path / "hammer" / "placement.json").exists()
    from starforge.runtime.kernels import digest

    assert [p.name for p in (tmp_path / "cache" / "numba").iterdir()] == [f"starforge-{digest(str(site / 'starforge'))}"]

    # a wheel built without them carries none, though the build folder still holds the last zip
    plain = tmp_path / "plain"
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q", "-w", str(plain)],
        capture_output=True, text=True, env=dict(os.environ, STARFORGE_PREBUILD="0"),
    )
    assert res.returncode == 0, res.stderr
    (whl,) = plain.glob("starforge-*.whl")
    assert "starforge/kernels.zip" not in zipfile.ZipFile(whl).namelist()


def test_templates_resolve_through_the_package():
    from starforge.catalog import KINDS, list_templates, load_template

    for kind in KINDS:
        for name in list_templates(kind):
            assert load_template(kind, name)[0] == name
    assert "finger" in list_templates("stars") and "limb" in list_templates("stars")
