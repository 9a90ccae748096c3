"""``--scheduler`` pointed at anything that is not a working dask cluster, each case N times.

Endpoints that are not a dask scheduler (a silent listener, an HTTP server, one that sends other
bytes, a closed port, an unreachable address), addresses that are not accepted (tls://, ucx://,
inproc://, a port that is not a number, a 5,000-digit port, empty), a scheduler without workers,
and a real cluster that fails mid-run (its only worker killed; the scheduler killed), each run
``--repeat`` times through sweep, stars and place-batch (the mid-run ones through sweep).  A run
is clean when it ends with exit 2, one ``error:`` line (the command's progress lines aside), no
traceback or warning, no process left in its session and the working folder as it was.

Prints JSON: runs clean / total, the worst seconds (from the start of the command; for the
mid-run cases from the kill), the not-clean runs, the load average.

Run from the repository root: ``python benchmarks/bench_scheduler.py [--repeat 3] [--only http,silent]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.test_hostile_inputs import CHILD, left_in_session, snapshot  # noqa: E402
from tests.test_hostile_runtime import dask_cli, end_group, free_port, not_dask_endpoints, wait_listening  # noqa: E402

TARGET_S = 15.0
COMMANDS = {
    "sweep": ("sweep", "--delta", "3", "--cube", "18", "--samples", "1000"),
    "stars": ("stars", "--box", "14", "10", "24"),
    "place-batch": ("place-batch", "hammer", "hammer"),
}
#: a sweep long enough to be running on the cluster when a worker or the scheduler is killed
LONG_SWEEP = ("sweep", "--delta", "1:3:0.5", "--cube", "18:30:3", "--samples", "20000")
PROGRESS = re.compile(r"^(starforge [a-z-]+|stars|place-batch|sweep): ")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", default=None, help="comma-separated case names (default: all)")
    opts = ap.parse_args()
    rows = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-scheduler-") as d, not_dask_endpoints() as ends:
        cases = {
            **ends,
            "unreachable": "192.0.2.1:8786",  # TEST-NET-1: routed nowhere
            "unknown-host": "no-such-host.invalid:8786",
            "tls": "tls://127.0.0.1:8786",
            "ucx": "ucx://127.0.0.1:8786",
            "inproc": "inproc://x",
            "port-abc": "tcp://127.0.0.1:abc",
            "port-5000-digits": "127.0.0.1:" + "9" * 5000,
            "empty": " ",
            "no-workers": None,
            "worker-killed": None,
            "scheduler-killed": None,
        }
        names = opts.only.split(",") if opts.only else list(cases)
        for name in names:
            for rep in range(opts.repeat):
                if name in ("worker-killed", "scheduler-killed"):
                    got = [_mid_run(Path(d) / f"{name}-{rep}", name)]
                    runs = [("sweep", got[0])]
                elif name == "no-workers":
                    runs = [(cmd, _no_workers(Path(d) / f"{name}-{rep}-{cmd}", cmd)) for cmd in COMMANDS]
                else:
                    runs = [(cmd, _run(Path(d) / f"{name}-{rep}-{cmd}", [*args, "--scheduler", cases[name]]))
                            for cmd, args in COMMANDS.items()]
                for cmd, row in runs:
                    rows.append({"case": name, "command": cmd, "repeat": rep, **row})
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    worst = max(rows, key=lambda r: r["seconds"], default=None)
    print(json.dumps({
        "runs_clean": sum(r["clean"] for r in rows),
        "runs": len(rows),
        "worst_seconds": round(worst["seconds"], 2) if worst else None,
        "worst_case": f"{worst['case']} / {worst['command']}" if worst else None,
        "within_target": sum(r["seconds"] <= TARGET_S for r in rows),
        "per_case_worst_s": {n: round(max(r["seconds"] for r in rows if r["case"] == n), 2)
                             for n in dict.fromkeys(r["case"] for r in rows)},
        "not_clean": [{k: r[k] for k in ("case", "command", "repeat", "seconds", "problems")}
                      for r in rows if not r["clean"]],
        "wall_seconds": round(time.perf_counter() - t_start, 1),
        "load_average": os.getloadavg(),
    }, indent=2))


def _start(work: Path, argv: list[str]) -> tuple[subprocess.Popen, list[str], dict]:
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(work)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    env.pop("STARFORGE_SCHEDULER", None)
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *argv, "--out", str(out)], cwd=work, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    said: list[str] = []
    reader = threading.Thread(target=lambda: said.extend(proc.stderr), daemon=True)
    reader.start()
    return proc, said, before


def _judge(proc, said, work: Path, before: dict, seconds: float) -> dict:
    problems = []
    time.sleep(0.2)
    err = "".join(said)
    lines = [line for line in err.splitlines() if not PROGRESS.match(line)]
    if proc.returncode != 2:
        problems.append(f"exit {proc.returncode}")
    if len(lines) != 1 or not lines[0].startswith("error: "):
        problems.append(f"stderr {lines[:4]}"[:400])
    if "Traceback" in err or "Warning" in err:
        problems.append("traceback or warning on stderr")
    if seconds > TARGET_S:
        problems.append(f"{seconds:.1f} s")
    left = left_in_session(proc.pid)
    if left:
        problems.append(f"processes left: {left}")
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
    if snapshot(work) != before:
        problems.append("the working folder changed")
    return {"clean": not problems, "seconds": round(seconds, 2), "code": proc.returncode,
            "line": lines[0][:160] if lines else None, "problems": problems}


def _wait(proc, limit_s: float = 120.0) -> None:
    try:
        proc.wait(timeout=limit_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _run(work: Path, argv: list[str]) -> dict:
    t0 = time.perf_counter()
    proc, said, before = _start(work, argv)
    _wait(proc)
    return _judge(proc, said, work, before, time.perf_counter() - t0)


def _no_workers(work: Path, cmd: str) -> dict:
    port = free_port()
    sched = dask_cli("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")
    try:
        wait_listening(port)
        return _run(work, [*COMMANDS[cmd], "--scheduler", f"127.0.0.1:{port}"])
    finally:
        end_group(sched)


def _mid_run(work: Path, which: str) -> dict:
    """A sweep on a one-worker cluster; once its cells are on the cluster, the worker (or the
    scheduler) is killed; seconds from the kill to the command's exit."""
    from distributed import Client

    port = free_port()
    addr = f"127.0.0.1:{port}"
    sched = dask_cli("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")
    worker = dask_cli("worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard")
    try:
        wait_listening(port)
        with Client(addr, timeout="60s", set_as_default=False) as c:
            c.wait_for_workers(1, timeout=60)
        proc, said, before = _start(work, [*LONG_SWEEP, "--scheduler", addr])
        deadline = time.monotonic() + 120
        while not any("on the dask cluster" in line for line in said) and time.monotonic() < deadline:
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        time.sleep(1.0)
        end_group(worker if which == "worker-killed" else sched)
        t0 = time.perf_counter()
        _wait(proc)
        return _judge(proc, said, work, before, time.perf_counter() - t0)
    finally:
        end_group(worker, sched)


if __name__ == "__main__":
    main()
