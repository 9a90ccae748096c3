"""The one engine for parallel work: independent pure tasks on dask.distributed, or in process.

Every parallel job of starforge (sweep cells, enumeration chunks, batch placements) is a list
of tasks ``fn(item)``: ``fn`` a module-level function, ``item`` a small picklable value, the
result a compact value (arrays, a few rows).  :func:`map_tasks` runs them and returns the
results **in item order**, whatever the number of workers and whichever finishes first, so
the output is the same byte for byte on one process, on this machine's cores or on a cluster.

Where the tasks run (:func:`plan`):

* ``--scheduler ADDRESS`` (or the environment variable ``STARFORGE_SCHEDULER``): an existing
  dask cluster (``dask scheduler`` / ``dask worker``, dask-jobqueue, dask-kubernetes).
* otherwise, when the estimated work is at least :data:`LOCAL_CLUSTER_SECONDS` and more than
  one worker is allowed: a local cluster sized to this machine (one single-threaded worker
  process per core, TCP on loopback), started for the run and closed after it.
* otherwise in this process, one task after another: starting a local cluster costs seconds
  (2-4 s measured here for 2 workers), more than a small job takes.

Memory: each task's peak is estimated before submission and must fit one worker thread's
share of its worker's memory limit (local cluster: the command's memory budget,
:mod:`starforge.runtime.budget`, divided among the workers); otherwise the run is refused in one line.
Local workers run one task at a time, so the estimates bound what each worker holds.

Faults: the address is parsed before anything connects, and a raw handshake with a bounded wait
tells a dask scheduler from an endpoint that is not one (an HTTP server, a silent listener, a
closed port, an unreachable host) before dask's client, which retries for its whole timeout, is
started (:mod:`starforge.runtime.address`).  A worker that dies mid-run has its
tasks rerun elsewhere by the scheduler (the results are pure, so nothing changes); a cluster
left without workers for :data:`NO_WORKERS_S`, or a scheduler out of reach for
:data:`LOST_SCHEDULER_S`, ends the run.  Each of these raises
:class:`~starforge.errors.StarforgeError` with one line; callers publish nothing then, and dask's
and asyncio's own reports of the same event are silenced (:func:`dask_quiet`).

Progress: ``progress(done, total)`` after each finished task; and one plain log line per
roughly 10 % on the ``starforge.runtime.engine`` logger.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from starforge.errors import StarforgeError
from starforge.runtime.address import ENV_SCHEDULER, probe, scheduler_address
from starforge.runtime.threads import threads_for_task

#: estimated single-core work (s) from which a local cluster is started (below: in process)
LOCAL_CLUSTER_SECONDS = 20.0
#: seconds to wait when connecting to a scheduler, and for its first worker
CONNECT_TIMEOUT_S = 5.0
#: seconds a running job waits for a cluster left with no worker before it gives up
NO_WORKERS_S = 10.0
#: seconds a running job waits for a scheduler that stopped answering before it gives up
LOST_SCHEDULER_S = 5.0

log = logging.getLogger("starforge.runtime.engine")


#: the share of a worker's memory a task may plan on (dask's nanny terminates at 0.95)
USABLE_SHARE = 0.9


@dataclass(frozen=True)
class Plan:
    """Where a job runs.

    mode : "serial" (in this process), "local" (a local cluster started for the job) or
           "remote" (an existing scheduler)
    workers : int                 worker threads that run tasks at once
    task_bytes : float            one worker thread's share of memory, bytes (a local cluster's
                                  per-worker limit); a task may plan on :attr:`usable_bytes`
    address : str or None         the scheduler's address (remote)
    """

    mode: str
    workers: int
    task_bytes: float
    address: str | None = None

    @property
    def usable_bytes(self) -> float:
        """What one task may plan to use: a margin under the share, because a dask nanny
        restarts a worker at 95 % of its limit (and pauses it at 80 %)."""
        return self.task_bytes * USABLE_SHARE

    def describe(self) -> str:
        if self.mode == "serial":
            return "in process"
        if self.mode == "local":
            return f"a local dask cluster of {self.workers} worker processes"
        return f"the dask cluster at {self.address} ({self.workers} worker threads)"


def local_workers(workers: int | None = None) -> int:
    """Worker processes of a local cluster: ``workers`` or every core."""
    return max(1, int(workers) if workers else (os.cpu_count() or 1))


def plan(
    n_tasks: int,
    seconds: float = math.inf,
    workers: int | None = None,
    scheduler: str | None = None,
    client=None,
) -> Plan:
    """Decide where ``n_tasks`` tasks of about ``seconds`` single-core seconds in all run (see
    the module docstring).  ``client``: a connected client, for a remote plan's capacity."""
    from starforge.runtime.budget import memory_limit_bytes

    if threads_for_task() == 1:  # a task's own parallel work stays in its worker (never nested)
        return Plan("serial", 1, float(memory_limit_bytes()))
    addr = scheduler_address(scheduler)
    if addr is not None:
        if client is None:
            return Plan("remote", 1, math.inf, addr)
        threads, per_thread = cluster_capacity(client)
        return Plan("remote", threads, per_thread, addr)
    w = min(local_workers(workers), max(1, n_tasks))
    if w == 1 or seconds < LOCAL_CLUSTER_SECONDS:
        return Plan("serial", 1, float(memory_limit_bytes()))
    return Plan("local", w, memory_limit_bytes() / w)


