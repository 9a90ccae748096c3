"""``starforge`` command line: thin; parses, calls library functions, prints.

Every user-facing error (StarforgeError, ValueError, a missing or unreadable file) becomes one
line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

from starforge.cli._app import app

__all__ = ["app", "main"]

_loaded = False


def _load_commands() -> None:
    global _loaded
    if _loaded:
        return
    for mod in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
        importlib.import_module(f"{__name__}.{mod}")
    _loaded = True


def _on_sigint(signum, frame):
    from starforge.io import note_interrupt

    note_interrupt()  # remembered even where a library swallows the exception below
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point; returns (and exits with) the process exit code."""
    import signal
    import threading

    from starforge.io import interrupted, reset_interrupt

    _load_commands()
    reset_interrupt()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, _on_sigint)
    try:
        code = _run(argv)
        # every Ctrl-C ends here: raised, turned into click's Abort, or swallowed by a library
        # (nothing was published in any case: starforge.io.staged_output checks the flag)
        if interrupted() and code in (0, 130):
            print("interrupted; no output was changed", file=sys.stderr)
            code = 130
    finally:
        reset_interrupt()  # library calls after this command are not affected
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    if argv is None:
        sys.exit(code)
    return code


def _run(argv: list[str] | None) -> int:
    from starforge.io import note_interrupt

    try:
        rv = app(args=argv, prog_name="starforge", standalone_mode=False)
        code = rv if isinstance(rv, int) else 0
    except KeyboardInterrupt:
        note_interrupt()  # reported by main()
        code = 130
    except MemoryError:
        # every large allocation is estimated first (starforge.budget); this is the last resort
        print("error: out of memory; lower the problem size or the memory others use (--max-memory)",
              file=sys.stderr)
        code = 2
    except (ValueError, OSError) as exc:  # StarforgeError is a ValueError
        msg = str(exc) or exc.__class__.__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{msg}: {exc.filename}"
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
