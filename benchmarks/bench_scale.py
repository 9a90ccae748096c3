"""Scale-out figures as JSON (issue 19): the engine on 1 and 2 local workers, a huge enumeration.

    python benchmarks/bench_scale.py scaling [--samples 40000]
    python benchmarks/bench_scale.py delta05 [--chunks 6] [--workers 2] [--first K]
    python benchmarks/bench_scale.py progress OUTDIR     (a run of benchmarks/run_delta05.sh)
    python benchmarks/bench_scale.py sweep-exact [--run]

* ``scaling``: the same sweep (interval cells: seeded, pure CPU) in process and on a local
  cluster of 1 and of 2 worker processes; the speed-up 1 -> 2 workers (target >= 1.7x), with
  and without the cluster's start-up.  The CSVs must be equal byte for byte.
* ``delta05``: ``stars --delta 0.5`` on the finger box.  Its enumeration (about 14e9 labelled
  candidates) runs as chunks on local workers; ``--chunks`` chunks spread evenly over the rank
  range are run (``--chunks 0``: all of them) and timed per worker, with each worker's peak
  memory; the whole run's time is extrapolated from them for this machine's workers and for 32
  (``--first K``: only chunks K.. are sampled, and the estimates cover those).
* ``progress``: the figures of a real run (``bash benchmarks/run_delta05.sh OUTDIR``: scheduler,
  2 workers and the command at ``nice -n 19``, sampled every 30 s) from its logs, finished or not:
  chunks done, worker CPU s per chunk, peak RSS per worker and of the client.
* ``sweep-exact``: the default sweep (0.5:3:0.5 x 10:50:5) with every cell whose enumeration
  fits one worker's memory made exhaustive (``sweep --exhaustive auto``): which cells, their
  estimated cost; ``--run`` runs it.

Figures are noisy on a shared machine: the load average is printed with each.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import sys
import time


def _load() -> list[float]:
    with open("/proc/loadavg") as fh:
        return [float(x) for x in fh.read().split()[:3]]


def _cluster(n: int):
    from distributed import Client, LocalCluster

    t = time.perf_counter()
    lc = LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None, silence_logs=logging.ERROR,
    )
    client = Client(lc, set_as_default=False)
    return lc, client, time.perf_counter() - t


def _maxrss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def scaling(args) -> dict:
    from starforge.tracking.sweep import rows_csv, sweep

    deltas = [1.0, 1.5, 2.0]
    cubes = [20.0, 25.0, 30.0, 35.0]
    kw = dict(rules=("face", "pair"), exhaustive_labelled=0, samples=args.samples)
    res: dict = {"cells": len(deltas) * len(cubes), "samples": args.samples, "load_before": _load()}
    t = time.perf_counter()
    ref = rows_csv(sweep(4.0, deltas, cubes, workers=1, **kw))
    res["in_process_s"] = round(time.perf_counter() - t, 2)
    for n in (1, 2):
        lc, client, start = _cluster(n)
        try:
            # warm the workers (imports, compiled kernels loaded from the cache) on a tiny sweep
            t = time.perf_counter()
            sweep(4.0, [3.0] * 1, [20.0, 25.0][: max(2, n)], scheduler=lc.scheduler_address, rules=("face",),
                  exhaustive_labelled=0, samples=200)
            res[f"workers_{n}_warmup_s"] = round(time.perf_counter() - t, 2)
            t = time.perf_counter()
            got = rows_csv(sweep(4.0, deltas, cubes, scheduler=lc.scheduler_address, **kw))
            res[f"workers_{n}_s"] = round(time.perf_counter() - t, 2)
            res[f"workers_{n}_startup_s"] = round(start, 2)
            res[f"workers_{n}_same_csv"] = got == ref
        finally:
            client.close()
            lc.close()
    res["speedup_1_to_2"] = round(res["workers_1_s"] / res["workers_2_s"], 2)
    res["speedup_1_to_2_with_startup"] = round(
        (res["workers_1_s"] + res["workers_1_startup_s"]) / (res["workers_2_s"] + res["workers_2_startup_s"]), 2
    )
    res["target_speedup"] = 1.7
    res["met"] = res["speedup_1_to_2"] >= 1.7
    res["load_after"] = _load()
    return res


def _finger(delta: float):
    from starforge.catalog import load_template
    from starforge.stars.spec import spec_from_mapping

    _, data = load_template("stars", "finger")
    data["delta_mm"] = delta
    return spec_from_mapping(data)


def delta05(args) -> dict:
    import numpy as np

    from starforge.stars import enumerate as E

    spec = _finger(0.5)
    parts = E.chunks(spec)
    labelled = E.labelled_count(spec)
    if args.chunks:
        pick = np.unique(np.linspace(args.first, len(parts) - 1, args.chunks).round().astype(int))
    else:
        pick = np.arange(len(parts))
    lc, client, start = _cluster(args.workers)
    res: dict = {
        "labelled": labelled,
        "pool_size": spec.pool_size,
        "chunks_total": len(parts),
        "chunks_run": int(len(pick)),
        "workers": args.workers,
        "startup_s": round(start, 2),
        "load_before": _load(),
    }
    try:
        from distributed import as_completed

        def timed(item):
            t = time.process_time()
            out = E.enumerate_chunk(item)
            return time.process_time() - t, out["counts"], len(out["fit"]), len(out["undecided"])

        items = [(spec, parts[i][0], parts[i][1], 1) for i in pick]
        client.run(lambda: None)
        t = time.perf_counter()
        futs = client.map(timed, items, pure=False)
        cpu, counts, fits, und = [], np.zeros(8, np.int64), 0, 0
        with client.as_current():
            for f in as_completed(futs):
                c, k, nf, nu = f.result()
                cpu.append(c)
                counts += k
                fits += nf
                und += nu
        wall = time.perf_counter() - t
        rss = client.run(_maxrss_mib)
    finally:
        client.close()
        lc.close()
    sampled = sum(parts[i][1] for i in pick) * 30
    # with --first, the estimates cover the chunks from that index on
    share = sampled / (sum(c for _, c in parts[args.first :]) * 30)
    cpu_total = sum(cpu) / share
    res.update(
        sampled_labelled=int(sampled),
        sampled_wall_s=round(wall, 2),
        cpu_s_per_chunk=[round(c, 2) for c in cpu],
        fit_share=round(fits / sampled, 5),
        undecided_share=float(und / sampled),
        est_fitting=int(fits / share),
        est_cpu_s=round(cpu_total),
        est_wall_s_here=round(cpu_total / args.workers + start),
        est_wall_s_32_workers=round(cpu_total / 32 + start),
        worker_peak_rss_mib=sorted(round(v) for v in rss.values()),
        est_client_bytes_fits=int(fits / share * (12 + 8)),
        load_after=_load(),
    )
    return res


def sweep_exact(args) -> dict:
    from starforge.runtime import engine
    from starforge.stars.enumerate import estimate
    from starforge.stars.spec import StarSpec
    from starforge.tracking.sweep import (
        SAMPLES,
        _auto_limit,
        cell_estimate,
        parse_range,
        rows_csv,
        run_cell,
        sweep,
    )

    deltas, cubes = parse_range("0.5:3:0.5", "delta"), parse_range("10:50:5", "cube")
    p = engine.plan(len(deltas) * len(cubes), float("inf"), args.workers)
    cells = []
    for d in deltas:
        for c in cubes:
            try:
                spec = StarSpec(box_mm=(c, c, c), marker_mm=4.0, delta_mm=d)
            except ValueError:
                continue
            est = estimate(spec)
            lim = _auto_limit(4.0, d, c, ("face", "pair"), SAMPLES, p.usable_bytes)
            cells.append({"delta": d, "cube": c, "labelled": est["labelled"],
                          "exhaustive_under_auto": lim >= est["labelled"],
                          # the sweep's own estimate (a pilot sample for the larger cells)
                          "est_cpu_s": round(cell_estimate(4.0, d, c, ("face", "pair"), max(lim, 0), SAMPLES)[0], 1)})
    exact = [x for x in cells if x["exhaustive_under_auto"]]
    res = {"n_cells": len(cells), "worker_memory_bytes": int(p.task_bytes), "workers": p.workers,
           "cells_exhaustive_under_auto": len(exact),
           "est_cpu_s_all_cells": round(sum(x["est_cpu_s"] for x in cells), 1),
           "cells": cells, "load_before": _load()}
    measured = []
    for tok in filter(None, (args.measure or "").split(",")):  # the estimate against a real run
        d, c = (float(x) for x in tok.split(":"))
        est = cell_estimate(4.0, d, c, ("face", "pair"), 10**12, SAMPLES)[0]
        t = time.process_time()
        rows = run_cell((4.0, d, c, ("face", "pair"), 10**12, SAMPLES, 0, None))
        cpu = time.process_time() - t
        measured.append({"delta": d, "cube": c, "est_cpu_s": round(est, 1), "cpu_s": round(cpu, 1),
                         "ratio": round(cpu / est, 2), "stars": [r["stars"] for r in rows]})
    if measured:
        res["estimate_vs_run"] = measured
    if args.run:  # the whole default sweep, every cell that fits a worker's memory exhaustive
        t = time.perf_counter()
        rows = sweep(4.0, deltas, cubes, exhaustive_labelled=None, workers=args.workers)
        res["ran"] = {"seconds": round(time.perf_counter() - t, 1),
                      "exhaustive_rows": sum(r["method"] == "exhaustive" for r in rows),
                      "interval_rows": sum(r["method"] == "interval" for r in rows),
                      "csv_lines": rows_csv(rows).count("\n")}
    res["load_after"] = _load()
    return res


def progress(args) -> dict:
    """Figures of a ``benchmarks/run_delta05.sh`` run from its logs (finished or not): chunks
    done, worker CPU s per chunk (all and the last ten minutes), peak RSS per worker and of the
    client, and the load seen."""
    import datetime as dt
    import re

    from starforge.stars import enumerate as E

    spec = _finger(0.5)
    parts = E.chunks(spec)
    size = E.CHUNK_SUBSETS * 30
    R = args.dir
    start = dt.datetime.strptime(open(f"{R}/start").read().strip(), "%Y-%m-%dT%H:%M:%SZ")
    text = open(f"{R}/client.log").read()
    prog = [(int(m[1]), int(m[2].replace(",", ""))) for m in re.finditer(r": (\d+) s, enumerating ([\d,]+)/", text)]
    rows, cur = [], None
    for line in open(f"{R}/sample.log"):
        if line.startswith("=="):
            hms = dt.datetime.strptime(line.split()[1], "%H:%M:%S").time()
            t = (dt.datetime.combine(start.date(), hms) - start).total_seconds() % 86400
            cur = {"t": t, "load": float(line.split()[3]), "worker": {}, "client": None}
            rows.append(cur)
        elif cur is not None and "rss_kb" in line:
            pid, role, rss, hwm, cpu = re.match(r"(\d+) (\w+) rss_kb=(\d+) hwm_kb=(\d+) cpu_s=(\d+)", line).groups()
            if role == "worker":
                cur["worker"][pid] = (int(hwm), int(cpu))
            elif role == "client":
                cur["client"] = (int(hwm), int(cpu))
    rows = [r for r in rows if r["worker"]]

    def chunks_at(t):
        return max([lab // size for s, lab in prog if s <= t], default=0)

    last = rows[-1]
    done, cpu = chunks_at(last["t"]), sum(c for _, c in last["worker"].values())
    back = next((r for r in rows if r["t"] >= last["t"] - 600), rows[0])
    d_chunks = max(1, done - chunks_at(back["t"]))
    d_cpu = cpu - sum(c for _, c in back["worker"].values())
    return {
        "finished": os.path.exists(f"{R}/end") and "exit 0" in text,
        "elapsed_s": last["t"],
        "chunks_done": int(done),
        "chunks_total": len(parts),
        "worker_cpu_s": cpu,
        "cpu_s_per_chunk": round(cpu / max(1, done), 3),
        "cpu_s_per_chunk_last_10_min": round(d_cpu / d_chunks, 3),
        "wall_s_per_chunk_last_10_min": round((last["t"] - back["t"]) / d_chunks, 3),
        "worker_peak_rss_mib": sorted(round(max(r["worker"].get(p, (0, 0))[0] for r in rows) / 1024) for p in last["worker"]),
        "client_peak_rss_mib": round(max((r["client"] or (0, 0))[0] for r in rows) / 1024),
        "client_cpu_s": (last["client"] or (0, 0))[1],
        "load_min_max": [min(r["load"] for r in rows), max(r["load"] for r in rows)],
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="case", required=True)
    a = sub.add_parser("scaling")
    a.add_argument("--samples", type=int, default=40_000)
    b = sub.add_parser("delta05")
    b.add_argument("--chunks", type=int, default=6)
    b.add_argument("--workers", type=int, default=2)
    b.add_argument("--first", type=int, default=0, help="sample only chunks from this index on")
    d = sub.add_parser("progress", help="figures of a benchmarks/run_delta05.sh run from its logs")
    d.add_argument("dir")
    c = sub.add_parser("sweep-exact")
    c.add_argument("--workers", type=int, default=2)
    c.add_argument("--run", action="store_true", help="run the sweep (long: tens of minutes on 2 cores)")
    c.add_argument("--measure", default="", help="cells DELTA:CUBE,... run exhaustively in process (one core) "
                   "and timed against the sweep's estimate")
    args = ap.parse_args(argv)
    fn = {"scaling": scaling, "delta05": delta05, "sweep-exact": sweep_exact, "progress": progress}[args.case]
    res = {"case": args.case, "cpus": os.cpu_count(), **fn(args)}
    json.dump(res, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