@contextlib.contextmanager
def dask_quiet(on: bool = True):
    """dask's own connection, reconnect and shutdown chatter silenced (``on``) for the block:
    our one line says what went wrong."""
    if on:
        import distributed  # noqa: F401  (its import configures its loggers: silenced after it)
    loggers = _chatty_loggers()
    levels = [q.level for q in loggers]
    if on:
        for q in loggers:
            q.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        if not _silenced[0]:
            for q, level in zip(loggers, levels, strict=True):
                q.setLevel(level)


#: the loggers of dask's client and the event loop it runs on (and their children, which dask
#: configures with levels of their own): connection errors, reconnects, and "Task exception
#: was never retrieved" after a scheduler went away
_CHATTY = ("distributed", "asyncio", "tornado")
_silenced = [False]


def _chatty_loggers() -> list[logging.Logger]:
    names = [n for n in list(logging.root.manager.loggerDict) if n.split(".")[0] in _CHATTY]
    return [logging.getLogger(n) for n in sorted(set(names) | set(_CHATTY))]


def silence_dask() -> None:
    """Silence dask's and asyncio's loggers for the rest of the process (the CLI: its one line
    says what went wrong; their reports come also while the client shuts down, after the
    command's own error)."""
    _silenced[0] = True
    for q in _chatty_loggers():
        q.setLevel(logging.CRITICAL + 1)


def plan_with_capacity(n_tasks: int, seconds: float = math.inf, workers: int | None = None, scheduler: str | None = None) -> Plan:
    """:func:`plan`, with a remote cluster's real size and memory (a short connection), for
    choices that depend on them before any task exists (a sweep's ``--exhaustive auto``)."""
    p = plan(n_tasks, seconds, workers, scheduler)
    if p.mode != "remote":
        return p
    with dask_quiet():
        client = _connect(p.address)
        try:
            return plan(n_tasks, seconds, workers, scheduler, client=client)
        finally:
            _close(client)


def cluster_capacity(client) -> tuple[int, float]:
    """(worker threads, the smallest memory one thread may use) of a connected cluster."""
    from starforge.runtime.budget import memory_limit_bytes

    info = client.scheduler_info()
    workers = info.get("workers", {})
    threads = sum(int(w.get("nthreads", 1)) for w in workers.values())
    shares = [
        (w.get("memory_limit") or memory_limit_bytes()) / max(1, int(w.get("nthreads", 1)))
        for w in workers.values()
    ]
    return max(1, threads), (min(shares) if shares else float(memory_limit_bytes()))


