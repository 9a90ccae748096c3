"""Where starforge's compiled kernels are cached, and the kernels a wheel ships already built.

Every module with numba kernels imports numba from here (``from starforge.runtime.kernels import
numba``), so that this module's cache locator is in place before any kernel is defined.

**The cache.**  Numba keys its cache of a function to the absolute folder of its source file
and stamps it with that one file.  starforge's locator (:class:`_Locator`) keys it instead to
the *contents* of the package: every kernel of a starforge module is cached under
``<numba cache dir>/starforge-<digest>/<subpackage>/``, where the digest is the SHA-256 of every
``.py`` file of the package (their paths relative to it, and their bytes), and that digest is
also each entry's stamp.  So

* the same sources compile to the same entries wherever they are installed (a wheel's build
  folder, a virtual environment, an editable checkout), which is what lets a wheel ship its
  kernels built (below);
* a kernel is never loaded after a change to another module it calls into (numba's own stamp
  only follows the function's own file, so an edit to a kernel that other kernels compile in
  left them stale);
* two installed versions do not overwrite each other's entries.

The numba cache folder is ``NUMBA_CACHE_DIR`` (:func:`starforge.runtime.cache.cache_dir`'s ``numba`` folder
unless the user set one), in the user's cache folder, never in the installed package.

**Built ahead of time.**  Building a wheel (``pip install .`` builds one on the user's machine)
compiles the kernels a ``starforge stars`` and a ``starforge place`` run load (:func:`prebuild`,
called by ``setup.py``)
and packs their cache entries into ``starforge/kernels.zip`` with a manifest: the digest and the
numba, numpy and Python versions they were built with.  The first time a process needs the
cache folder of this digest and it does not exist yet, the entries are unpacked into it
(:func:`_seed`, into a temporary folder renamed into place) when the manifest matches this
installation; numba then checks each entry against this machine's CPU and loads it instead of
compiling.  When anything differs (a wheel built elsewhere, another numba, edited sources, no
zip) nothing is unpacked and the kernels are compiled on first use, as without it.  The zip is
a build product shipped like a compiled extension; nothing is ever written into the package.
"""

from __future__ import annotations

import errno
import functools
import hashlib
import json
import os
import shutil
import sys
import tempfile
import zipfile

import numba
from llvmlite import ir
from numba.core import caching, cgutils, types
from numba.extending import intrinsic

from starforge.runtime.cache import cache_dir

__all__ = ["numba", "digest", "kernel_dir", "manifest", "prebuild", "prefetch"]

#: the package folder, whose ``.py`` files the digest covers
PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: the kernels a wheel ships (a build product; absent from a source checkout)
SEED = os.path.join(PACKAGE_DIR, "kernels.zip")
_MANIFEST = "manifest.json"
#: folders of the package that hold data, not code (the templates' ``__init__.py`` only makes
#: them a package, and an editable checkout keeps them outside this folder)
_NOT_CODE = ("templates",)


@functools.cache
def digest(root: str = PACKAGE_DIR) -> str:
    """SHA-256 (hex, 16 characters) of the package's code: each ``.py`` file's path relative
    to ``root`` and its bytes, in sorted order.  About 2 ms for the 100 files."""
    h = hashlib.sha256()
    for folder, subs, files in os.walk(root):
        subs[:] = sorted(s for s in subs if s != "__pycache__" and not (folder == root and s in _NOT_CODE))
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                h.update(os.path.relpath(path, root).replace(os.sep, "/").encode() + b"\0")
                with open(path, "rb") as f:
                    h.update(hashlib.sha256(f.read()).digest())
    return h.hexdigest()[:16]


def manifest() -> dict:
    """What kernels built here are valid for: this package's digest and the numba, numpy
    (major.minor) and Python versions.  A shipped zip carries it and is unpacked only where it
    is equal."""
    import numpy

    return {
        "digest": digest(),
        "numba": numba.__version__,
        "numpy": ".".join(numpy.__version__.split(".")[:2]),
        "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
    }


@functools.cache
def kernel_dir() -> str:
    """This package's folder in the numba cache, ``starforge-<digest>``; on its first use in a
    process, unpacked from the shipped kernels when it does not exist yet (:func:`_seed`)."""
    base = numba.config.CACHE_DIR or os.path.join(cache_dir(), "numba")
    path = os.path.join(base, f"starforge-{digest()}")
    if not os.path.isdir(path):
        _seed(SEED, path)
    return path


