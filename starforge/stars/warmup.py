"""A first run compiles its kernels on two cores instead of one.

On an empty numba cache (a fresh install) ``starforge stars`` spends most of its first run
compiling, one kernel after another on one core, while the other cores wait.  When the cache
is cold, :func:`start` launches one helper process that compiles the enumeration's first pass
and the selection's kernels into the same cache, while this process compiles the fit decision
(:func:`compile_fit_decision`); each then loads what the other wrote.  The kernels, their
signatures and every result are the same as without it; a warm cache starts nothing.

The helper reports each group of kernels on its standard output as soon as they are in the
cache ("enumerate", then "select"); before this process first calls a group's kernels it waits
for that report (:func:`ready`) instead of compiling the same kernels a second time beside the
helper (a duplicate that would cost seconds of CPU on the same two cores).  Whatever the two
processes' speeds (the load on the machine, kernels added or made cheaper), each kernel is then
compiled once.

Numba's cache files are written to a temporary name and renamed, so a helper stopped part way
leaves no broken entry: at worst a kernel is compiled by this process as before (a helper that
ends without its report, or is slower than :data:`WAIT_S`, is not waited for).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading

from starforge.runtime.kernels import FIRST_RUN_NOTE, compiled_here
from starforge.runtime.procs import adopt, release

#: seconds this process waits at most for the helper's report of a group of kernels (a first
#: run's groups take a few seconds each); past it, it compiles them itself as without a helper
WAIT_S = 60.0


class Helper:
    """The helper process and the groups of kernels it has reported in the cache (read from its
    standard output by a daemon thread)."""

    def __init__(self, proc: subprocess.Popen):
        self.proc = proc
        self._done: set[str] = set()
        self._ended = False
        self._cond = threading.Condition()
        listener = threading.Thread(target=self._listen, name="starforge-warmup", daemon=True)
        # it only reads a pipe and takes this object's own lock, which no forked child uses
        listener.fork_safe = True
        listener.start()
        self._listener = listener

    @property
    def returncode(self) -> int | None:
        return self.proc.returncode

    def _listen(self) -> None:
        try:
            for line in self.proc.stdout:
                with self._cond:
                    self._done.add(line.strip())
                    self._cond.notify_all()
        except (OSError, ValueError):
            pass
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify_all()

    def wait_for(self, group: str, timeout_s: float) -> bool:
        """Wait until the helper reports ``group`` (True), ends without it or ``timeout_s``
        passes (False)."""
        with self._cond:
            self._cond.wait_for(lambda: group in self._done or self._ended, timeout_s)
            return group in self._done


#: the helper of this process's run, while it runs (:func:`start` to :func:`finish`)
_active: list = [None]


def ready(group: str, timeout_s: float = WAIT_S) -> None:
    """Before this process first calls a group's kernels ("enumerate": the enumeration's first
    pass; "select": the selection's): when a helper is compiling them, wait for its report, so
    that they are loaded from the cache rather than compiled twice.  No helper: returns at once."""
    helper = _active[0]
    if helper is not None:
        helper.wait_for(group, timeout_s)


def cache_is_cold() -> bool:
    """True when the numba cache holds no entry of the enumeration's compiled kernel for this
    machine (:func:`starforge.runtime.kernels.compiled_here`)."""
    from starforge.stars.classify import classify_range

    return not compiled_here(classify_range)


def start() -> Helper | None:
    """Start the helper process when the cache is cold and there is a second core; None
    otherwise.  The caller ends it with :func:`finish`; meanwhile :func:`ready` waits for it."""
    if not cache_is_cold():
        return None
    from starforge.runtime.progress import note

    note(FIRST_RUN_NOTE)
    if (os.cpu_count() or 1) < 2:
        return None
    try:
        proc = subprocess.Popen(
            [sys.executable, "-c", "from starforge.stars.warmup import child_main; child_main()"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
    except OSError:
        return None
    adopt(proc.pid)  # ended with the command (starforge.runtime.procs.end_children)
    _active[0] = Helper(proc)
    return _active[0]


def finish(helper: Helper | None, timeout_s: float = 30.0) -> None:
    """Wait up to ``timeout_s`` for the helper (it is done long before a first run ends), then
    stop it; nothing is left running."""
    if helper is None:
        return
    if _active[0] is helper:
        _active[0] = None
    proc = helper.proc
    try:
        proc.wait(timeout=timeout_s) if timeout_s > 0 else None
    except subprocess.TimeoutExpired:
        pass
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    release(proc.pid)
    helper._listener.join(1.0)  # the pipe is at its end once the helper has exited
    if proc.stdout is not None:
        proc.stdout.close()  # not left to the garbage collector (a ResourceWarning)


def compile_fit_decision() -> None:
    """Compile (or load) the fit decision's one entry with the types the enumeration and the
    placement call it with."""
    import numpy as np

    from starforge.geometry.fit import decide_fit

    P = np.zeros((1, 4, 3))
    P[0, 1, 0] = P[0, 2, 1] = P[0, 3, 2] = 1.0
    decide_fit(P, np.array([2.0, 2.0, 2.0]))


def _helper() -> None:
    """The helper process: the enumeration's first pass and the selection's kernels, called on
    tiny inputs of the types ``stars`` uses, so that they land in the cache."""
    import numpy as np

    from starforge.stars import select as sel
    from starforge.stars.classify import assignment_table, classify_range, subsets_from

    assign = assignment_table()
    sub = np.array([[0, 1, 2, 3, 4, 5]], dtype=np.int16)
    codes = np.empty((1, len(assign)), dtype=np.int8)
    faces = np.zeros((6, 6, 6), dtype=np.int8)  # no claims (the pool indices of sub are < 6)
    classify_range(sub, assign, 10.0, 1.0, np.array([5.0, 10.0, 40.0]), 1.0, 0, faces, codes, 0, 1)
    subsets_from(8, 1, np.array([0, 1, 2, 3, 4, 5], dtype=np.int64), 2)
    _report("enumerate")
    # the selection, on two stars sharing rows: greedy, the packing, local search and the ILS
    from starforge.stars.rules import window_rows

    idx = np.array([[0, 1, 2, 3, 4, 5], [0, 1, 2, 3, 4, 6]], dtype=np.int16)
    star_of, row, n_rows = window_rows(idx, "face", 1, 8)
    ptr, rows = sel.csr_rows(star_of, row, len(idx))
    order = np.arange(len(idx))
    chosen = sel.greedy(order, ptr, rows, n_rows)
    chosen, _ = sel.local_search(chosen, order, ptr, rows, n_rows)
    sel.ils(chosen, order, ptr, rows, n_rows, iterations=1)


#: whether this process is the run's helper (:func:`_run`): only then is stdout the run's pipe
_reporting = [False]


def _report(group: str) -> None:
    """The helper tells the run that ``group``'s kernels are in the cache (its stdout is the
    run's pipe, not a user's terminal; :func:`_helper` called otherwise says nothing)."""
    if _reporting[0]:
        sys.stdout.write(group + "\n")
        sys.stdout.flush()


def child_main() -> None:
    """The helper process: :func:`_helper`, reporting each group as it lands in the cache.
    Without the cyclic garbage collector: numba's compiler builds many short-lived object
    graphs, and the collector's passes over them cost compile time; this short-lived process
    can afford the memory they hold instead."""
    import gc

    gc.disable()
    _reporting[0] = True
    _helper()
    _report("select")
