"""Progress of an engine job (:mod:`starforge.engine`) on the terminal, or as plain lines."""

from __future__ import annotations

from contextlib import contextmanager

from starforge.cli._app import console, progress


@contextmanager
def job_progress(label: str, noun: str, total: int, quiet: bool):
    """Yield ``(tick, where)`` for :func:`starforge.engine.map_tasks`'s ``progress`` and
    ``on_plan``: a progress bar on a terminal, else a plain line per tenth of the tasks (for
    logs); ``where`` says once where the tasks run.  ``quiet``: neither."""
    say = console(stderr=True)
    with progress() as bar:
        task = bar.add_task(noun, total=total)
        plain = bar.disable and not quiet

        def tick(done: int, n: int) -> None:
            bar.update(task, completed=done, total=n)
            if plain and (done == n or done % max(1, n // 10) == 0):
                say.print(f"{label}: {done}/{n} {noun} done")

        def where(plan) -> None:
            if not quiet:
                say.print(f"{label}: {total} {noun} on {plan.describe()}")

        yield tick, where
