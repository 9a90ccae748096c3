"""The command's process: its signals, its helpers, its garbage collector and its exit.

:func:`command` wraps one command: Ctrl-C and SIGTERM unwind it (nothing staged is published,
:mod:`starforge.io`), a last-resort watcher ends it when a compiled kernel does not return, its
helper processes end with it (:mod:`starforge.runtime.procs`), and what it paused is resumed.
:func:`end_process` then ends the process, without the interpreter's teardown where the command
allowed it (:func:`allow_quick_exit`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

from starforge.io import discard_stages, interrupted, note_interrupt, published, renaming, reset_interrupt
from starforge.runtime.budget import ENV_MEMORY, ENV_SECONDS
from starforge.runtime.engine import ENV_SCHEDULER, silence_dask
from starforge.runtime.procs import end_children
from starforge.runtime.stop import report_stop

__all__ = ["STOP_DEADLINE_S", "Command", "allow_quick_exit", "command", "end_process", "pause_gc"]

#: set by a command that allows the process to end without the interpreter's teardown
_quick_exit = [False]
#: whether the cyclic garbage collector ran before :func:`pause_gc` turned it off
_gc_was = [None]


def allow_quick_exit() -> None:
    """Let the process end without the interpreter's teardown once this command returns
    (:func:`end_process`): for a command whose every output is written, closed and published
    (``starforge.io``) by the time it returns, and that leaves no thread of its own running."""
    _quick_exit[0] = True


def pause_gc() -> None:
    """Turn Python's cyclic garbage collector off until the command returns (:func:`command`
    turns it back on): for a short command whose objects are nearly all acyclic and freed by
    reference counting, so that no collector pass walks numba's, scipy's and trimesh's heap."""
    import gc

    if _gc_was[0] is None:
        _gc_was[0] = gc.isenabled()
    gc.disable()


#: the signal that stopped the command (SIGINT or SIGTERM), for its one line and exit code
_stopped_by: list = [None]


def _on_signal(signum, frame):
    """Ctrl-C and SIGTERM alike, in the main thread: remember it (even where a library swallows
    the exception below) and unwind; nothing staged is published (starforge.io.staged_output
    checks the flag).  During a publish's renames it only remembers: they finish (or roll back)
    first, and the publish stops the command right after."""
    _noted(signum)
    if renaming():
        return
    raise KeyboardInterrupt


def _noted(signum: int) -> bool:
    """Record the stopping signal; True the first time."""
    note_interrupt()
    if _stopped_by[0] is None:
        _stopped_by[0] = signum
        return True
    return False


#: seconds a command has to stop on its own after Ctrl-C or SIGTERM before the last resort
STOP_DEADLINE_S = 1.0

_reported = threading.Lock()  # held by whoever reports the stop (the command, or the last resort)


def _watch_signals(read_fd: int, done: threading.Event, discard_stages, end_children, published) -> None:
    """The last resort, in a thread: Python runs a signal handler only between bytecodes of the
    main thread, and a compiled kernel (numba, HiGHS) does not return to Python until it is done.
    The signal's number also arrives on ``read_fd`` (signal.set_wakeup_fd) while such a kernel
    runs without the GIL; if the command has not ended STOP_DEADLINE_S later, remove its stage
    folders (never in the middle of a publish), end the command's helper processes, print the
    one line and exit at once.  It imports nothing itself (``discard_stages``, ``end_children``
    and ``published`` come in): a module lock it held while the process forks would stay taken
    in the child forever."""
    while True:
        try:
            data = os.read(read_fd, 1)
        except OSError:
            return
        if not data:  # the command ended and closed the pipe
            return
        signum = data[0]
        if signum not in (signal.SIGINT, signal.SIGTERM):
            continue
        _noted(signum)
        if done.wait(STOP_DEADLINE_S):
            return
        with _reported:
            if done.is_set() or not discard_stages():
                return  # ended meanwhile, or a publish that would not finish: let it end on its own
            end_children()
            report_stop(_stopped_by[0] or signum, published())
            os._exit(128 + (_stopped_by[0] or signum))


def _install_signals():
    """Handlers for SIGINT and SIGTERM and the last-resort watcher; returns (the event to set
    when the command has ended, under ``_reported``; the undo function)."""
    done = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        return done, lambda: None
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    try:
        old_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    except (ValueError, OSError):
        old_fd = None
    watcher = threading.Thread(
        target=_watch_signals, args=(read_fd, done, discard_stages, end_children, published), name="starforge-signals",
        daemon=True,
    )
    # safe to fork beside (starforge.render.props forks render processes, starforge.cad.step_worker
    # its STEP worker): it imports nothing and holds no lock while it waits in os.read, and a
    # forked child drops the wakeup fd (starforge.runtime.procs), so it never writes into the watcher's pipe
    watcher.fork_safe = True
    watcher.start()

    def undo() -> None:
        with _reported:  # if the last resort holds it, it is exiting the process
            done.set()
        if old_fd is not None:
            signal.set_wakeup_fd(old_fd)
        os.close(write_fd)  # the watcher reads EOF and ends
        watcher.join(timeout=1.0)
        os.close(read_fd)
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return done, undo


