"""Progress by stage: what a long command is doing now, for whoever shows it.

The library reports to the process's reporter without knowing who shows it: a stage starts
when its work starts (:func:`stage`), its count moves as the work is done
(:meth:`Stage.update`), and a one-line note says what the user should know once (a first run
compiles its kernels: :func:`note`).  With no listener installed (a notebook, a test, a worker
process) every call is a cheap no-op.  The command line installs a listener
(:func:`reporting`) that draws a bar on a terminal or writes plain lines to a log.

A stage's estimate of the time left comes from its measured rate since its first count
(:meth:`Stage.eta_s`): the first count often carries a one-off cost (loading a kernel, the
first chunk's set-up), so the rate is taken over the counts after it.

>>> from starforge.runtime import progress
>>> with progress.stage("select", total=3) as s:
...     s.update(2)
>>> s.done, s.ended
(2, True)
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import contextmanager

__all__ = ["Stage", "Reporter", "stage", "note", "report", "reporting", "current"]


class Stage:
    """One named stage: its count (``done`` of ``total``; total None: not known ahead) and its
    clock.  ``unit`` names what is counted ("candidates", "bodies"; empty: plain counts).
    Updates and reads may come from several threads; each update is one assignment."""

    def __init__(
        self,
        reporter: Reporter | None,
        name: str,
        total: int | None,
        unit: str,
        clock,
        parallel: bool = False,
    ) -> None:
        self.reporter, self.name, self.unit, self.clock = reporter, name, unit, clock
        self.parallel = parallel
        self.total = None if total is None else int(total)
        self.done = 0
        self.started = clock()
        self.first: tuple[float, int] | None = None  # (time, done) at the first count
        self.last: tuple[float, int] | None = None  # (time, done) at the latest count
        self.ended = False

    def update(self, done: int | None = None, total: int | None = None, advance: int | None = None) -> None:
        """Set the count (``done``), the total, or add ``advance`` to the count."""
        if total is not None:
            self.total = int(total)
        if advance is not None:
            done = self.done + int(advance)
        if done is not None:
            now = self.clock()
            self.done = int(done)
            if self.first is None:
                self.first = (now, self.done)
            self.last = (now, self.done)
        if self.reporter is not None:
            self.reporter._changed(self)

    def elapsed_s(self) -> float:
        """Seconds since the stage started."""
        return self.clock() - self.started

    def rate(self) -> float | None:
        """Counts per second measured after the first count; None before a second count (the
        first one's time includes the stage's set-up, which says little of the rate after it)."""
        if self.first is None or self.last is None:
            return None
        (t0, d0), (t1, d1) = self.first, self.last
        if t1 > t0 and d1 > d0:
            return (d1 - d0) / (t1 - t0)
        return None

    def eta_s(self) -> float | None:
        """Seconds left at the measured rate (:meth:`rate`), counted from the latest count; None when
        the total or the rate is not known."""
        r = self.rate()
        if self.total is None or r is None or r <= 0 or self.last is None:
            return None
        left = max(self.total - self.done, 0) / r - (self.clock() - self.last[0])
        return max(left, 0.0)

    def end(self) -> None:
        """The stage's work is over (a listener stops drawing it)."""
        if self.ended:
            return
        self.ended = True
        if self.reporter is not None:
            self.reporter._ended(self)

    def __enter__(self) -> Stage:
        return self

    def __exit__(self, *exc) -> None:
        self.end()


class Reporter:
    """The stages of one command, passed on to a listener.

    A listener has ``started(stage)``, ``changed(stage)``, ``ended(stage)`` and ``note(text)``;
    they are called under this reporter's lock, from whichever thread reports.  Starting a
    stage ends every other open one unless it is ``parallel`` (work that runs beside the others:
    the STEP files while meshes and plates are made); a parallel stage ends on its own.
    """

    def __init__(self, listener, clock: Callable[[], float] = time.monotonic) -> None:
        self.listener, self.clock = listener, clock
        self.open: list[Stage] = []
        self.lock = threading.RLock()

    def stage(self, name: str, total: int | None = None, unit: str = "", parallel: bool = False) -> Stage:
        with self.lock:
            if not parallel:
                for s in [s for s in self.open if not s.parallel]:
                    s.end()
            st = Stage(self, name, total, unit, self.clock, parallel)
            self.open.append(st)
            self.listener.started(st)
            return st

    def note(self, text: str) -> None:
        with self.lock:
            self.listener.note(text)

    def close(self) -> None:
        with self.lock:
            for s in list(self.open):
                s.end()

    def _changed(self, st: Stage) -> None:
        with self.lock:
            if not st.ended:
                self.listener.changed(st)

    def _ended(self, st: Stage) -> None:
        with self.lock:
            if st in self.open:
                self.open.remove(st)
            self.listener.ended(st)


#: the process's reporter (None: nobody listens)
_current: list[Reporter | None] = [None]


def current() -> Reporter | None:
    """The installed reporter, or None."""
    return _current[0]


def stage(name: str, total: int | None = None, unit: str = "", parallel: bool = False) -> Stage:
    """Start stage ``name`` on the installed reporter (a stage nobody sees when none is installed);
    use it as a context manager, or call :meth:`Stage.end`."""
    rep = _current[0]
    if rep is None:
        return Stage(None, name, total, unit, time.monotonic)
    return rep.stage(name, total, unit, parallel)


def note(text: str) -> None:
    """A one-line note for the user (shown once, above any bar); nothing when nobody listens."""
    rep = _current[0]
    if rep is not None:
        rep.note(text)


def report(unit: str | dict[str, str] = "") -> Callable[..., None]:
    """A ``progress(stage_name, done, total)`` callback for library functions that take one: a new
    name starts that stage on the installed reporter, a known one updates it.  ``unit``: what
    every stage counts, or a unit per stage name."""
    held: list[Stage | None] = [None]

    def cb(name: str, done: int | None, total: int | None = None) -> None:
        st = held[0]
        if st is None or st.name != name or st.ended:
            st = held[0] = stage(name, total, unit.get(name, "") if isinstance(unit, dict) else unit)
        st.update(done, total)

    return cb


@contextmanager
def reporting(listener, clock: Callable[[], float] = time.monotonic):
    """Install a reporter that passes stages to ``listener`` for the ``with`` block (the one
    before it is restored after it); yields the reporter."""
    rep = Reporter(listener, clock)
    before = _current[0]
    _current[0] = rep
    try:
        yield rep
    finally:
        rep.close()
        _current[0] = before
