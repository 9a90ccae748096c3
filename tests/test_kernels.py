"""Kernels cached by the package's contents, and the kernels a wheel ships built (starforge.runtime.kernels):
the digest follows the code and nothing else, a shipped zip is unpacked only when it matches this
installation (never half, never a foreign or broken one), and kernels built in one folder load in
another copy of the same sources without compiling, while an edit makes them compile."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from starforge.runtime import kernels

ROOT = Path(__file__).resolve().parents[1]

PROBE = """
from starforge.runtime.kernels import numba


@numba.njit(cache=True)
def twice(x):
    return 2.0 * x


def build():
    twice(1.5)
"""


def _copy_package(dest: Path) -> Path:
    pkg = dest / "starforge"
    shutil.copytree(ROOT / "starforge", pkg, ignore=shutil.ignore_patterns("__pycache__", "kernels.zip"))
    return pkg


def test_digest_follows_the_code_not_its_place(tmp_path):
    a, b = _copy_package(tmp_path / "a"), _copy_package(tmp_path / "b")
    d = kernels.digest(str(a))
    assert d == kernels.digest(str(b)) == kernels.digest(kernels.PACKAGE_DIR)
    # bytecode, data and the templates package do not count
    (b / "__pycache__").mkdir()
    (b / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"\0")
    (b / "kernels.zip").write_bytes(b"zip")
    (b / "templates").mkdir()
    (b / "templates" / "__init__.py").write_text("")
    kernels.digest.cache_clear()
    assert kernels.digest(str(b)) == d
    # one byte of code does, and so does a file's name
    f = b / "stars" / "rules.py"
    f.write_bytes(f.read_bytes() + b"\n")
    kernels.digest.cache_clear()
    assert kernels.digest(str(b)) != d
    f.write_bytes(f.read_bytes()[:-1])
    (b / "stars" / "rules.py").rename(b / "stars" / "rules2.py")
    kernels.digest.cache_clear()
    assert kernels.digest(str(b)) != d
    kernels.digest.cache_clear()


def _zip(path: Path, manifest: dict | None, files: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        if manifest is not None:
            z.writestr("manifest.json", json.dumps(manifest))
        for name, data in files.items():
            z.writestr(name, data)
    return path


def _here() -> dict:
    return kernels.manifest()


def test_seed_unpacks_a_matching_zip_whole_and_once(tmp_path):
    files = {"stars/a.nbi": b"index", "stars/a.1.nbc": b"code", "geometry/b.nbi": b"other"}
    z = _zip(tmp_path / "k.zip", _here(), files)
    target = tmp_path / "cache" / "starforge-x"
    assert kernels._seed(str(z), str(target))
    assert {
        p.relative_to(target).as_posix(): p.read_bytes() for p in target.rglob("*") if p.is_file()
    } == files
    # a second process finds the folder there: it unpacks nothing and leaves no temporary folder
    (target / "stars" / "a.nbi").write_bytes(b"newer")
    assert not kernels._seed(str(z), str(target))
    assert (target / "stars" / "a.nbi").read_bytes() == b"newer"
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == ["starforge-x"]


@pytest.mark.parametrize(
    "case",
    ["no zip", "other numba", "other digest", "other python", "no manifest", "corrupt", "escaping path"],
)
def test_seed_unpacks_nothing_that_does_not_match(tmp_path, case):
    z = tmp_path / "k.zip"
    man = _here()
    files = {"stars/a.nbi": b"index"}
    if case == "other numba":
        man["numba"] = "0.1.0"
    elif case == "other digest":
        man["digest"] = "0" * 16
    elif case == "other python":
        man["python"] = "2.7"
    elif case == "escaping path":
        files = {"../outside.nbi": b"x"}
    if case == "corrupt":
        z.write_bytes(b"PK\x03\x04 not a zip")
    elif case != "no zip":
        _zip(z, None if case == "no manifest" else man, files)
    target = tmp_path / "cache" / "starforge-x"
    assert not kernels._seed(str(z), str(target))
    assert not target.exists()
    assert not (tmp_path / "outside.nbi").exists()
    left = list((tmp_path / "cache").iterdir()) if (tmp_path / "cache").exists() else []
    assert left == []  # no half-unpacked temporary folder


def _py(pythonpath: Path, cache: Path, code: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
    env.update(PYTHONPATH=str(pythonpath), STARFORGE_CACHE_DIR=str(cache))
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=pythonpath
    )
    assert res.returncode == 0, res.stderr
    return res.stdout


STATS = (
    "import starforge, starforge._probe as p; p.build(); s = p.twice.stats; "
    "print(starforge.__file__, sum(s.cache_hits.values()), sum(s.cache_misses.values()))"
)


@pytest.mark.slow
def test_kernels_built_in_one_copy_load_in_another_without_compiling(tmp_path):
    """What ``pip install .`` relies on: kernels built in the wheel's build folder (here copy a)
    load in the installed copy (b), from a fresh user cache, with no compile; an edited copy (c)
    unpacks nothing and compiles."""
    pkgs = [_copy_package(tmp_path / n) for n in "abc"]
    for pkg in pkgs:
        (pkg / "_probe.py").write_text(PROBE)
    (pkgs[2] / "_probe.py").write_text(PROBE + "\n# edited\n")
    zip_path = pkgs[0] / "kernels.zip"
    _py(
        tmp_path / "a",
        tmp_path / "build-cache",
        f"from starforge.runtime.kernels import prebuild; prebuild({str(zip_path)!r}, ('starforge._probe:build',))",
    )
    with zipfile.ZipFile(zip_path) as z:
        names = z.namelist()
        assert json.loads(z.read("manifest.json"))["digest"] == kernels.digest(str(pkgs[0]))
    assert any(n.startswith("_probe.twice") and n.endswith(".nbc") for n in names), names
    for pkg in pkgs[1:]:
        shutil.copy(zip_path, pkg / "kernels.zip")

    where, hits, misses = _py(tmp_path / "b", tmp_path / "user-b", STATS).split()
    assert Path(where).parent == pkgs[1]
    assert (int(hits), int(misses)) == (1, 0)  # loaded, not compiled
    assert len(list((tmp_path / "user-b").rglob("_probe.twice*.nbc"))) == 1

    where, hits, misses = _py(tmp_path / "c", tmp_path / "user-c", STATS).split()
    assert Path(where).parent == pkgs[2]
    assert (int(hits), int(misses)) == (0, 1)  # other code: compiled
    # and cached for the next run of that code
    assert _py(tmp_path / "c", tmp_path / "user-c", STATS).split()[1:] == ["1", "0"]


def test_starforge_kernels_are_cached_under_the_digest_folder_only():
    from numba.core import caching

    from starforge.geometry.sym3 import sym3_eigvals

    assert kernels._install() and kernels._install()  # idempotent
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    assert impl._locator_classes.count(kernels._Locator) == 1
    path = Path(sym3_eigvals._cache.cache_path)
    assert path == Path(kernels.kernel_dir()) / "geometry"
    assert path.parent.name == f"starforge-{kernels.digest()}"
    # a function outside the package is left to numba's own locators
    assert kernels._Locator.from_function(test_digest_follows_the_code_not_its_place, __file__) is None


def test_a_cache_entry_that_cannot_be_written_leaves_the_kernel_uncached():
    """A full disk or a read-only cache folder while a kernel's entry is saved: the command goes
    on (the kernel stays compiled in memory); any other error still ends it."""
    import contextlib
    import errno

    from numba.core import caching

    import starforge.runtime.kernels  # noqa: F401  (puts the guard in place)

    class Saving:
        def __init__(self, err):
            self.err = err

        def _guard_against_spurious_io_errors(self):
            return contextlib.nullcontext()

        def _save_overload(self, sig, data):
            raise self.err

    for code in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS, errno.EACCES):
        caching.Cache.save_overload(Saving(OSError(code, "cannot write")), None, None)
    with pytest.raises(OSError, match="input/output"):
        caching.Cache.save_overload(Saving(OSError(errno.EIO, "input/output error")), None, None)


def test_prefetch_is_a_hint_that_changes_no_value():
    """A compiled loop that prefetches the rows it reaches ahead reads and writes exactly what
    the same loop does without it (numpy's sums as the independent check); rows past the end
    are never asked for."""
    import numpy as np

    @kernels.numba.njit
    def bump(a, flat, idx, ahead):
        for k in range(len(idx)):
            if ahead and k + ahead < len(idx):
                kernels.prefetch(a, idx[k + ahead])
                kernels.prefetch(flat, idx[k + ahead])
            a[idx[k], 0] += 1
            a[idx[k], 1] += idx[k]
            flat[idx[k]] += 1

    rng = np.random.default_rng(3)
    idx = rng.integers(0, 5000, 20000)
    want = np.zeros((5000, 2), dtype=np.int64)
    np.add.at(want[:, 0], idx, 1)
    np.add.at(want[:, 1], idx, idx)
    for ahead in (0, 1, 16):
        got = np.zeros((5000, 2), dtype=np.int64)
        flat = np.zeros(5000, dtype=np.int32)
        bump(got, flat, idx, ahead)
        assert np.array_equal(got, want) and np.array_equal(flat, want[:, 0])
