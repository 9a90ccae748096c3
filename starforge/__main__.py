"""``python -m starforge`` and the ``starforge`` console script: the signal handlers first, then
the CLI's imports (a Ctrl-C while they load ends in one line, not a traceback)."""

from starforge.runtime.procs import stop_early


def run() -> None:
    """The console script's entry point."""
    stop_early()
    from starforge.cli import main

    main()


if __name__ == "__main__":
    run()
