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


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print ``error: message`` on stderr and return an Exit(code) to raise."""
    print(f"error: {message}", file=sys.stderr)
    return typer.Exit(code)


def console(stderr: bool = False):
    """A rich console (imported lazily)."""
    from rich.console import Console

    return Console(stderr=stderr, highlight=False)


def progress(transient: bool = True, disable: bool | None = None):
    """A rich Progress bar on stderr, off when stderr is not a terminal unless forced."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    if disable is None:
        disable = not sys.stderr.isatty()
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console(stderr=True),
        transient=transient,
        disable=disable,
    )


@app.callback(invoke_without_command=True)
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True),
    max_memory: str = typer.Option(
        None, "--max-memory", help="Memory any command may plan to use, e.g. 2G (default: half this machine's)."
    ),
    max_seconds: float = typer.Option(None, "--max-seconds", help="Time any command may plan to take, s (default 7200)."),
    scheduler: str = typer.Option(
        None,
        "--scheduler",
        help="Run parallel work (enumeration chunks, sweep cells) on the dask scheduler at this address "
        "(default: $STARFORGE_SCHEDULER; unset: this machine).",
    ),
) -> None:
    """Design optical motion-capture markers: unique marker-star families, printable bodies,
    prop marker placement and the files trackers load."""
    import os

    from starforge import budget

    if max_memory is not None:
        os.environ[budget.ENV_MEMORY] = str(budget.parse_bytes(max_memory, "--max-memory"))
    if max_seconds is not None:
        os.environ[budget.ENV_SECONDS] = repr(float(max_seconds))
        budget.time_limit_s()  # validates
    if scheduler:
        from starforge.engine import ENV_SCHEDULER

        os.environ[ENV_SCHEDULER] = scheduler
    if version:
        from starforge import __version__

        print(f"starforge {__version__}")
        raise typer.Exit(0)
    if ctx.invoked_subcommand is None:
        print(ctx.get_help())
        raise typer.Exit(0)
