"""Atomic output: nothing half-written, nothing overwritten without ``force``."""

from __future__ import annotations

import contextlib
import errno
import functools
import json
import os
import re
import secrets
import shutil
import signal
import stat
import tempfile
import threading
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
    """Write ``data`` to ``path`` through a temp file in the same folder, then rename.  Missing
    folders on the way are created, but never a stage folder (:func:`staged_output`): one that
    is gone was removed by its command, and a late writer (a helper process) must not bring it
    back (FileNotFoundError instead)."""
    path = Path(path)
    _make_parents(path.parent)
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


def _make_parents(folder: Path) -> None:
    missing = []
    d = Path(os.path.abspath(folder))
    while not os.path.lexists(d) and d != d.parent:
        missing.append(d)
        d = d.parent
    for m in missing:
        if m in _stages or m.name.endswith(_STAGE_SUFFIX):
            raise FileNotFoundError(errno.ENOENT, "the stage folder was removed by its command", str(m))
    if missing:
        folder.mkdir(parents=True, exist_ok=True)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 text atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj) -> Path:
    """Write JSON atomically, indented, keys in insertion order, trailing newline."""
    return atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def check_name(name: str, what: str = "name") -> str:
    """A name that becomes a file or folder name: letters, digits, ``._-``, not starting with a dot,
    so that it can never leave the output folder (``../x``) or hide itself."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,99}", name):
        raise StarforgeError(
            f"{what} must be 1-100 letters, digits, '.', '_' or '-' and not start with '.' or '-', got {name!r}"
        )
    return name


def _nearest_existing(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def _what_it_is(path: Path) -> tuple[str, str]:
    """What ``path`` (something that exists and is no folder) is, and what to call it in a remedy."""
    if path.is_symlink() and not path.exists():
        return "a symbolic link that loops or leads nowhere", "the link"
    if path.is_file():
        return "a file, not a folder", "the file"
    mode = os.stat(path).st_mode
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device, not a folder", "the device"
    return "not a folder", "it"


def _output_base(out_dir: Path) -> Path:
    """The nearest existing folder of ``out_dir`` (``out_dir`` itself when it exists); a
    StarforgeError naming ``--out`` and what to do when ``out_dir`` or the path on its way is
    something else than a folder (a file, a link that loops, a device such as /dev/null)."""
    if os.path.lexists(out_dir) and not out_dir.is_dir():
        what, thing = _what_it_is(out_dir)
        raise StarforgeError(f"output folder {out_dir} is {what}: give --out a folder path (or move {thing} away)")
    base = _nearest_existing(out_dir)
    if not base.is_dir():
        raise StarforgeError(
            f"output folder {out_dir} cannot be made: {base} is {_what_it_is(base)[0]}; give --out a folder path"
        )
    return base


def check_writable(out_dir: str | Path, names: Iterable[str], force: bool) -> None:
    """Before the work starts: refuse (StarforgeError) when ``out_dir`` cannot be written or when
    any of ``names`` already exists there and not ``force``.

    ``out_dir`` may not exist yet; its nearest existing ancestor must be a folder in which a
    file can really be created (probed with a temp file, so read-only mounts and permissions
    are caught even for root).  Nothing is left behind by the check.
    """
    out_dir = Path(out_dir)
    base = _output_base(out_dir)
    try:
        fd, probe = tempfile.mkstemp(prefix=".starforge-probe.", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise StarforgeError(
            f"cannot write to {out_dir}: {exc.strerror or exc} ({base}); choose another --out"
        ) from None
    names = list(names)
    for n in names:
        dst = out_dir / n
        if dst.is_dir():
            raise StarforgeError(f"{dst} is a folder where an output file goes; move it away first")
        for anc in Path(n).parents:
            a = out_dir / anc
            if anc != Path(".") and os.path.lexists(a) and not a.is_dir():
                raise StarforgeError(f"{a} is a file where an output folder goes; move it away first")
    existing = [n for n in names if os.path.lexists(out_dir / n)]
    if existing and not force:
        shown = ", ".join(existing[:3]) + (" ..." if len(existing) > 3 else "")
        raise StarforgeError(f"{out_dir} already holds {shown}; pass --force to overwrite")
    # a read-only file (no write bit: root may write anyway) is the user's "keep this", even with --force
    locked = [n for n in existing if not os.path.islink(out_dir / n) and not os.stat(out_dir / n).st_mode & 0o222]
    if locked:
        shown = ", ".join(locked[:3]) + (f" and {len(locked) - 3} more" if len(locked) > 3 else "")
        raise StarforgeError(
            f"{out_dir} holds read-only {shown}; --force does not replace read-only files "
            "(make them writable, e.g. chmod u+w, or choose another --out)"
        )


@contextmanager
def _sigint_blocked():
    """Hold Ctrl-C and SIGTERM back from this thread (delivered afterwards) while a few renames
    run, so they finish or roll back; the starforge command's handler also waits for them
    (:func:`renaming`), since a signal another thread receives is not held back."""
    blockable = threading.current_thread() is threading.main_thread() and hasattr(signal, "pthread_sigmask")
    if blockable:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        if blockable:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def publish(stage: Path, out_dir: Path, force: bool) -> list[Path]:
    """Move every file of ``stage`` into ``out_dir`` all or nothing; returns the relative paths.

    A new ``out_dir`` is the stage folder renamed (one atomic step).  Into an existing folder,
    old files of the same names are moved aside first, then the new ones in; if any step fails
    every move is undone, so ``out_dir`` is exactly as it was.  Other files there stay.
    """
    stage, out_dir = Path(stage), Path(out_dir)
    produced = sorted(p.relative_to(stage) for p in stage.rglob("*") if p.is_file())
    check_writable(out_dir, [str(p) for p in produced], force)
    with _sigint_blocked():
        _renaming[0] = True
        try:
            if not os.path.lexists(out_dir):
                out_dir.parent.mkdir(parents=True, exist_ok=True)
                os.rename(stage, out_dir)
            else:
                _replace_files(stage, out_dir, produced)
            # recorded before a signal held back during the renames is acted on: a stop from here
            # on says the outputs were written (runtime.stop.report_stop)
            _published.append(out_dir)
        finally:
            _renaming[0] = False
    return produced


def _replace_files(stage: Path, out_dir: Path, produced: list[Path]) -> None:
    """Move ``produced`` from ``stage`` into the existing ``out_dir``: old files of the same names
    aside first, then the new ones in; on any failure every move is undone."""
    backup = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".old", dir=out_dir.parent))
    saved: list[Path] = []
    moved: list[Path] = []
    made: list[Path] = []
    try:
        for rel in produced:
            dst = out_dir / rel
            if os.path.lexists(dst):
                (backup / rel).parent.mkdir(parents=True, exist_ok=True)
                os.replace(dst, backup / rel)
                saved.append(rel)
            for anc in reversed(rel.parents):
                d = out_dir / anc
                if not d.exists():
                    d.mkdir()
                    made.append(d)
            os.replace(stage / rel, dst)
            moved.append(rel)
    except BaseException:
        for rel in reversed(moved):
            os.replace(out_dir / rel, stage / rel)
        for rel in reversed(saved):
            os.replace(backup / rel, out_dir / rel)
        for d in reversed(made):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    finally:
        shutil.rmtree(backup, ignore_errors=True)


#: the output folders this command has published, in order: a signal after a publish cannot
#: undo it, so the command's last line names them (runtime.stop.report_stop)
_published: list[Path] = []
#: True while a publish renames files: the mask of :func:`_sigint_blocked` holds a signal back
#: only from the thread that sets it, and a signal delivered to any other thread still runs the
#: Python handler in the main thread at once, so the command's handler asks :func:`renaming`
_renaming = [False]


def renaming() -> bool:
    """Whether a publish is renaming files now (a signal handler then lets it finish first)."""
    return _renaming[0]


def published() -> list[Path]:
    """The output folders published since the command began (:func:`reset_interrupt`)."""
    return list(_published)


#: set by the CLI's SIGINT handler: a Ctrl-C that a library swallowed (numba's compiler runs
#: inside ctypes callbacks, which print a KeyboardInterrupt and carry on) still stops publishing
_interrupted = False


def note_interrupt() -> None:
    """Record a Ctrl-C (called from the CLI's signal handler)."""
    global _interrupted
    _interrupted = True


def interrupted() -> bool:
    """Whether Ctrl-C was pressed during this command, even if the exception was swallowed."""
    return _interrupted


def reset_interrupt() -> None:
    """Forget a Ctrl-C and the folders published: a new command begins."""
    global _interrupted
    _interrupted = False
    _published.clear()


@contextmanager
def staged_output(out_dir: str | Path, force: bool = False) -> Iterator[Path]:
    """Stage every output file in a temp folder beside ``out_dir``; publish them only on success.

    Usage::

        with staged_output(out, force) as stage:
            (stage / "family.json").write_text(...)
        # now out/family.json exists; on any exception (Ctrl-C included) nothing in ``out`` changed

    Publishing is all or nothing (:func:`publish`).  Existing files of the same names are
    refused unless ``force``; other files in ``out_dir`` are left alone.
    """
    out_dir = Path(out_dir)
    _output_base(out_dir)
    # stage in the nearest folder that exists, so a failure creates no folder either
    with _kept_folder(_nearest_existing(out_dir.parent), f".{out_dir.name}.", _STAGE_SUFFIX) as stage:
        try:
            yield stage
        except Exception as exc:
            # a writer that fails while cleaning up after a full disk (matplotlib's PDF writer
            # ends in a zlib error) still means a full disk
            full = _full_disk_error(exc)
            if full is not None:  # say where: the message alone names no path
                raise StarforgeError(
                    f"cannot write the outputs for {out_dir}: {full.strerror or full} (staging in {stage.parent}); "
                    "free some space or choose another --out"
                ) from None
            raise
        if _interrupted:  # a Ctrl-C somebody swallowed: publish nothing
            raise KeyboardInterrupt
        for p in [stage, *stage.rglob("*")]:  # mkdtemp/mkstemp create 0o700/0o600; use the usual modes
            p.chmod(0o777 & ~_umask() if p.is_dir() else _file_mode())
        with _publishing:
            publish(stage, out_dir, force)
        if _interrupted:  # a signal that came while the files were renamed: stop now
            raise KeyboardInterrupt


def _full_disk_error(exc: BaseException) -> OSError | None:
    """The OSError of a full or read-only file system that ``exc`` is or arose from, else None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in _FULL:
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


@contextmanager
def scratch_folder(prefix: str, where: str | Path | None = None) -> Iterator[Path]:
    """A temporary working folder (in ``where``, default the system's temporary folder), removed
    afterwards, also by the CLI's last-resort exit after a signal (it is kept with the stages)."""
    with _kept_folder(Path(where or tempfile.gettempdir()), prefix) as folder:
        yield folder


@contextmanager
def _kept_folder(parent: Path, prefix: str, suffix: str = "") -> Iterator[Path]:
    """A new private folder in ``parent`` (``prefix`` + random + ``suffix``), removed with all it
    holds on leaving.  Its name joins the stages before the folder exists, and the removal covers
    every name tried, so a signal at any moment (in the middle of creating it included) leaves
    no folder behind: the exception's unwinding removes it, or the CLI's last-resort exit does."""
    tried: list[Path] = []
    try:
        while True:
            folder = parent / f"{prefix}{secrets.token_hex(5)}{suffix}"
            tried.append(folder)
            _stages.add(folder)
            try:
                folder.mkdir(mode=0o700)
                break
            except FileExistsError:
                continue
        yield folder
    finally:
        for f in tried:
            shutil.rmtree(f, ignore_errors=True)
            _stages.discard(f)


#: the name ending of every stage folder (never created by :func:`atomic_write_bytes`)
_STAGE_SUFFIX = ".staging"

#: errors of a full or read-only file system while writing (ENOSPC, EDQUOT, EFBIG, EROFS)
_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}

#: stage folders of the runs under way, and a lock held while one is published: the CLI's
#: last-resort exit after a signal (a compiled kernel that does not return to Python) takes the
#: lock, so that it never cuts a publish in half, and removes the stages (:func:`discard_stages`)
_stages: set[Path] = set()
_publishing = threading.Lock()


def discard_stages(timeout_s: float = 5.0) -> bool:
    """Remove every stage folder of this process, unless a publish is under way (then wait for it
    up to ``timeout_s``).  Returns False when a publish did not finish in time (nothing removed).
    The caller exits right after; the lock stays held so that no publish starts."""
    if not _publishing.acquire(timeout=timeout_s):
        return False
    import time

    for stage in list(_stages):
        # a worker thread may still be writing a file into it (e.g. a STEP file begun before the
        # signal): remove until the folder is gone, for a bounded time
        for _ in range(50):
            shutil.rmtree(stage, ignore_errors=True)
            if not os.path.lexists(stage):
                break
            time.sleep(0.02)
    return True


#: the largest input file of each kind, bytes: far above any real one, and small enough that
#: parsing it stays inside a command's memory budget (Python's JSON, TOML and CSV readers hold
#: 5-20 x a file's size as objects).  A 10,000-star family file is about 10 MB; meshes have
#: their own memory estimate from their size and the work asked of them (starforge.props.mesh).
INPUT_LIMITS = {
    "json": 128 * 2**20,  # family, placement and body files
    "toml": 2**20,  # specs, markers, mounts, rigs, presets
    "csv": 64 * 2**20,  # marker and score tables
    "mask": 128 * 2**20,  # --mask: one value per face
    "tracker": 128 * 2**20,  # QTM XML, VSK, Atracsys INI, NDI ROM, Motive, body CSV
    "mesh": 2 * 2**30,  # STL, OBJ, PLY, GLB, ...
    "file": 256 * 2**20,  # anything else
}


#: the way out of a file that cannot be opened
_UNREADABLE = "make it readable (chmod u+r) or give a copy you can read"


def check_input_file(path: str | Path, what: str = "file", kind: str = "file") -> Path:
    """A readable regular file no larger than ``INPUT_LIMITS[kind]``, or StarforgeError saying
    what is wrong with it (missing, a folder, a device such as /dev/null, a symlink loop,
    empty, unreadable, too large for its kind)."""
    path = Path(path)
    if not os.path.lexists(path):
        raise StarforgeError(f"{what} not found: {path}; check the path")
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise StarforgeError(f"{what} {path} is a symbolic link that loops back on itself; give the file it should point to") from None
        if exc.errno == errno.ENOENT:
            raise StarforgeError(f"{what} {path} is a symbolic link to a missing file; give the file itself") from None
        raise StarforgeError(f"cannot read {what} {path}: {exc.strerror or exc}; {_UNREADABLE}") from None
    if stat.S_ISDIR(st.st_mode):
        raise StarforgeError(f"{what} {path} is a folder, expected a file")
    if not stat.S_ISREG(st.st_mode):
        raise StarforgeError(f"{what} {path} is not a regular file; give a file, not a device or a pipe")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise StarforgeError(f"cannot read {what} {path}: {exc.strerror or exc}; {_UNREADABLE}") from None
    if st.st_size == 0:
        raise StarforgeError(f"{what} {path} is empty (0 bytes); give the saved file")
    limit = INPUT_LIMITS[kind]
    if st.st_size > limit:
        raise StarforgeError(
            f"{what} {path} is {_mb(st.st_size)}, above the {_mb(limit)} a {kind} input may be; "
            "give the file you meant"
        )
    return path


def _mb(n: float) -> str:
    return f"{n / 2**20:,.0f} MB" if n >= 2**20 else f"{n / 1024:,.0f} kB"


def read_json(path: str | Path, what: str = "file") -> dict:
    """Read a JSON object with clear errors for a missing, empty or corrupt file."""
    path = check_input_file(path, what, "json")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StarforgeError(f"{what} {path} is not valid JSON ({exc}); save it again from the program that wrote it") from None
    except RecursionError:
        raise StarforgeError(f"{what} {path} is nested too deeply to be a starforge file") from None
    if not isinstance(data, dict):
        raise StarforgeError(f"{what} {path} must hold a JSON object, got {type(data).__name__}")
    return data
