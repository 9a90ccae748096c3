"""The engine on a real dask cluster: 2 worker processes over TCP on loopback.

Equality with the serial run (enumeration and sweep), a worker killed mid-run (same result),
an unreachable scheduler (one line, exit 2, nothing published), and the plan / memory checks.
"""

from __future__ import annotations

import json
import logging
import os
import signal

import numpy as np
import pytest

from starforge.cli import main
from starforge.errors import StarforgeError
from starforge.runtime import engine
from starforge.stars import enumerate as E
from starforge.stars.spec import StarSpec

SPEC = StarSpec(box_mm=(14, 10, 30), delta_mm=1.0, tolerance_mm=2.0)  # 814k labelled candidates


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    lc = distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        protocol="tcp",
        dashboard_address=None,
        # the scheduler's HTTP routes (/health, /metrics) on a free port: the default 8787 may be
        # taken (a notebook's cluster, a second starforge run), which dask reports as a warning
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR,
    )
    yield lc
    lc.close()


@pytest.fixture(scope="module")
def serial():
    return E.enumerate_candidates(SPEC, workers=1)


def _same(a, b):
    assert a.index.tobytes() == b.index.tobytes()
    assert a.box_volume.tobytes() == b.box_volume.tobytes()
    assert a.undecided.tobytes() == b.undecided.tobytes()
    sa = {k: v for k, v in a.stats.items() if k != "seconds"}
    sb = {k: v for k, v in b.stats.items() if k != "seconds"}
    assert sa == sb


def test_unrank_matches_the_lexicographic_walk():
    n, m = 13, 2
    start = np.array([k * m for k in range(6)], dtype=np.int64)
    walk = E.subsets_from(n, m, start, 10_000)
    assert len(walk) == E.admissible_subsets(n, m)
    for r in (0, 1, 7, len(walk) // 2, len(walk) - 1):
        assert E.unrank_subset(r, n, m).tolist() == walk[r].tolist()


def test_chunked_enumeration_equals_one_chunk(serial, monkeypatch):
    monkeypatch.setattr(E, "CHUNK_SUBSETS", 997)  # many uneven chunks, in process
    assert len(E.chunks(SPEC)) > 20
    _same(E.enumerate_candidates(SPEC, workers=1), serial)
    _same(E.enumerate_candidates(SPEC, workers=2), serial)  # two chunks at once, on 2 threads each


@pytest.mark.slow  # starts dask processes
def test_enumeration_on_the_cluster_equals_serial(cluster, serial, monkeypatch):
    monkeypatch.setattr(E, "CHUNK_SUBSETS", 2000)
    seen = []
    got = E.enumerate_candidates(SPEC, scheduler=cluster.scheduler_address, progress=lambda d, t: seen.append(d))
    _same(got, serial)
    assert seen == sorted(seen) and seen[-1] == serial.stats["labelled"]


@pytest.mark.slow  # starts dask processes
def test_a_killed_worker_changes_nothing(cluster, serial, monkeypatch):
    from distributed import Client

    monkeypatch.setattr(E, "CHUNK_SUBSETS", 1000)
    with Client(cluster.scheduler_address, set_as_default=False) as c:
        pids = sorted(c.run(os.getpid).values())
    killed = []

    def kill_one(done, total):
        if not killed:
            os.kill(pids[0], signal.SIGKILL)  # mid-run: most chunks are still queued
            killed.append(done)

    got = E.enumerate_candidates(SPEC, scheduler=cluster.scheduler_address, progress=kill_one)
    assert killed and killed[0] < serial.stats["labelled"]
    _same(got, serial)
    with Client(cluster.scheduler_address, set_as_default=False) as c:
        c.wait_for_workers(2, timeout=60)  # the nanny restarted the worker for the next tests
        assert pids[0] not in c.run(os.getpid).values()


@pytest.mark.slow  # starts dask processes
def test_sweep_on_the_cluster_equals_serial(cluster, tmp_path):
    from starforge.tracking.sweep import rows_csv, sweep

    # interval cells (seeded samples and the pool bound), which a cluster runs as tasks
    args = (4.0, [2.0, 3.0], [18.0, 24.0], ("face", "pair"), 0, 1_000)
    a = rows_csv(sweep(*args, workers=1))
    b = rows_csv(sweep(*args, scheduler=cluster.scheduler_address))
    assert a == b and a.count("\n") == 9


def test_unreachable_scheduler_is_one_line_and_publishes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    out = tmp_path / "sw"
    rc = main(["sweep", "--delta", "3", "--cube", "18", "--samples", "1000", "--scheduler",
               "127.0.0.1:9", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.startswith("error: cannot reach the dask scheduler at tcp://127.0.0.1:9") and "\n" not in err
    assert not out.exists()


def test_the_environment_variable_names_the_scheduler(monkeypatch):
    monkeypatch.setenv(engine.ENV_SCHEDULER, "10.0.0.1:8786")
    assert engine.scheduler_address() == "tcp://10.0.0.1:8786"
    assert engine.scheduler_address("h:1") == "tcp://h:1"
    with pytest.raises(StarforgeError, match=r"tls:// is not supported"):
        engine.scheduler_address("tls://h:1")
    monkeypatch.setenv(engine.ENV_SCHEDULER, "inproc://x")
    with pytest.raises(StarforgeError, match=r"^STARFORGE_SCHEDULER 'inproc://x': inproc:// is not supported"):
        engine.scheduler_address()
    monkeypatch.delenv(engine.ENV_SCHEDULER)
    assert engine.scheduler_address() is None


def test_plan_runs_small_work_in_process_and_splits_memory():
    assert engine.plan(100, seconds=1.0, workers=4).mode == "serial"
    assert engine.plan(1, seconds=1e6, workers=4).mode == "serial"
    p = engine.plan(100, seconds=1e6, workers=4)
    assert p.mode == "local" and p.workers == 4
    with pytest.raises(StarforgeError, match="task 1 needs about"):
        engine.require_task_memory([1.0, 2 * p.task_bytes], p, "a job", "split it")


def test_results_come_back_in_item_order_in_process():
    got = engine.map_tasks(abs, [-3, 1, -2], workers=1)
    assert got == [3, 1, 2]


def _wait_listening(port: int, timeout_s: float = 60.0) -> None:
    """Wait until something accepts connections on ``port`` (a scheduler starting up)."""
    import socket
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.mark.slow  # starts dask processes
def test_a_scheduler_that_goes_away_is_one_error(monkeypatch):
    import socket
    import subprocess
    import sys

    pytest.importorskip("distributed")
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    addr = f"tcp://127.0.0.1:{port}"
    dask = os.path.join(os.path.dirname(sys.executable), "dask")
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    sched = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], **quiet)
    work = subprocess.Popen([dask, "worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"], **quiet)
    try:
        _wait_listening(port)
        monkeypatch.setattr(E, "CHUNK_SUBSETS", 500)
        monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 60.0)  # slow start on a loaded machine

        def kill_scheduler(done, total):
            if sched.poll() is None:
                sched.kill()
                sched.wait()

        with pytest.raises(StarforgeError, match=f"lost the dask scheduler at {addr} mid-run"):
            E.enumerate_candidates(SPEC, scheduler=addr, progress=kill_scheduler)
    finally:
        for proc in (work, sched):
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()


