"""Values kept in starforge's cache folder (:func:`starforge.runtime.cache.cache_dir`) by the
content of everything they are computed from: a later run with the same inputs, the same
starforge code and the same libraries reads the value back instead of computing it again.

Only for pure functions of their inputs whose value pickles; what is read back equals what the
function returns, so every output computed from it is the same, byte for byte."""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from starforge.io import atomic_write_bytes
from starforge.runtime.cache import cache_dir
from starforge.runtime.kernels import digest

T = TypeVar("T")

#: values kept per kind; past this many the least recently written are removed
KEEP_PER_KIND = 64


def _feed(h, obj) -> None:
    """Hash ``obj`` into ``h`` by value: numbers, strings, arrays (dtype, shape, bytes), and
    tuples, lists, dicts and dataclasses of them, each tagged by its type; anything else is a
    TypeError (a value keyed by its ``repr`` or ``id`` could match a different one)."""
    if obj is None or isinstance(obj, bool | int | float | complex | str | bytes):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    elif isinstance(obj, Path):
        h.update(f"path:{obj!s};".encode())
    elif isinstance(obj, np.ndarray | np.generic):
        a = np.ascontiguousarray(obj)
        h.update(f"array:{a.dtype.str}:{a.shape};".encode())
        if a.dtype.hasobject:
            for x in a.ravel():
                _feed(h, x)
        else:
            h.update(a.tobytes())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"dataclass:{type(obj).__module__}.{type(obj).__qualname__};".encode())
        for f in dataclasses.fields(obj):
            h.update(f"{f.name}=".encode())
            _feed(h, getattr(obj, f.name))
    elif isinstance(obj, tuple | list):
        h.update(f"{type(obj).__module__}.{type(obj).__qualname__}:{len(obj)};".encode())
        for x in obj:
            _feed(h, x)
    elif isinstance(obj, dict):
        h.update(f"dict:{len(obj)};".encode())
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
    else:
        raise TypeError(f"no content key for a {type(obj).__name__}")


def content_key(*parts, libraries: tuple[str, ...] = ()) -> str:
    """The hex key of ``parts`` (numbers, strings, arrays, and tuples, lists, dicts and
    dataclasses of them), starforge's code (:func:`starforge.runtime.kernels.digest`: every
    ``.py`` file, the version among them, so that code that computes a value differently never
    reads it back), Python's version and the installed version of each distribution named in
    ``libraries`` (read from its metadata, so the key does not import it).

    >>> content_key(1, "a") == content_key(1, "a") != content_key(1, "b")
    True
    """
    h = hashlib.blake2b(digest_size=20)
    env = [digest(), sys.version]
    env += [f"{name}={_version(name)}" for name in libraries]
    _feed(h, (tuple(env), parts))
    return h.hexdigest()


def _version(name: str) -> str:
    """The installed version of the distribution ``name``; ``?`` when it is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "?"


def stored(kind: str, key: str, compute: Callable[[], T]) -> tuple[T, bool]:
    """``(compute(), False)``, the value kept under the cache folder's ``kind`` folder by ``key``
    (a :func:`content_key` of everything the value depends on); ``(value, True)`` when a call
    with the same key kept it before.  An unreadable entry is computed and written again; one
    that cannot be written (a read-only or full cache folder) is only computed."""
    path = Path(cache_dir()) / "stored" / kind / f"{key}.pkl"
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh), True
    except Exception:  # none yet, or a truncated or foreign file: computed (and written) again
        pass
    value = compute()
    _keep(path, value)
    return value, False


def _keep(path: Path, value: Any) -> None:
    try:
        atomic_write_bytes(path, pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        entries = sorted(path.parent.glob("*.pkl"), key=lambda p: p.stat().st_mtime)
        for old in entries[: max(0, len(entries) - KEEP_PER_KIND)]:
            old.unlink(missing_ok=True)
    except OSError:
        pass
