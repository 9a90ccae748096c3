"""How the command line shows the library's progress (:mod:`starforge.runtime.progress`).

On a terminal a rich bar per open stage: its name, the count with thousands separators, the
time in the stage and the time left at the measured rate.  Off a terminal (a pipe, a log, CI)
one plain line when a stage starts and one every :data:`HEARTBEAT_S` seconds, from a thread, so
that work that never reports (a kernel compiling) still shows the process is alive.  Quiet:
nothing at all (errors are printed by :mod:`starforge.cli`).
"""

from __future__ import annotations

import os
import sys
import threading
import time

from starforge.words import singular

#: seconds between two plain progress lines (when stderr is not a terminal)
HEARTBEAT_S = 5.0

#: seconds a command runs before it writes plain lines: a short command (or one refused at
#: once) writes none, only its result or its one error line
HOLD_S = HEARTBEAT_S


def unit_of(n: int, unit: str) -> str:
    """A stage's unit (a plural noun, or ``""``) for a count of ``n``: ``" picture"`` for 1."""
    return f" {singular(unit) if n == 1 else unit}" if unit else ""


def count_text(st) -> str:
    """``"70,778,880/211,771,560 candidates (33 %)"``, ``"12 bodies"`` or ``""`` (nothing counted)."""
    if st.total:
        return f"{st.done:,}/{st.total:,}{unit_of(st.total, st.unit)} ({100 * st.done / st.total:.0f} %)"
    if st.done:
        return f"{st.done:,}{unit_of(st.done, st.unit)}"
    return ""


def eta_text(st) -> str:
    """``"about 24 s left"`` (rounded to what a person reads), or ``""`` when not known."""
    left = st.eta_s()
    if left is None or st.done == 0 or st.done >= st.total:  # counted out: the stage's wrap-up
        return ""
    if left < 60:
        return f"about {max(round(left), 1)} s left"
    if left < 3600:
        return f"about {round(left / 60)} min left"
    return f"about {left / 3600:.1f} h left"


def clock_text(st) -> str:
    """The time in the stage, ``"0:07"`` or ``"1:02:07"``: it moves every second while the
    stage runs, whether or not its count moves."""
    m, sec = divmod(int(st.elapsed_s()), 60)
    return f"{m // 60}:{m % 60:02d}:{sec:02d}" if m >= 60 else f"{m}:{sec:02d}"


def stage_text(st) -> str:
    """One stage's state in words: name, count, time left (or time in the stage)."""
    parts = [st.name]
    count = count_text(st)
    if count:
        parts.append(count)
    eta = eta_text(st)
    parts.append(eta if eta else f"{st.elapsed_s():.0f} s in")
    return f"{parts[0]}: {', '.join(parts[1:])}"


