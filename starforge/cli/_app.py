"""The Typer application object and the shared helpers of the command modules.

Command modules (``starforge/cli/<name>.py``) import ``app`` from here and register with
``@app.command()``; :func:`starforge.cli.main` imports every such module.  Keep module
top-levels light: heavy imports go inside the command functions.
"""

from __future__ import annotations

import sys

import typer

app = typer.Typer(
    name="starforge",
    help="Design optical motion-capture markers: unique marker-star families, printable bodies, "
    "prop marker placement and the files trackers load.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


#: set by a command that allows the process to end without the interpreter's teardown
#: (:func:`allow_quick_exit`); read by :func:`starforge.cli.main`
_quick_exit = [False]


def allow_quick_exit() -> None:
    """Let the process end without the interpreter's teardown once this command returns
    (:func:`starforge.cli.main`): for a command whose every output is written, closed and
    published (``starforge.io``) by the time it returns, and that leaves no thread of its own
    running."""
    _quick_exit[0] = True


#: whether the cyclic garbage collector ran before :func:`pause_gc` turned it off
_gc_was = [None]


def pause_gc() -> None:
    """Turn Python's cyclic garbage collector off until the command returns (
    :func:`starforge.cli.main` turns it back on): for a short command whose objects are nearly all
    acyclic and freed by reference counting.  The collector's passes over the heap of numba,
    scipy and trimesh while they are imported and numba's target is set up cost 0.1-0.3 s of the
    main process's CPU in a ``starforge place`` run (measured on a loaded machine: medians 1.85
    vs 1.52 s with the collector off from the start), for a few hundred kB of cycles reclaimed."""
    import gc

    if _gc_was[0] is None:
        _gc_was[0] = gc.isenabled()
    gc.disable()


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``error: message`` on stderr and return an Exit(code) to raise."""
    print(f"error: {message}", file=sys.stderr)
    return typer.Exit(code)


def console(stderr: bool = False):
    """A rich console (imported lazily)."""
    from rich.console import Console

    return Console(stderr=stderr, highlight=False)


def progress(transient: bool = True, disable: bool | None = None):
    """Progress on stderr: a rich bar on a terminal; otherwise (a pipe, a log file, CI) the
    heartbeat's plain line every few seconds shows the task's state (:class:`PlainProgress`)."""
    if disable is None and not sys.stderr.isatty():
        return PlainProgress()
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console(stderr=True),
        transient=transient,
        disable=bool(disable),
    )


#: seconds between two plain progress lines (when stderr is not a terminal)
HEARTBEAT_S = 5.0

#: what the command is doing now, read by the heartbeat: [description, done, total]
_state: list = ["working", None, None]


class PlainProgress:
    """The part of rich's Progress API the commands use; it only records the state, which the
    heartbeat (:func:`start_heartbeat`) prints as a plain line every few seconds."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        _state[:] = ["working", None, None]

    def add_task(self, description: str, total=None, **_) -> int:
        _state[:] = [description, 0, total]
        return 0

    def update(self, task, description=None, completed=None, total=None, advance=None, **_) -> None:
        if description is not None:
            _state[0] = description
        if total is not None:
            _state[2] = total
        if completed is not None:
            _state[1] = completed
        if advance is not None:
            _state[1] = (_state[1] or 0) + advance

    def advance(self, task, advance: float = 1) -> None:
        self.update(task, advance=advance)


def _state_line(command: str, seconds: float) -> str:
    what, done, total = _state
    text = f"starforge {command}: {seconds:.0f} s, {what}"
    if done is not None and total:
        text += f" {done:,}/{total:,} ({100 * done / total:.0f} %)"
    elif done:
        text += f" {done:,}"
    return text


_FORK_LOCK: list = []


def _fork_safe_lock():
    """The heartbeat's print lock, held across every ``os.fork`` of this process (registered
    once): a child forked while the heartbeat runs (the pictures' render processes) never
    inherits stderr's lock taken, so the heartbeat thread is safe to fork beside."""
    import os
    import threading

    if not _FORK_LOCK:
        lock = threading.Lock()
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(before=lock.acquire, after_in_parent=lock.release, after_in_child=lock.release)
        _FORK_LOCK.append(lock)
    return _FORK_LOCK[0]


def start_heartbeat(command: str, interval_s: float = HEARTBEAT_S):
    """Print a plain progress line on stderr every ``interval_s`` until the returned stop function
    is called: long work (numba's first compile included) shows progress without a terminal."""
    import threading
    import time

    stop = threading.Event()
    t0 = time.monotonic()
    _state[:] = ["working", None, None]
    lock = _fork_safe_lock()

    def beat() -> None:
        while not stop.wait(interval_s):
            try:
                with lock:  # never forked half-way through a line (stderr's lock held)
                    print(_state_line(command, time.monotonic() - t0), file=sys.stderr, flush=True)
            except (OSError, ValueError):  # stderr closed: nobody is reading
                return

    th = threading.Thread(target=beat, name="starforge-heartbeat", daemon=True)
    th.fork_safe = True  # a process forked while it runs inherits no lock it holds (see above)
    th.start()

    def stop_fn() -> None:
        stop.set()
        th.join(timeout=1.0)

    return stop_fn


def use_scheduler(scheduler: str | None, probe: bool = True) -> None:
    """Check the scheduler address (``--scheduler``, before or after the command, else
    ``STARFORGE_SCHEDULER``) before any work starts and hand it to the engine through the
    environment; with ``probe`` (the commands that run on it) also check, within seconds, that
    a dask scheduler answers there.  StarforgeError in one line otherwise."""
    import os

    from starforge.runtime import address

    if scheduler:
        os.environ[address.ENV_SCHEDULER] = address.parse_address(scheduler)
    addr = address.scheduler_address()
    if probe and addr is not None and addr not in _probed:
        address.probe(addr)
        _probed.add(addr)


#: scheduler addresses that answered as dask schedulers in this process
_probed: set = set()


SCHEDULER_HELP = (
    "Run parallel work (enumeration chunks, sweep cells, placements) on the dask scheduler at this "
    "address: tcp://HOST:PORT, HOST:PORT or HOST (default: $STARFORGE_SCHEDULER; unset: this machine)."
)


@app.callback(invoke_without_command=True)
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True),
    max_memory: str = typer.Option(
        None, "--max-memory", help="Memory any command may plan to use, e.g. 2G (default: half this machine's)."
    ),
    max_seconds: float = typer.Option(None, "--max-seconds", help="Time any command may plan to take, s (default 7200)."),
    scheduler: str = typer.Option(None, "--scheduler", help=SCHEDULER_HELP),
) -> None:
    """Design optical motion-capture markers: unique marker-star families, printable bodies,
    prop marker placement and the files trackers load."""
    import os

    from starforge.runtime import budget

    if max_memory is not None:
        os.environ[budget.ENV_MEMORY] = str(budget.parse_bytes(max_memory, "--max-memory"))
    if max_seconds is not None:
        os.environ[budget.ENV_SECONDS] = repr(budget.parse_seconds(max_seconds, "--max-seconds"))
    use_scheduler(scheduler, probe=False)  # checked here; reached by the commands that use it
    if version:
        from starforge import __version__

        print(f"starforge {__version__}")
        raise typer.Exit(0)
    if ctx.invoked_subcommand is None:
        print(ctx.get_help())
        raise typer.Exit(0)
    if not sys.stderr.isatty():  # a pipe or a log: plain progress lines every few seconds
        ctx.call_on_close(start_heartbeat(ctx.invoked_subcommand))
