"""Forked helper processes: when this process may fork, and what a forked child gives up of its
parent's signal handling.

A forked child starts with everything the parent has imported (no interpreter start-up, no
second import of numpy or of starforge), which is why the placement pictures
(:mod:`starforge.render.props`) and the STEP worker (:mod:`starforge.cad.step_worker`) fork
where they can.  Forking is unsafe while another thread may hold a lock the child would inherit
taken, so it is done only when every other thread declares itself ``fork_safe``; callers keep a
path without ``os.fork`` for the rest.
"""

from __future__ import annotations

import os


def can_fork() -> bool:
    """True when ``os.fork`` exists and every thread but this one declares itself safe to fork
    beside (``fork_safe``: the CLI's progress heartbeat holds a lock across forks while it
    prints)."""
    import threading

    if not hasattr(os, "fork"):
        return False
    me = threading.current_thread()
    return all(t is me or getattr(t, "fork_safe", False) for t in threading.enumerate())


def leave_parent_signals(default_handlers: bool = False) -> None:
    """In a forked child: stop writing signal numbers into the parent's wakeup pipe (the CLI's
    last-resort watcher reads it; a signal meant for this process is not the parent's) and close
    this process's copy of its write end.  ``default_handlers``: also put Python's own handlers
    back for SIGINT (KeyboardInterrupt) and SIGTERM (end at once) in place of the parent's."""
    import signal

    try:
        if default_handlers:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        fd = signal.set_wakeup_fd(-1)
    except (ValueError, OSError):  # not the main thread, or no wakeup fd set
        return
    if fd >= 0:
        try:
            os.close(fd)
        except OSError:
            pass
