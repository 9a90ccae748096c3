"""A first run compiles its kernels on two cores instead of one.

On an empty numba cache (a fresh install) ``starforge stars`` spends most of its first run
compiling, one kernel after another on one core, while the other cores wait.  When the cache
is cold, :func:`start` launches one helper process that compiles the enumeration's first pass
and the selection's kernels into the same cache, while this process compiles the fit decision
(:func:`compile_fit_decision`); each then loads what the other wrote.  The kernels, their
signatures and every result are the same as without it; a warm cache starts nothing.

Numba's cache files are written to a temporary name and renamed, so a helper stopped part way
leaves no broken entry: at worst a kernel is compiled by this process as before.
"""

from __future__ import annotations

import os
import subprocess
import sys


def cache_is_cold() -> bool:
    """True when the enumeration's compiled kernel is not in the numba cache (a first run).
    (Reads numba's cache index; any doubt counts as warm, so nothing is started.)"""
    try:
        from starforge.stars.enumerate import _classify

        return len(_classify._cache._cache_file._load_index()) == 0
    except Exception:  # noqa: BLE001  (a private numba API: never fail a command over it)
        return False


def start() -> subprocess.Popen | None:
    """Start the helper process when the cache is cold and there is a second core; None
    otherwise.  The caller ends it with :func:`finish`."""
    if (os.cpu_count() or 1) < 2 or not cache_is_cold():
        return None
    try:
        return subprocess.Popen(
            [sys.executable, "-c", "from starforge.stars.warmup import _helper; _helper()"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        return None


def finish(proc: subprocess.Popen | None, timeout_s: float = 30.0) -> None:
    """Wait up to ``timeout_s`` for the helper (it is done long before a first run ends), then
    stop it; nothing is left running."""
    if proc is None:
        return
    try:
        proc.wait(timeout=timeout_s) if timeout_s > 0 else None
    except subprocess.TimeoutExpired:
        pass
    if proc.poll() is None:
        proc.kill()
    proc.wait()


def compile_fit_decision() -> None:
    """Compile (or load) the fit decision's one entry with the types the enumeration and the
    placement call it with."""
    import numpy as np

    from starforge.geometry.fit import decide_fit

    P = np.zeros((1, 4, 3))
    P[0, 1, 0] = P[0, 2, 1] = P[0, 3, 2] = 1.0
    decide_fit(P, np.array([2.0, 2.0, 2.0]))


def _helper() -> None:
    """The helper process: the enumeration's first pass and the selection's kernels, called on
    tiny inputs of the types ``stars`` uses, so that they land in the cache."""
    import numpy as np

    from starforge.geometry.tetra import canonical_assignments
    from starforge.stars import select as sel
    from starforge.stars.enumerate import _classify, _subsets_from

    assign = canonical_assignments().astype(np.int64)
    sub = np.array([[0, 1, 2, 3, 4, 5]], dtype=np.int16)
    codes = np.empty((1, len(assign)), dtype=np.int8)
    faces = np.zeros((6, 6, 6), dtype=np.int8)  # no claims (the pool indices of sub are < 6)
    _classify(sub, assign, 10.0, 1.0, np.array([5.0, 10.0, 40.0]), 1.0, 0, faces, codes, 0, 1)
    _subsets_from(8, 1, np.array([0, 1, 2, 3, 4, 5], dtype=np.int64), 2)
    # the selection, on two stars sharing rows: greedy, the packing, local search and the ILS
    from starforge.stars.rules import window_rows

    idx = np.array([[0, 1, 2, 3, 4, 5], [0, 1, 2, 3, 4, 6]], dtype=np.int16)
    star_of, row, n_rows = window_rows(idx, "face", 1, 8)
    ptr, rows = sel._csr(star_of, row, len(idx))
    order = np.arange(len(idx))
    chosen = sel.greedy(order, ptr, rows, n_rows)
    chosen, _ = sel.local_search(chosen, order, ptr, rows, n_rows)
    sel.ils(chosen, order, ptr, rows, n_rows, iterations=1)