def require_task_memory(task_bytes: Sequence[float], p: Plan, what: str, advice: str) -> None:
    """Refuse in one line when the largest task does not fit one worker thread's memory."""
    from starforge.runtime.budget import format_bytes

    if not len(task_bytes):
        return
    worst = max(range(len(task_bytes)), key=lambda i: task_bytes[i])
    need = float(task_bytes[worst])
    if not need <= p.usable_bytes:
        raise StarforgeError(
            f"{what}: task {worst} needs about {format_bytes(need)} of memory, above the "
            f"{format_bytes(p.usable_bytes)} a task on each worker of {p.describe()} may use; {advice}"
        )


def _connect(addr: str):
    """A client of the scheduler at ``addr``, after :func:`probe`, with at least one worker; every
    wait bounded (:data:`CONNECT_TIMEOUT_S`)."""
    probe(addr, CONNECT_TIMEOUT_S)
    from distributed import Client

    try:
        client = Client(addr, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
    except Exception as exc:  # noqa: BLE001  (any failure of dask's handshake is the same one line)
        raise StarforgeError(
            f"cannot connect to the dask scheduler at {addr} ({type(exc).__name__}: {_first_line(exc)}); "
            f"check that its dask version matches this one's, or unset --scheduler / {ENV_SCHEDULER}"
        ) from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except Exception:  # noqa: BLE001  (a timeout, or the scheduler gone meanwhile)
        _close(client)
        raise StarforgeError(
            f"the dask scheduler at {addr} has no workers; start some with `dask worker {addr}`"
        ) from None
    return client


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:120] if text else "no message"


def _close(client) -> None:
    """Close a client without waiting long for a scheduler that is gone."""
    try:
        client.close(timeout=2)
    except Exception:  # noqa: BLE001  (closing a lost connection: nothing left to report)
        pass


#: the warning filter handed to multiprocessing's resource tracker (it takes this process's -W
#: options when it starts): a run stopped by a signal ends at once, and the tracker then frees
#: the semaphores of the local cluster's process pool itself, with a warning per run that says so
_TRACKER_QUIET = "ignore::UserWarning:multiprocessing.resource_tracker"


def _local_cluster(p: Plan):
    import sys

    from distributed import Client, LocalCluster

    if _TRACKER_QUIET not in sys.warnoptions:
        sys.warnoptions.append(_TRACKER_QUIET)

    cluster = LocalCluster(
        n_workers=p.workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        # the scheduler's HTTP routes (/health, /metrics) on a free port: the default 8787 may be
        # taken (a notebook's cluster, a second starforge run), which dask reports as a warning
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        memory_limit=int(p.task_bytes),
        # a task's own error comes back to the client as raised (one line from the CLI); the
        # worker's log of it, with its traceback, would come first on the same stderr
        silence_logs=logging.CRITICAL + 1,
    )
    return cluster, Client(cluster, set_as_default=False)


class _Progress:
    def __init__(self, total: int, label: str, progress):
        self.total, self.label, self.progress = total, label, progress
        self.done, self.next_log = 0, 0.1

    def tick(self) -> None:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total)
        if self.done / max(1, self.total) >= self.next_log or self.done == self.total:
            log.info("%s: %d/%d done", self.label, self.done, self.total)
            while self.next_log <= self.done / max(1, self.total):
                self.next_log += 0.1