def _quiet_interrupts(previous):
    """An unraisable-exception hook: a Ctrl-C that lands inside a callback Python cannot raise
    from (numba compiles inside llvmlite's ctypes callbacks) is recorded as an interrupt, without
    the 'Exception ignored in ... Traceback' print; so is whatever a finalizer raises once the
    command is stopping (an object the signal left half-built, such as llvmlite's ``ObjectRef``,
    fails in its ``__del__``; the command's one line says what happened); anything else goes to
    ``previous``."""
    def hook(unraisable) -> None:
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
            note_interrupt()
            return
        if interrupted():
            return
        previous(unraisable)

    return hook


class Command:
    """One command's run under :func:`command`; :meth:`finish` turns its return code into the
    process's exit code."""

    def __init__(self, done: threading.Event):
        self._done = done

    def finish(self, code: int) -> int:
        """The exit code: a Ctrl-C or SIGTERM, raised, turned into click's Abort or swallowed by
        a library, ends as 128 + the signal with its one line: nothing was published
        (``starforge.io.staged_output`` checks the flag), or the line names the folders a publish
        finished before the signal was delivered."""
        with _reported:  # if the last resort holds it, it is exiting the process
            self._done.set()
            if interrupted() and code in (0, 130):
                signum = _stopped_by[0] or signal.SIGINT
                code = 128 + signum
                report_stop(signum, published())
        return code


#: what ``--scheduler``, ``--max-memory`` and ``--max-seconds`` set (for the command's helpers and
#: workers to read): :func:`command` puts them back as they were when it ends, so that a program
#: calling the CLI twice does not carry one call's limits into the next
COMMAND_ENV = (ENV_SCHEDULER, ENV_MEMORY, ENV_SECONDS)


@contextlib.contextmanager
def command():
    """Run one command: signals, helpers, the scheduler address and limits it set and the
    collector it paused are all undone when it ends, whatever way it ends."""
    reset_interrupt()
    _stopped_by[0] = None
    _quick_exit[0] = False
    silence_dask()  # the engine's one line says what a cluster did wrong; dask's loggers stay quiet
    saved_env = {k: os.environ.get(k) for k in COMMAND_ENV}  # the global options set them for this command only
    done, undo = _install_signals()
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_interrupts(previous_hook)
    try:
        yield Command(done)
    finally:
        end_children()  # a helper the command did not wait for (an error, a signal) ends with it
        for key, value in saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        sys.unraisablehook = previous_hook
        undo()
        reset_interrupt()  # library calls after this command are not affected
        _resume_gc()


def _resume_gc() -> None:
    """Turn the garbage collector back on if a command paused it (:func:`pause_gc`)."""
    import gc

    if _gc_was[0]:
        gc.enable()
    _gc_was[0] = None


def end_process(code: int) -> None:
    """Exit the process with ``code``.  After a command that allowed it
    (:func:`allow_quick_exit`), without the interpreter's teardown: clearing
    the modules of a process that imported numba, scipy and trimesh costs about 0.3 s of CPU
    after the last output is published (a seventh of ``starforge place`` on the built-in hammer),
    and the operating system frees that memory at once.  The ``atexit`` handlers still run and
    stdout and stderr are flushed.  The ordinary exit under a tracer or profiler (coverage,
    cProfile: they write their data at the teardown) and while a thread that is not a daemon
    runs (the interpreter would wait for it)."""
    traced = sys.gettrace() is not None or sys.getprofile() is not None
    if "distributed" in sys.modules and not traced:
        # the engine closed every client and cluster it started; what dask leaves to the
        # interpreter's exit (its event-loop thread, connections to a scheduler that may be
        # gone) takes seconds to tear down, and dask reports on it after our one line
        _flush_and_exit(code)
    if _stopped_by[0] is not None and not traced:
        # stopped by a signal: the stages are gone (what was published is whole); a compiled kernel
        # may still run on a worker thread, which the interpreter's exit would wait for
        import atexit

        atexit._run_exitfuncs()
        _flush_and_exit(code)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if not _quick_exit[0] or others or traced:
        # everything is written and flushed; freezing what is left spares the interpreter's exit
        # a last walk over numba's and numpy's objects (measured: 0.15 CPU s, 0.5 s wall under
        # load, for `starforge stars`); atexit handlers and file flushes run as before
        import gc

        gc.freeze()
        sys.exit(code)
    import atexit

    atexit._run_exitfuncs()
    _flush_and_exit(code)


def _flush_and_exit(code: int) -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said on it
            pass
    os._exit(code)
