"""``python -m starforge`` and the ``starforge`` console script: the signal handlers first, then
the CLI's imports (a Ctrl-C while they load ends in one line, not a traceback).  A command line
that exports STEP files launches its STEP worker before those imports, so that the worker's CAD
kernel loads while they do (:func:`starforge.cad.step_worker.start_early`)."""

import sys

from starforge.runtime.procs import stop_early


def exports_step(argv: list[str]) -> bool:
    """True when ``argv`` (the arguments after ``starforge``) runs ``export`` with STEP among its
    formats, judged from the words alone (the CLI is not loaded yet): ``export`` is the first
    word after any ``-q``, no help is asked for, and the last ``--format`` given, if any, names
    ``step`` (export's default formats do).  A wrong guess costs a worker that is never used."""
    words = list(argv)
    while words and words[0] in ("-q", "--quiet"):
        words.pop(0)
    if not words or words[0] != "export" or any(w in ("-h", "--help") for w in words):
        return False
    formats = None
    for i, w in enumerate(words):
        if w == "--format" and i + 1 < len(words):
            formats = words[i + 1]
        elif w.startswith("--format="):
            formats = w.split("=", 1)[1]
    return formats is None or "step" in (f.strip().lower() for f in formats.split(","))


def run() -> None:
    """The console script's entry point."""
    stop_early()
    if exports_step(sys.argv[1:]):
        from starforge.cad.step_worker import start_early

        try:
            start_early()
        except OSError:  # no process to spare: the export launches its own
            pass
    from starforge.cli import main

    main()


if __name__ == "__main__":
    run()
