"""Forked helper processes: when this process may fork, and what a forked child gives up of its
parent's signal handling; and the one line a command stopped by a signal ends with, with the
handlers the console script sets before anything else is imported (:func:`stop_early`).

A forked child starts with everything the parent has imported (no interpreter start-up, no
second import of numpy or of starforge), which is why the placement pictures
(:mod:`starforge.render.props`) and the STEP worker (:mod:`starforge.cad.step_worker`) fork
where they can.  Forking is unsafe while another thread may hold a lock the child would inherit
taken, so it is done only when every other thread declares itself ``fork_safe``; callers keep a
path without ``os.fork`` for the rest.

Every helper belongs to its command: :func:`fork_helper` (and :func:`adopt` for a launched
interpreter) registers it, and :func:`end_children` ends whatever is still registered when the
command ends, by an error, a signal or the CLI's last-resort exit; a forked helper also dies
with its parent when that is killed outright.
"""

from __future__ import annotations

import os
import signal
import sys


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


#: helper processes of this command: pid -> True when the helper leads its own process group
#: (its own children are in it and end with it)
_children: dict[int, bool] = {}


def adopt(pid: int, group: bool = False) -> None:
    """Register a helper process as this command's: :func:`end_children` ends it (the CLI calls
    that when the command ends, however it ends).  ``group``: the helper leads its own process
    group (see :func:`in_forked_child`), which is ended as a whole."""
    if group:
        try:  # also done by the child; whichever runs first makes the group
            os.setpgid(pid, pid)
        except OSError:
            pass
    _children[pid] = group


def release(pid: int) -> None:
    """The helper ``pid`` has been reaped: forget it (its pid may be reused)."""
    _children.pop(pid, None)


def end_children() -> None:
    """SIGKILL every helper still registered (and each group a helper leads), so that none
    outlives the command or writes after its stage folder is removed.  Safe from any thread
    and after a fork (it imports nothing); the helpers are reaped by whoever waits for them,
    or by the system once this process exits."""
    for pid, group in list(_children.items()):
        try:
            if group:
                os.killpg(pid, signal.SIGKILL)
            else:
                os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            try:  # the group was never made (killed before setpgid): the process alone
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass


def fork_helper(group: bool = False, default_handlers: bool = False) -> int:
    """``os.fork`` for a helper of this command: 0 in the child, the child's pid (registered with
    :func:`adopt`) in the parent.  The child forgets the parent's helpers (they are not its own),
    leaves the parent's signal handling (:func:`leave_parent_signals`), asks the kernel to
    SIGKILL it when its parent dies (Linux ``PR_SET_PDEATHSIG``, when forked from the main
    thread: the kernel ties it to the forking thread), so that a parent killed outright leaves
    no orphan writing into a removed folder, and with ``group`` leads a new process group, so
    that :func:`end_children` ends it and every process it forks in one call."""
    import threading

    from_main = threading.current_thread() is threading.main_thread()
    pid = os.fork()
    if pid == 0:
        _children.clear()
        if group:
            try:
                os.setpgid(0, 0)
            except OSError:
                pass
        if from_main:
            _die_with_parent()
        leave_parent_signals(default_handlers)
        return 0
    adopt(pid, group)
    return pid


def _die_with_parent() -> None:
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        parent = os.getppid()
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
        if os.getppid() != parent:  # the parent died before the request: end now
            os._exit(1)
    except (OSError, AttributeError):
        pass


def report_stop(signum: int) -> None:
    """The one line of a command stopped by SIGTERM or Ctrl-C (nothing was published)."""
    word = "terminated" if signum == signal.SIGTERM else "interrupted"
    try:
        sys.stderr.write(f"{word}; no output was changed\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def stop_early() -> None:
    """Until :mod:`starforge.runtime.process` installs a command's own handlers: Ctrl-C or SIGTERM
    while the CLI's modules are still being imported ends the process at once with the one line.
    Nothing has started then (no output, no stage) but perhaps the export's STEP worker, which is
    ended with it; without this, an import would end in a KeyboardInterrupt traceback, or SIGTERM
    silently.  For the console script only (it sets the process's handlers); this module imports
    nothing else, so they are set within milliseconds."""
    def early(signum, frame):
        end_children()
        report_stop(signum)
        os._exit(128 + signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, early)