def test_stage_counts_match_a_brute_force_recount():
    """Every stage count of the chunked enumeration, recounted in numpy over every labelled
    candidate, with the fit decided by ``decide_fit`` (no cone test): the cone test that skips
    the search never changes a decision, and the chunks lose or repeat nothing."""
    from starforge.geometry.fit import decide_fit
    from starforge.geometry.tetra import canonical_assignments, tetra_width

    spec, got = SPEC, E.enumerate_candidates(SPEC, workers=1).stats
    n, m = spec.pool_size, spec.grid_steps
    sub = E.subsets_from(n, m, np.array([k * m for k in range(6)], dtype=np.int64), 10**7)
    L = E.edge_pool(spec)[sub[:, canonical_assignments()]].reshape(-1, 6)
    u, U, v, V, w, W = L.T
    cx = (u * u + w * w - v * v) / (2 * u)
    cy2 = w * w - cx * cx
    cy = np.sqrt(np.maximum(cy2, 1e-300))
    dx = (u * u + V * V - W * W) / (2 * u)
    dy = (V * V - U * U + w * w - 2 * dx * cx) / (2 * cy)
    dz2 = V * V - dx * dx - dy * dy
    real = (cy2 > 1e-9) & (dz2 > 1e-9)
    width = np.where(real, tetra_width(np.where(real[:, None], L, 10.0)), 0.0)
    deep = real & (width >= spec.depth_mm - 1e-9)
    lim = np.sort(np.array(spec.centre_limit_mm))
    narrow = deep & (width <= lim[0] + 1e-9)
    P = np.zeros((len(L), 4, 3))
    P[:, 1, 0] = u
    P[:, 2, 0], P[:, 2, 1] = cx, cy
    P[:, 3, 0], P[:, 3, 1], P[:, 3, 2] = dx, dy, np.sqrt(np.maximum(dz2, 0))
    Q = P[narrow] - P[narrow].mean(axis=1, keepdims=True)
    ev = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", Q, Q) / 4)  # ascending
    ky = (np.cumsum(ev, axis=1) <= np.cumsum(lim**2) / 4 + 1e-9).all(axis=1)
    status, _, _ = decide_fit(P[narrow][ky], lim)
    want = {
        "labelled": len(L),
        "realisable": int(real.sum()),
        "deep_enough": int(deep.sum()),
        "width_ok": int(narrow.sum()),
        "kyfan_ok": int(ky.sum()),
        "no_fit": int((status == 0).sum()),
        "undecided": int((status == -1).sum()),
        "fitting": int((status == 1).sum()),
    }
    assert {k: got[k] for k in want} == want


