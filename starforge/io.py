"""Atomic output: nothing half-written, nothing overwritten without ``force``."""

from __future__ import annotations

import functools
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from starforge.errors import StarforgeError


@functools.cache
def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _file_mode() -> int:
    """The mode ``open()`` gives a new file (0o666 less the umask); mkstemp would leave 0o600."""
    return 0o666 & ~_umask()


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temp file in the same folder, then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _file_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 text atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj) -> Path:
    """Write JSON atomically, indented, keys in insertion order, trailing newline."""
    return atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def check_writable(out_dir: str | Path, names: Iterable[str], force: bool) -> None:
    """Refuse (StarforgeError) when any of ``names`` already exists in ``out_dir`` and not ``force``."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise StarforgeError(f"output path {out_dir} exists and is not a folder")
    existing = [n for n in names if (out_dir / n).exists()]
    if existing and not force:
        shown = ", ".join(existing[:3]) + (" ..." if len(existing) > 3 else "")
        raise StarforgeError(f"{out_dir} already holds {shown}; pass --force to overwrite")


@contextmanager
def staged_output(out_dir: str | Path, force: bool = False) -> Iterator[Path]:
    """Stage every output file in a temp folder beside ``out_dir``; publish them only on success.

    Usage::

        with staged_output(out, force) as stage:
            (stage / "family.json").write_text(...)
        # now out/family.json exists; on any exception nothing in ``out`` changed

    Files are moved in with ``os.replace`` (atomic per file).  Existing files of the same
    names are refused unless ``force``; other files in ``out_dir`` are left alone.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise StarforgeError(f"output path {out_dir} exists and is not a folder")
    parent = out_dir.parent
    parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".staging", dir=parent))
    try:
        yield stage
        for p in stage.rglob("*"):  # mkdtemp/mkstemp create 0o700/0o600; give outputs the usual modes
            p.chmod(0o777 & ~_umask() if p.is_dir() else _file_mode())
        produced = sorted(p.relative_to(stage) for p in stage.rglob("*") if p.is_file())
        check_writable(out_dir, [str(p) for p in produced], force)
        out_dir.mkdir(parents=True, exist_ok=True)
        for rel in produced:
            dst = out_dir / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / rel, dst)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def read_json(path: str | Path, what: str = "file") -> dict:
    """Read a JSON object with clear errors for a missing or corrupt file."""
    path = Path(path)
    if not path.exists():
        raise StarforgeError(f"{what} not found: {path}")
    if path.is_dir():
        raise StarforgeError(f"{what} {path} is a folder, expected a JSON file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StarforgeError(f"{what} {path} is not valid JSON ({exc.__class__.__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise StarforgeError(f"{what} {path} must hold a JSON object, got {type(data).__name__}")
    return data
