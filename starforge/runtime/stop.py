"""The one line a command stopped by SIGTERM or Ctrl-C ends with, and the handlers the starforge
command sets before anything else is imported.

``import starforge`` runs :func:`stop_early_in_command` first: when the process is the
``starforge`` command (the console script, or ``python -m starforge``), a signal from then on
ends it with the one line, also while the CLI's own modules load (a large share of a second).
Any other program that imports starforge (a notebook, a test run, a user's script) keeps its own
signal handling.  This module imports only ``os``, ``sys`` and ``_signal`` (the C module under
:mod:`signal`, which loads in microseconds where :mod:`signal` first imports :mod:`enum`), so that
the handlers are in place within the first milliseconds of the package's import.
"""

from __future__ import annotations

import _signal
import os
import sys

#: what the command's file may be called: the console script (``-script.py`` and ``.exe`` are
#: the forms Windows launchers give it)
_COMMAND_NAMES = ("starforge", "starforge.exe", "starforge-script.py")


def report_stop(signum: int, written=()) -> None:
    """The one line of a command stopped by SIGTERM or Ctrl-C: nothing was published, or (a signal
    that came during or after a publish, which it cannot undo) the folders in ``written`` hold the
    command's complete outputs."""
    word = "terminated" if signum == _signal.SIGTERM else "interrupted"
    if written:
        line = f"{word} after its outputs were written to {', '.join(str(w) for w in written)}\n"
    else:
        line = f"{word}; no output was changed\n"
    try:
        sys.stderr.write(line)
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):  # no stderr (closed, or not yet made)
        pass


def launched_as_command() -> bool:
    """True when this process is the ``starforge`` command: its script is the console script, or
    it was started as ``python -m starforge``; False for any other program importing starforge."""
    if sys.argv and os.path.basename(sys.argv[0]) in _COMMAND_NAMES:
        return True
    args = iter(getattr(sys, "orig_argv", ())[1:])
    for arg in args:
        if arg in ("-X", "-W"):  # the interpreter's options that take a value
            next(args, None)
        elif arg == "-m":
            return next(args, None) == "starforge"
        elif arg.startswith("-m"):
            return arg == "-mstarforge"
        elif arg in ("-c", "-") or not arg.startswith("-"):
            return False  # the program is a command string, stdin or a script of another name
    return False


def stop_early() -> None:
    """Until :mod:`starforge.runtime.process` installs a command's own handlers: Ctrl-C or SIGTERM
    ends the process at once with the one line.  Nothing has started then (no output, no stage)
    but perhaps a helper, which is ended with it; without this, an import would end in a KeyboardInterrupt traceback, or SIGTERM
    silently.  For the command only: it sets the process's handlers."""

    def early(signum, frame):
        # a helper started before the CLI loaded (the export's STEP worker) ends with the command;
        # none is registered unless starforge.runtime.procs is loaded, so nothing is imported here
        procs = sys.modules.get("starforge.runtime.procs")
        if procs is not None and hasattr(procs, "end_children"):
            procs.end_children()
        report_stop(signum)
        os._exit(128 + signum)

    for sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(sig, early)


def stop_early_in_command() -> None:
    """:func:`stop_early` when this process is the ``starforge`` command (:func:`launched_as_command`)."""
    if launched_as_command():
        stop_early()