def _seed(zip_path: str, target: str) -> bool:
    """Unpack the kernels in ``zip_path`` into ``target`` (which does not exist yet) when its
    manifest matches this installation; True when they were.  Unpacked into a temporary
    folder beside ``target`` and renamed into place, so no process ever sees half of them; a
    missing, foreign or corrupt zip unpacks nothing (the kernels are compiled on first use)."""
    if not os.path.isfile(zip_path):
        return False
    parent = os.path.dirname(target)
    tmp = None
    try:
        with zipfile.ZipFile(zip_path) as z:
            if json.loads(z.read(_MANIFEST)) != manifest():
                return False
            names = [n for n in z.namelist() if n != _MANIFEST]
            if any(n.startswith("/") or ".." in n.split("/") for n in names):
                return False
            os.makedirs(parent, exist_ok=True)
            tmp = tempfile.mkdtemp(prefix=".seed-", dir=parent)
            for name in names:
                z.extract(name, tmp)
        os.rename(tmp, target)  # atomic; fails when another process got there first
        return True
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        return False


class _Locator(getattr(caching, "_CacheLocator", object)):
    """Numba cache locator for the functions of starforge's modules: the folder
    ``kernel_dir()/<subpackage>``, stamped with the package digest (see the module's text)."""

    def __init__(self, py_func, py_file):
        self._lineno = py_func.__code__.co_firstlineno
        sub = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), PACKAGE_DIR)
        self._cache_path = os.path.join(kernel_dir(), "" if sub == "." else sub)

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return digest()

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        path = os.path.abspath(py_file)
        if not path.startswith(PACKAGE_DIR + os.sep):
            return None  # not starforge's: numba's own locators decide
        self = cls(py_func, py_file)
        try:
            self.ensure_cache_path()
        except OSError:
            return None  # not writable: numba's other locators (or no cache)
        return self


def _install() -> bool:
    """Put :class:`_Locator` first in numba's list of cache locators (a class attribute that is
    not numba's public API: where a numba release lacks it, nothing is installed and numba's
    own locators cache the kernels by folder, as before).  True when it is in place."""
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    locators = getattr(impl, "_locator_classes", None)
    if not isinstance(locators, list) or not hasattr(caching, "_CacheLocator"):
        return False
    if _Locator not in locators:
        locators.insert(0, _Locator)
    return True


#: errors of a cache entry that cannot be written for lack of room or of permission
_CANNOT_WRITE = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)


def _guard_saves() -> bool:
    """A kernel whose cache entry cannot be written (a full disk, a quota, a read-only cache
    folder) stays compiled in this process and uncached, as where numba finds no writable cache
    folder; the command goes on (numba itself lets the error end it).  Wraps numba's
    ``Cache.save_overload``; True when the wrapper is in place."""
    cls = getattr(caching, "Cache", None)
    save = getattr(cls, "save_overload", None)
    if save is None or getattr(save, "starforge_guard", False):
        return False

    @functools.wraps(save)
    def guarded(self, sig, data):
        try:
            save(self, sig, data)
        except OSError as exc:
            if exc.errno not in _CANNOT_WRITE:
                raise

    guarded.starforge_guard = True
    cls.save_overload = guarded
    return True


_install()
_guard_saves()


@intrinsic
def prefetch(typingctx, array, i):
    """In compiled code, ``prefetch(array, i)`` asks the CPU to bring ``array[i]`` (its row ``i``
    when 2-d; C-contiguous) into its cache for writing (LLVM's ``llvm.prefetch``); a hint
    only, it changes no value.  A loop over scattered rows that prefetches the row it reaches
    some steps ahead finds it cached instead of waiting for memory."""
    if not (isinstance(array, types.Array) and array.ndim in (1, 2) and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        row = context.cast(builder, args[1], signature.args[1], types.intp)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [row, zero][: aryty.ndim])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        builder.call(fn, [builder.bitcast(ptr, i8p), i32(1), i32(3), i32(1)])  # write, keep, data
        return context.get_dummy_value()

    return types.void(array, i), codegen


# -- building ahead of time -------------------------------------------------------------------

