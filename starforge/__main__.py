"""``python -m starforge`` and the ``starforge`` console script: the signal handlers first, then
the CLI's imports (a Ctrl-C while they load ends in one line, not a traceback).  ``import
starforge`` has set them already when the process is the command
(:func:`starforge.runtime.stop.stop_early_in_command`); a program that imports this module and
calls :func:`run` gets them here."""

from starforge.runtime.stop import stop_early


def run() -> None:
    """The console script's entry point."""
    stop_early()
    from starforge.cli import main

    main()


if __name__ == "__main__":
    run()