def test_global_scheduler_option_reaches_the_enumeration(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(engine.ENV_SCHEDULER, "")  # recorded, so the option's setting is undone after
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    out = tmp_path / "fam"
    rc = main(["--scheduler", "127.0.0.1:9", "stars", "--box", "14", "10", "24", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("error: cannot reach the dask scheduler") and "\n" not in err
    assert not out.exists()


@pytest.mark.slow  # starts dask processes
def test_a_tasks_own_error_comes_back_as_raised(cluster, tmp_path):
    missing = str(tmp_path / "no-such-file")
    with pytest.raises(FileNotFoundError):  # not mistaken for a lost connection (an OSError too)
        engine.map_tasks(os.stat, [str(tmp_path), missing], scheduler=cluster.scheduler_address)


@pytest.mark.slow  # starts dask processes
def test_ils_restarts_on_the_cluster_are_the_serial_ones(cluster, monkeypatch):
    """The exact selection's ILS restarts as tasks on 2 workers: the same family, iterations and
    restart count as one after another here, with the stop at the bound emulated in seed order."""
    from starforge.stars import select as sel
    from starforge.stars.rules import internal_ok, window_rows

    monkeypatch.delenv(engine.ENV_SCHEDULER, raising=False)
    c = E.enumerate_candidates(StarSpec(box_mm=(14, 10, 30), delta_mm=1.0, tolerance_mm=1.0), workers=1)
    ok = internal_ok(c.index, "face", 1)
    index, volume = c.index[ok], c.box_volume[ok]
    star_of, row, n_rows = window_rows(index, "face", 1, len(c.pool_mm))
    ptr, rows = sel.csr_rows(star_of, row, len(index))
    order = sel.compactness_order(index, c.pool_mm, volume)
    start, _ = sel.local_search(sel.greedy(order, ptr, rows, n_rows), order, ptr, rows, n_rows)
    first, _ = sel.ils(start, order, ptr, rows, n_rows, iterations=20)

    def both(bound):
        args = (first, start, order, ptr, rows, n_rows, bound)
        here = sel.ils_restarts(*args, iterations=60)
        monkeypatch.setenv(engine.ENV_SCHEDULER, cluster.scheduler_address)
        try:
            there = sel.ils_restarts(*args, iterations=60)
        finally:
            monkeypatch.delenv(engine.ENV_SCHEDULER)
        assert here[0].tobytes() == there[0].tobytes() and here[1:] == there[1:]
        return here

    best, used, ran = both(10**6)  # never reached: every restart runs
    assert ran == sel.ILS_RESTARTS and len(best) > len(first)
    _, _, ran = both(len(best))  # reached by some seed: the restarts after it are dropped
    assert 1 <= ran <= sel.ILS_RESTARTS
    # independent check of the family: no two of its stars share a window row
    used_rows = np.concatenate([rows[ptr[s] : ptr[s + 1]] for s in best.tolist()])
    assert len(np.unique(used_rows)) == len(used_rows)


@pytest.mark.slow  # starts dask processes
def test_streamed_selection_on_the_cluster_is_the_serial_one(cluster, serial):
    """The streamed path (chunk results consumed as they arrive, in completion order) gives the
    same family on 2 workers as in process, and the in-memory greedy's family."""
    from dataclasses import replace

    from starforge.stars import stream as S
    from starforge.stars.rules import internal_ok, window_rows
    from starforge.stars.select import compactness_order, csr_rows, greedy

    spec = replace(SPEC, select="greedy")
    here = S.stream_family(spec, workers=1)
    there = S.stream_family(spec, scheduler=cluster.scheduler_address)
    assert here["index"].tobytes() == there["index"].tobytes()
    assert (here["bound"], here["candidates"], here["stats"]) == (there["bound"], there["candidates"], there["stats"])
    ok = internal_ok(serial.index, "face", SPEC.grid_steps)
    index, volume = serial.index[ok], serial.box_volume[ok]
    star_of, row, n_rows = window_rows(index, "face", SPEC.grid_steps, len(serial.pool_mm))
    ptr, rows = csr_rows(star_of, row, len(index))
    want = index[greedy(compactness_order(index, serial.pool_mm, volume), ptr, rows, n_rows)]
    assert here["index"].tobytes() == want[np.lexsort(want.T[::-1])].astype(np.int16).tobytes()


@pytest.mark.slow  # starts dask processes
def test_the_default_family_on_a_cluster_is_the_one_made_here(cluster, tmp_path, monkeypatch):
    """``starforge --scheduler ADDRESS stars`` writes the same family, byte for byte outside its
    timings, as ``starforge stars`` in one process."""
    monkeypatch.delenv(engine.ENV_SCHEDULER, raising=False)

    def family(args, name):
        out = tmp_path / name
        assert main([*args, "stars", "--out", str(out), "-q"]) == 0
        doc = json.loads((out / "family.json").read_text())
        doc.pop("timings", None)
        sel = doc["summary"]["selection"]
        doc["summary"]["selection"] = {k: v for k, v in sel.items() if not k.endswith("_s")}
        return json.dumps(doc, sort_keys=True), sorted(p.name for p in out.iterdir())

    here = family([], "here")
    before = cluster.scheduler.transition_counter
    try:
        there = family(["--scheduler", cluster.scheduler_address], "there")
    finally:
        monkeypatch.delenv(engine.ENV_SCHEDULER, raising=False)
    assert cluster.scheduler.transition_counter > before  # the work ran on the cluster
    assert here == there
    assert len(json.loads(here[0])["stars"]) > 0


@pytest.mark.slow  # starts dask processes
def test_auto_sweep_asks_a_remote_cluster_for_its_memory(cluster, monkeypatch):
    """``--exhaustive auto`` on a scheduler decides each cell against the cluster's real worker
    memory (a short connection), with a margin under dask's 95 % restart threshold."""
    from starforge.tracking import sweep as SW

    p = engine.plan_with_capacity(4, scheduler=cluster.scheduler_address)
    limit = min(w["memory_limit"] for w in cluster.scheduler_info["workers"].values())
    assert p.mode == "remote" and p.workers == 2 and p.task_bytes == limit
    assert p.usable_bytes == pytest.approx(engine.USABLE_SHARE * limit)
    seen = []
    monkeypatch.setattr(SW, "_auto_limit", lambda *a: seen.append(a[-1]) or 0)
    SW.sweep(4.0, [3.0], [18.0], exhaustive_labelled=None, samples=1_000, scheduler=cluster.scheduler_address)
    assert seen == [p.usable_bytes]


def test_a_task_planned_above_the_usable_share_is_refused():
    p = engine.Plan("local", 2, 1e9)
    engine.require_task_memory([0.9e9], p, "a job", "split it")
    with pytest.raises(StarforgeError, match="task 0 needs about"):
        engine.require_task_memory([0.95e9], p, "a job", "split it")


def test_beside_returns_the_result_or_the_error_of_the_call():
    """threads.beside: the result of fn(*args) (the same as in place), its exception raised
    where the result is asked for, and no thread left behind."""
    import threading

    from starforge.runtime.threads import beside
    from starforge.stars.family import margins

    L = np.random.default_rng(0).uniform(8, 40, (50, 6))
    assert beside(margins, L)() == margins(L)
    get = beside(int, "not a number")
    with pytest.raises(ValueError):
        get()
    assert not [t for t in threading.enumerate() if t.name.startswith("starforge-") and t.name != "starforge-signals"]


def _slow_square(x):
    import time

    time.sleep(0.002 * (x % 3))  # finish out of order
    if x == 7:
        raise ValueError("task 7 fails")
    return x * x


def test_overlapped_tasks_in_process_give_the_serial_results():
    """map_tasks(overlap=k) runs k tasks at once on threads: the same results in item order,
    every item consumed once whatever the completion order, progress ticked once per task,
    the memory check counting each task k times, and a task's error raised."""
    items = [0, 1, 2, 3, 4, 5, 6, 8, 9, 10]
    want = [x * x for x in items]
    ticks = []
    got = engine.map_tasks(_slow_square, items, workers=1, overlap=3, progress=lambda d, n: ticks.append((d, n)))
    assert got == want
    assert ticks == [(d, len(items)) for d in range(1, len(items) + 1)]
    seen = {}
    assert engine.map_tasks(_slow_square, items, workers=1, overlap=2, consume=lambda i, r: seen.setdefault(i, r)) == []
    assert seen == dict(enumerate(want))
    with pytest.raises(ValueError, match="task 7 fails"):
        engine.map_tasks(_slow_square, [1, 7, 2, 3], workers=1, overlap=2)
    usable = engine.plan(1, 0.0, workers=1).usable_bytes
    engine.map_tasks(_slow_square, [1, 2], workers=1, overlap=2, task_bytes=usable * 0.4)
    with pytest.raises(StarforgeError, match="memory"):
        engine.map_tasks(_slow_square, [1, 2], workers=1, overlap=2, task_bytes=usable * 0.6)
