"""Progress of an engine job (:mod:`starforge.runtime.engine`) on the terminal, or as plain lines."""

from __future__ import annotations

from contextlib import contextmanager

from starforge.cli._app import console, progress


@contextmanager
def job_progress(label: str, noun: str, total: int, quiet: bool):
    """Yield ``(tick, where)`` for :func:`starforge.runtime.engine.map_tasks`'s ``progress`` and
    ``on_plan``: a progress bar on a terminal, else the heartbeat's plain line every few seconds
    (:func:`starforge.cli._app.progress`, for logs); ``where`` says once where the tasks run.
    ``quiet``: neither."""
    say = console(stderr=True)
    with progress(disable=True if quiet else None) as bar:
        task = bar.add_task(noun, total=total)

        def tick(done: int, n: int) -> None:
            bar.update(task, completed=done, total=n)

        def where(plan) -> None:
            if not quiet:
                say.print(f"{label}: {total} {noun} on {plan.describe()}")

        yield tick, where
