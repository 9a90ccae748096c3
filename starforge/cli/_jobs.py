"""Progress of an engine job (:mod:`starforge.runtime.engine`) on the terminal, or as plain lines."""

from __future__ import annotations

from contextlib import contextmanager

from starforge.cli._app import console
from starforge.runtime import progress


@contextmanager
def job_progress(label: str, noun: str, total: int, quiet: bool):
    """Yield ``(tick, where)`` for :func:`starforge.runtime.engine.map_tasks`'s ``progress`` and
    ``on_plan``: stage ``label`` counting ``noun`` (:mod:`starforge.runtime.progress`); ``where``
    says once where the tasks run.  ``quiet``: nothing is said."""
    say = console(stderr=True)
    with progress.stage(label, total=total, unit=noun) as st:

        def tick(done: int, n: int) -> None:
            st.update(done, n)

        def where(plan) -> None:
            if not quiet:
                say.print(f"{label}: {total:,} {noun} on {plan.describe()}")

        yield tick, where
