"""The templates ship inside the package, so a plain (non-editable) `pip install .` finds them."""

from __future__ import annotations

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed():
    """Each folder of the package with an ``__init__.py`` is named in pyproject's package list
    (an unlisted one is left out of the wheel: ``tracking.formats`` once was)."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "starforge").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert found and found <= listed, sorted(found - listed)


@pytest.mark.slow
def test_wheel_carries_every_template(tmp_path):
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
    assert "starforge/cli/__init__.py" in names


def test_templates_resolve_through_the_package():
    from starforge.catalog import KINDS, list_templates, load_template

    for kind in KINDS:
        for name in list_templates(kind):
            assert load_template(kind, name)[0] == name
    assert "finger" in list_templates("stars") and "limb" in list_templates("stars")
