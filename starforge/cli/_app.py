"""The Typer application object and the shared helpers of the command modules.

Command modules (``starforge/cli/<name>.py``) import ``app`` from here and register with
``@app.command()``; :func:`starforge.cli.main` imports every such module.  Keep module
top-levels light: heavy imports go inside the command functions.
"""

from __future__ import annotations

import sys

import typer

from starforge.cli._args import QUIET, RootGroup
from starforge.runtime.budget import DEFAULT_SECONDS, MEMORY_FRACTION

app = typer.Typer(
    cls=RootGroup,
    name="starforge",
    help="Design optical motion-capture markers: unique marker-star families, printable bodies, "
    "prop marker placement and the files trackers load.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``error: message`` on stderr and return an Exit(code) to raise."""
    print(f"error: {message}", file=sys.stderr)
    return typer.Exit(code)


def console(stderr: bool = False):
    """A rich console (imported lazily)."""
    from rich.console import Console

    return Console(stderr=stderr, highlight=False)


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


#: ``--mount`` of the commands that write a family.json of a lab's bodies (convert, measure)
FAMILY_MOUNT = typer.Option(
    "flat",
    "--mount",
    help="Mount the family.json's bodies are printed with (`starforge mounts`); its room is added to the "
    "family's size limit so `starforge export` builds them.",
)

SCHEDULER_HELP = (
    "Run parallel work (enumeration chunks, sweep cells, placements) on the dask scheduler at this "
    "address: tcp://HOST:PORT, HOST:PORT or HOST (default: $STARFORGE_SCHEDULER; unset: this machine)."
)


@app.callback(invoke_without_command=True)
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True),
    max_memory: str = typer.Option(
        None, "--max-memory", help=f"Memory any command may plan to use, e.g. 2G (default: {MEMORY_FRACTION:.0%} of this machine's; also accepted after the command)."
    ),
    quiet: bool = typer.Option(
        False, "--quiet", "-q", help="Print nothing but errors (also accepted after the command)."
    ),
    max_seconds: float = typer.Option(None, "--max-seconds", help=f"Time any command may plan to take, s (default {DEFAULT_SECONDS:g}; also accepted after the command)."),
    scheduler: str = typer.Option(
        None,
        "--scheduler",
        help=SCHEDULER_HELP + " Also accepted after the command.",
    ),
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
    _show_progress(ctx, quiet or bool(ctx.meta.get(QUIET)))


#: the stage a command is in from its start to its first own stage
LOAD_STAGE = "load"


def _show_progress(ctx: typer.Context, quiet: bool) -> None:
    """Install the listener of the library's progress (:mod:`starforge.cli._progress`) until the
    command ends, with stage ``load`` open (the command's libraries and inputs) until the
    command's first stage starts."""
    from starforge.cli._progress import listener_for
    from starforge.runtime.progress import reporting, stage

    listener = listener_for(ctx.invoked_subcommand, quiet)
    installed = reporting(listener)
    installed.__enter__()
    stage(LOAD_STAGE)

    def close() -> None:
        installed.__exit__(None, None, None)
        listener.close()

    ctx.call_on_close(close)
