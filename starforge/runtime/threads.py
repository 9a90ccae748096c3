"""Threads of this process: how many a compiled kernel may use (one inside a dask worker, every
core otherwise), a kernel spread over index ranges on them, and one function run beside the
caller's own work.  Tasks across processes and machines are :mod:`starforge.runtime.engine`'s."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


def one_blas_thread() -> None:
    """In the ``starforge`` command, before numpy loads: numpy's and scipy's BLAS run on the
    calling thread (``OPENBLAS_NUM_THREADS=1``, unless the user set it).  The commands' parallel
    work is their compiled kernels' and the engine's; the BLAS calls are on small matrices
    (3 x 3 fits, a few markers), which OpenBLAS runs on one thread anyway, while each copy of
    it (numpy's, and scipy's that numba loads) starts a worker per extra core that spins on the
    cores the kernels use before it sleeps.  Child processes inherit it."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def threads_for_task() -> int | None:
    """Compiled-kernel threads a task should use: 1 inside a dask worker (each worker thread
    is one core's share), None (every core) in process."""
    import sys

    dist = sys.modules.get("distributed")  # a worker has it imported; never import it just to ask
    if dist is None:
        return None
    try:
        dist.get_worker()
    except (AttributeError, ValueError):
        return None
    return 1


def kernel_threads(threads: int | None = None) -> int:
    """Threads a compiled kernel may use in this process: ``threads`` (None: every core; 1
    inside a dask worker, see :func:`threads_for_task`), never more than ``NUMBA_NUM_THREADS``."""
    import numba

    if threads is None:
        threads = threads_for_task()
    cap = numba.config.NUMBA_NUM_THREADS
    if threads is None:
        return max(1, min(os.cpu_count() or 1, cap))
    return max(1, min(int(threads), cap))


#: work items (index triples of a kernel's loops) below which a ``parallel=True`` kernel runs on
#: the calling thread alone: waking the OpenMP team costs more than it saves there, its threads
#: spin on the cores the render processes draw on, and a region whose threads wait for a busy
#: core stalls for a scheduler tick
PARALLEL_MIN_WORK = 4_000_000


@contextmanager
def threads_for_work(work: int, threads: int | None = None) -> Iterator[int]:
    """Within the block, ``parallel=True`` kernels called from this thread run on one thread
    when ``work`` (their loops' item count) is below :data:`PARALLEL_MIN_WORK`, else on
    :func:`kernel_threads` threads; yields that count.  For kernels whose every index writes its
    own result, so the result does not depend on it."""
    import numba

    n = 1 if work < PARALLEL_MIN_WORK else kernel_threads(threads)
    old = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield n
    finally:
        numba.set_num_threads(old)


def over_ranges(kernel: Callable[[int, int], Any], n: int, chunk: int, threads: int | None = None) -> None:
    """``kernel(i0, i1)`` over ``[0, n)`` cut into ranges of ``chunk``, on up to ``threads``
    threads (:func:`kernel_threads`).  For compiled kernels that release the GIL and write
    each index's result in place: every index is done once whatever the thread count, so the
    result does not depend on it.  A serial kernel spread this way costs no parallel compile
    (numba's ``parallel=True`` adds seconds to a first run).  An exception (Ctrl-C included)
    cancels the ranges not yet started and is raised."""
    threads = min(kernel_threads(threads), max(1, -(-n // max(1, chunk))))
    if threads <= 1:
        kernel(0, n)
        return
    from concurrent.futures import ThreadPoolExecutor

    ex = ThreadPoolExecutor(threads)
    try:
        futs = [ex.submit(kernel, a, min(a + chunk, n)) for a in range(0, n, chunk)]
        for f in futs:
            f.result()
    except BaseException:
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown()


def beside(fn: Callable[..., Any], *args) -> Callable[[], Any]:
    """Start ``fn(*args)`` on a thread beside the caller's own work and return a function that
    waits for its result (or raises its exception).  For independent numpy work on large
    arrays (its array loops release the GIL) while the caller runs other code: the same result
    as calling ``fn`` in place, on the second core where one is idle.  With one core it is
    simply called in place."""
    if (os.cpu_count() or 1) < 2:
        value = fn(*args)
        return lambda: value
    import threading

    out: dict = {}

    def run():
        try:
            out["value"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001  (handed to the caller, re-raised there)
            out["error"] = exc

    th = threading.Thread(target=run, name=f"starforge-{getattr(fn, '__name__', 'beside')}", daemon=True)
    th.fork_safe = True  # joined before the caller goes on; it forks nothing and holds no lock
    th.start()

    def result():
        th.join()
        if "error" in out:
            raise out["error"]
        return out["value"]

    return result