#: kernels compiled from their signatures alone, each with the types its callers pass (arrays
#: C-contiguous): those ``starforge place`` calls, and those ``starforge stars`` calls only for
#: large specs (from 1 M stars or 4 M window entries up, e.g. ``--delta 1.0``).  A kernel called
#: with other types is compiled on its first use as before (the wheel test fails on any such
#: compile in a default ``stars`` or ``place``).
SIGNATURES = (
    ("starforge.props.sites:_greedy_keep", "int64[::1], int64[::1], int64"),
    (
        "starforge.props.visibility:_view_masks",
        "float64[:, ::1], float64[:, ::1], float64[:, :, ::1], float64[:, :, :, ::1], float64[:, ::1], float64, "
        "float64[:, ::1], int64[::1], int64[::1], int64",
    ),
    ("starforge.props.visibility:_seg_seg_dist2", ", ".join(["float64"] * 12)),
    (
        "starforge.props.tracked:_screen_tracked",
        "float64[::1], float64[:, ::1], float64[:, ::1], boolean[:, ::1], float64[:, ::1], float64[:, ::1], float64",
    ),
    ("starforge.props.distinct:_added_own", "float64[:, ::1], float64[:, ::1], float64[:, ::1], float64"),
    ("starforge.props.distinct:_own_counts", "float64[:, ::1], float64"),
    (
        "starforge.props.scan:_quadric_fits",
        "float64[:, ::1], float64[:, ::1], int64[::1], int64[:, ::1], float64[:, ::1], float64, float64, float64, "
        "float64[:, ::1], float64[::1], int64[::1], boolean[::1]",
    ),
    ("starforge.geometry.sym3:line_spread2", ", ".join(["float64"] * 10)),
    ("starforge.geometry.sym3:line_spread2", ", ".join(["int64"] + ["float64"] * 9)),
    ("starforge.geometry.sym3:line_spread2_at_least", ", ".join(["float64"] * 11)),
    ("starforge.geometry.sym3:line_spread2_many", "float64[::1], float64[:, ::1], float64[:, ::1]"),
    ("starforge.geometry.sym3:line_spread2_at_least_many", "float64[::1], float64[:, ::1], float64[:, ::1], float64"),
    (
        "starforge.stars.bounds:_face_blocks",
        "int16[:, ::1], int64[:, ::1], int64, int64, int64, int64, int64, boolean[::1]",
    ),
    ("starforge.stars.rules:_window_codes", "int32[:, ::1], int64[:, ::1], int64, int64"),
    ("starforge.stars.rules:_counted_entries", "int64[:, ::1], int64[::1]"),
    ("starforge.stars.rules:_dense_rows", "int64[::1], int64"),
)


def compiled_here(kernel) -> bool:
    """Whether numba's cache holds an entry of ``kernel`` (a cached ``numba.njit`` function) for
    this machine: false on a first run (and for a cache built on another CPU, whose entries numba
    does not load).  It reads numba's cache index, keyed by signature and the target's triple,
    CPU and features; any doubt counts as compiled, so that nothing is said or started for it."""
    try:
        here = kernel.targetctx.codegen().magic_tuple()
        return any(key[1] == here for key in kernel._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001  (a private numba API: never fail a command over it)
        return True


#: what a command says once when it compiles its kernels (:func:`compiled_here` false)
FIRST_RUN_NOTE = "a first run compiles the kernels once (tens of seconds); later runs load them from the cache"


def compile_signatures() -> None:
    """Compile (or load) the kernels of :data:`SIGNATURES`."""
    import importlib

    from numba.core.sigutils import normalize_signature

    for target, sig in SIGNATURES:
        mod, name = target.split(":")
        args, _ = normalize_signature(f"({sig})")
        # the argument types as a tuple: the key a call looks the cache up by (a string would
        # be stored under the string)
        getattr(importlib.import_module(mod), name).compile(tuple(args))


#: the groups of kernels a ``starforge stars`` run and a ``starforge place`` run load, each
#: compiled by a process of its own
_GROUPS = (
    "starforge.stars.warmup:compile_fit_decision",
    "starforge.stars.warmup:_helper",
    "starforge.runtime.kernels:compile_signatures",
)


def prebuild(zip_path: str, groups: tuple[str, ...] = _GROUPS, timeout_s: float = 600.0) -> None:
    """Compile the kernels of ``groups`` (``"module:function"``, each function called without
    arguments) into a fresh cache and pack it, with its manifest, into ``zip_path`` (written
    to a temporary name, then renamed).  Each group runs in its own process (two cores
    compile at once); the caller's environment must import this package and numba."""
    import subprocess

    with tempfile.TemporaryDirectory(prefix="starforge-prebuild-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, STARFORGE_CACHE_DIR=cache)
        procs = []
        for group in groups:
            mod, fn = group.split(":")
            code = f"import gc; gc.disable(); from {mod} import {fn}; {fn}()"
            procs.append(subprocess.Popen([sys.executable, "-c", code], env=env, stdin=subprocess.DEVNULL))
        try:
            for p in procs:
                if p.wait(timeout=timeout_s) != 0:
                    raise RuntimeError(f"compiling the kernels failed (exit {p.returncode})")
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        src = os.path.join(cache, f"starforge-{digest()}")
        zip_path = os.path.abspath(zip_path)
        tmp = zip_path + ".tmp"
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr(_MANIFEST, json.dumps(manifest(), sort_keys=True))
            for folder, subs, files in os.walk(src):
                subs.sort()
                for name in sorted(files):
                    if name.endswith((".nbi", ".nbc")):
                        path = os.path.join(folder, name)
                        z.write(path, os.path.relpath(path, src).replace(os.sep, "/"))
        os.replace(tmp, zip_path)


def prebuild_main() -> None:
    """``python -c "from starforge.runtime.kernels import prebuild_main; prebuild_main()" OUT.zip``"""
    prebuild(sys.argv[1])
