"""``starforge`` command line: thin; parses, calls library functions, prints.

Every user-facing error (StarforgeError, ValueError, a missing or unreadable file) becomes one
line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

from starforge.cli._app import app
from starforge.runtime import process

__all__ = ["app", "click_command", "main"]

_command = None


def click_command():
    """The click command of the whole CLI, every command module loaded: what ``starforge --help``
    and ``starforge COMMAND --help`` print, for tools that document the commands (the docs'
    generated command pages), and what :func:`main` runs.  Built once per process: typer builds
    it by reading every command function's signature and type hints, which costs more than
    most refusals take."""
    global _command
    if _command is None:
        import typer.main

        for mod in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
            importlib.import_module(f"{__name__}.{mod}")
        _command = typer.main.get_command(app)
    return _command


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point; returns (and exits with) the process exit code."""
    command = click_command()
    with process.command() as cmd:
        code = cmd.finish(_run(command, argv))
    if argv is None:  # the console script: the process ends here
        process.end_process(code)
    return code


def _run(command, argv: list[str] | None) -> int:
    from starforge.io import interrupted, note_interrupt

    try:
        rv = command.main(args=argv, prog_name="starforge", standalone_mode=False)
        code = rv if isinstance(rv, int) else 0
    except KeyboardInterrupt:
        note_interrupt()  # reported by main()
        code = 130
    except MemoryError:
        if interrupted():  # an allocation cut short by the Ctrl-C: the stop, not a shortage
            return 130
        # every large allocation is estimated first (starforge.runtime.budget); this is the last resort
        print("error: out of memory; lower the problem size or the memory others use (--max-memory)",
              file=sys.stderr)
        code = 2
    except Exception as exc:
        if not interrupted():
            return _error_code(exc, sys.argv[1:] if argv is None else [str(a) for a in argv])
        # a library turned the Ctrl-C into its own error (OCP's import: "initialization failed")
        code = 130
    return code


def _error_code(exc: Exception, argv: list[str]) -> int:
    """The exit code of an exception that is not a Ctrl-C, after printing its one line (a
    parameter it starts with named by the option the user typed: ``argv``)."""
    from starforge.cli._args import as_typed
    from starforge.io import note_interrupt

    try:
        raise exc
    except (ValueError, OSError) as exc:  # StarforgeError is a ValueError
        msg = str(exc) or exc.__class__.__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{msg}: {exc.filename}"
        msg = as_typed(msg, click_command(), argv)
        print(f"error: {msg}", file=sys.stderr)
        code = 2
    except Exception as exc:
        # click's (or typer's vendored click's) control-flow exceptions, matched by shape so
        # that both layouts work: Exit carries exit_code, usage errors also know how to show().
        name = type(exc).__name__
        if name == "Abort":  # click turns Ctrl-C (KeyboardInterrupt) into Abort
            note_interrupt()  # reported by main()
            code = 130
        elif hasattr(exc, "show") and hasattr(exc, "exit_code"):
            if exc.exit_code == 0:
                exc.show()
                code = 0
            else:  # a usage error: one line, naming the option and where to read more
                ctx = getattr(exc, "ctx", None)
                where = f" (see `{ctx.command_path} --help`)" if ctx is not None else ""
                text = " ".join(str(exc.format_message()).split())
                print(f"error: {text}{where}", file=sys.stderr)
                code = 2
        elif name == "Exit" and hasattr(exc, "exit_code"):
            code = exc.exit_code
        else:
            raise
    return code