def map_tasks(
    fn: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    task_bytes: Sequence[float] | float | None = None,
    seconds: float = math.inf,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    what: str = "tasks",
    advice: str = "use smaller pieces of work",
    on_plan: Callable[[Plan], None] | None = None,
    consume: Callable[[int, Any], None] | None = None,
    overlap: int = 1,
) -> list:
    """``[fn(x) for x in items]``, run where :func:`plan` decides; results in item order.

    With ``consume``, each result is handed to ``consume(i, result)`` as it arrives (in
    completion order; the caller makes what it builds independent of that order) and is not
    kept, so the client holds one result at a time; the list returned is then empty.

    Parameters
    ----------
    fn : callable
        A module-level (picklable) pure function of one item.
    items : sequence
        Small picklable inputs, one per task.
    task_bytes : sequence of float, float or None
        Estimated peak memory of each task (or of every task), bytes; checked against one
        worker's share before anything is submitted.
    seconds : float
        Estimated single-core seconds of all tasks together (decides in process vs a cluster).
    workers : int or None
        Local worker processes (default: every core); 1 runs in process.
    scheduler : str or None
        Address of an existing dask scheduler (default: ``STARFORGE_SCHEDULER``, else local).
    progress : callable or None
        ``progress(done, total)`` after each finished task.
    what, advice : str
        The job and what to change, for the one-line refusals.
    on_plan : callable or None
        Called with the :class:`Plan` before the first task (to tell the user where it runs).
    consume : callable or None
        ``consume(i, result)`` per finished task instead of collecting the results.
    overlap : int
        In process, up to this many tasks at once, on threads (default 1: one after another).
        For tasks that spend most of their time in compiled kernels releasing the GIL on every
        core: the single-threaded numpy work between one task's kernels then runs beside
        another task's kernels instead of leaving the other cores idle.  The memory check
        counts each task ``overlap`` times.  Results do not depend on it (each task is a pure
        function; with ``consume`` they arrive in completion order, as on a cluster).
    """
    items = list(items)
    n = len(items)
    if task_bytes is None:
        tb = [0.0] * n
    elif isinstance(task_bytes, (int, float)):
        tb = [float(task_bytes)] * n
    else:
        tb = [float(x) for x in task_bytes]
    p = plan(n, seconds, workers, scheduler)
    client = cluster = None
    with dask_quiet(p.mode != "serial"):
        try:
            if p.mode == "remote":
                client = _connect(p.address)
                p = plan(n, seconds, workers, scheduler, client=client)
            k = max(1, min(int(overlap), n)) if p.mode == "serial" else 1
            require_task_memory([b * k for b in tb], p, what, advice)
            if on_plan is not None:
                on_plan(p)
            ticker = _Progress(n, what, progress)
            if k > 1:
                return _overlapped(fn, items, ticker, consume, k)
            if p.mode == "serial":
                out = []
                for i, x in enumerate(items):
                    res = fn(x)
                    if consume is None:
                        out.append(res)
                    else:
                        consume(i, res)
                    del res
                    ticker.tick()
                return out
            if p.mode == "local":
                cluster, client = _local_cluster(p)
            return _run_on(client, fn, items, ticker, p, consume)
        finally:
            if client is not None:
                _close(client)
            if cluster is not None:
                with contextlib.suppress(Exception):
                    cluster.close(timeout=5)