class Silent:
    """The listener of a quiet command: shows nothing."""

    def started(self, st) -> None:
        pass

    def changed(self, st) -> None:
        pass

    def ended(self, st) -> None:
        pass

    def note(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


_FORK_LOCK: list = []


def fork_safe_lock():
    """The plain lines' print lock, held across every ``os.fork`` of this process (registered
    once): a child forked while the heartbeat runs (the pictures' render processes) never
    inherits stderr's lock taken, so the heartbeat thread is safe to fork beside."""
    if not _FORK_LOCK:
        lock = threading.Lock()
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(
                before=lock.acquire, after_in_parent=lock.release, after_in_child=lock.release
            )
        _FORK_LOCK.append(lock)
    return _FORK_LOCK[0]


class Plain:
    """Plain lines on stderr, ``starforge COMMAND: N s, <state>``: one when a stage starts, one per
    note, and one every ``interval_s`` from a daemon thread (``working`` before any stage); a
    line the same as the one before is not repeated, and nothing is written in the first
    ``hold_s`` seconds (default :data:`HOLD_S`)."""

    def __init__(self, command: str, interval_s: float = HEARTBEAT_S, stream=None, hold_s: float | None = None) -> None:
        self.command, self.interval_s = command, interval_s
        self.hold_s = HOLD_S if hold_s is None else hold_s
        self.stream = stream
        self.t0 = time.monotonic()
        self.open: list = []
        self.last = ""
        self.lock = fork_safe_lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._beat, name="starforge-heartbeat", daemon=True)
        self.thread.fork_safe = True  # a process forked while it runs inherits no lock it holds
        self.thread.start()

    def _say(self, text: str, held: bool = True) -> None:
        seconds = time.monotonic() - self.t0
        if held and seconds < self.hold_s:  # the first heartbeat says where the command has got to
            return
        line = f"starforge {self.command}: {seconds:.0f} s, {text}"
        if line == self.last:  # nothing new to tell
            return
        self.last = line
        try:
            with self.lock:  # never forked half-way through a line (stderr's lock held)
                print(line, file=self.stream or sys.stderr, flush=True)
        except (OSError, ValueError):  # stderr closed: nobody is reading
            self.stop.set()

    def state(self) -> str:
        return "; ".join(stage_text(st) for st in list(self.open)) or "working"

    def _beat(self) -> None:
        while not self.stop.wait(self.interval_s):
            self._say(self.state())

    def started(self, st) -> None:
        self.open.append(st)
        total = f", {st.total:,}{unit_of(st.total, st.unit)}" if st.total else ""
        self._say(f"{st.name} started{total}")

    def changed(self, st) -> None:
        pass  # read by the heartbeat

    def ended(self, st) -> None:
        if st in self.open:
            self.open.remove(st)

    def note(self, text: str) -> None:
        self._say(f"note: {text}", held=False)

    def close(self) -> None:
        self.stop.set()
        if self.thread is not threading.current_thread():
            self.thread.join(timeout=1.0)


class Bars:
    """Rich bars on stderr's terminal, one per open stage; a stage's bar goes when it ends, and
    the display with the last one (what the command prints next starts on a clean line)."""

    def __init__(self) -> None:
        self.live = None
        self.tasks: dict = {}

    def _start(self):
        from rich.console import Console
        from rich.progress import BarColumn, Progress, ProgressColumn, TextColumn
        from rich.text import Text

        class _Count(ProgressColumn):
            def render(self, task) -> Text:
                return Text(count_text(task.fields["stage"]))

        class _Clock(ProgressColumn):  # rich's own stops when the count reaches the total
            def render(self, task) -> Text:
                return Text(clock_text(task.fields["stage"]))

        class _Eta(ProgressColumn):
            def render(self, task) -> Text:
                return Text(eta_text(task.fields["stage"]))

        self.live = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            _Count(),
            _Clock(),
            _Eta(),
            console=Console(stderr=True, highlight=False),
            transient=True,
        )
        self.live.start()

    def started(self, st) -> None:
        if self.live is None:
            self._start()
        self.tasks[id(st)] = self.live.add_task(st.name, total=st.total or None, completed=st.done, stage=st)

    def changed(self, st) -> None:
        task = self.tasks.get(id(st))
        if task is not None:  # no total (or 0): a moving bar, not a full one
            self.live.update(task, total=st.total or None, completed=st.done)

    def ended(self, st) -> None:
        task = self.tasks.pop(id(st), None)
        if task is not None:
            self.live.remove_task(task)
        if not self.tasks:  # no stage open: the bars go before the command prints its result
            self.close()

    def note(self, text: str) -> None:
        if self.live is not None:
            self.live.console.print(f"note: {text}", markup=False, highlight=False)
        else:
            print(f"note: {text}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None


def listener_for(command: str, quiet: bool, interval_s: float = HEARTBEAT_S):
    """Nothing when ``quiet``; rich bars on a terminal; else plain lines."""
    if quiet:
        return Silent()
    if sys.stderr.isatty():
        return Bars()
    return Plain(command, interval_s)