def _overlapped(fn, items, ticker: _Progress, consume, k: int) -> list:
    """:func:`map_tasks` in process with ``k`` tasks at once on threads, the next item started
    as one finishes (so at most ``k`` are held in memory).  An exception (Ctrl-C included)
    cancels the tasks not started and is raised."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    out: list = [None] * len(items) if consume is None else []
    todo = iter(enumerate(items))
    ex = ThreadPoolExecutor(k)
    try:
        running = {ex.submit(fn, x): i for i, x in itertools.islice(todo, k)}
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in sorted(done, key=running.get):
                i = running.pop(f)
                res = f.result()
                if consume is None:
                    out[i] = res
                else:
                    consume(i, res)
                del res
                ticker.tick()
                for j, x in itertools.islice(todo, 1):
                    running[ex.submit(fn, x)] = j
    except BaseException:
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown()
    return out


def _run_on(client, fn, items, ticker: _Progress, p: Plan, consume=None) -> list:
    from distributed import as_completed

    futures = client.map(fn, items, pure=False)
    index = {f.key: i for i, f in enumerate(futures)}
    out: list = [None] * len(items) if consume is None else []
    where = p.address or "the local cluster"
    health = _Health(client, where)
    try:
        with client.as_current():
            for fut in _completed(as_completed(futures), health):
                if fut.cancelled():  # the scheduler went away
                    raise StarforgeError(f"lost the dask scheduler at {where} mid-run; nothing was written")
                try:
                    # waits if the worker that held this result died since: the task reruns
                    res = _result(fut, health)
                except Exception as exc:
                    if _is_lost(exc):
                        raise
                    if type(exc).__name__ == "KilledWorker":
                        raise StarforgeError(
                            f"a task of {ticker.label} killed {p.describe()}'s workers repeatedly "
                            f"(out of memory?); nothing was written"
                        ) from None
                    raise _TaskFailed(exc) from None  # the task's own error, as raised
                if consume is None:
                    out[index[fut.key]] = res
                else:
                    consume(index[fut.key], res)
                del res
                fut.release()
                ticker.tick()
    except _TaskFailed as failed:
        raise failed.exc from None
    except Exception as exc:
        if _is_lost(exc):
            raise StarforgeError(
                f"lost the dask scheduler at {where} mid-run ({type(exc).__name__}); nothing was written"
            ) from None
        raise
    return out


class _Health:
    """Watches a running job's cluster, at most once a second: it raises StarforgeError when the
    cluster has had no worker for :data:`NO_WORKERS_S` (the scheduler would wait for one for
    ever) or the scheduler has not answered for :data:`LOST_SCHEDULER_S`."""

    def __init__(self, client, where: str):
        import time

        self.client, self.where, self.clock = client, where, time.monotonic
        now = self.clock()
        self.next_at, self.workers_seen, self.answered = now + 1.0, now, now

    def check(self) -> None:
        from starforge.io import interrupted

        if interrupted():
            raise KeyboardInterrupt
        now = self.clock()
        if now < self.next_at:
            return
        self.next_at = now + 1.0
        try:
            threads = self.client.nthreads(callback_timeout=2)
        except Exception:  # noqa: BLE001  (no answer: counted below)
            threads = None
        now = self.clock()
        if threads is not None:
            self.answered = now
            if threads:
                self.workers_seen = now
        if now - self.answered > LOST_SCHEDULER_S:
            raise StarforgeError(
                f"lost the dask scheduler at {self.where} mid-run (no answer for {LOST_SCHEDULER_S:g} s); "
                f"nothing was written"
            )
        if now - self.workers_seen > NO_WORKERS_S:
            raise StarforgeError(
                f"the dask cluster at {self.where} lost all its workers mid-run (none for {NO_WORKERS_S:g} s); "
                f"nothing was written"
            )


def _completed(ac, health: _Health):
    """The futures of ``ac`` (distributed's as_completed) as they finish, the cluster's health
    checked while none does."""
    import time

    while not ac.is_empty():
        batch = ac.next_batch(block=False)
        if not batch:
            health.check()
            time.sleep(0.02)
            continue
        for fut in batch:
            health.check()
            yield fut


def _result(fut, health: _Health):
    """A finished future's result; if its worker died since, it reruns: wait for it with the
    cluster's health checked."""
    from distributed import TimeoutError as DaskTimeout

    while True:
        try:
            return fut.result(timeout=1.0)
        except (TimeoutError, DaskTimeout):
            health.check()


class _TaskFailed(Exception):
    """A task's own exception, carried past the connection-loss handlers."""

    def __init__(self, exc: BaseException):
        super().__init__(str(exc))
        self.exc = exc


def _is_lost(exc: BaseException) -> bool:
    """The client lost its scheduler: cancelled futures, closed comms, connection timeouts."""
    name = type(exc).__name__
    return "Cancelled" in name or name in ("CommClosedError", "TimeoutError", "ConnectionRefusedError", "StreamClosedError")


