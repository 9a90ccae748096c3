"""``starforge place`` on a finely tessellated mesh as JSON: wall and CPU seconds, peak memory and
the run's own stage timings, against the targets (a 500k-face mesh in at most 10 s and 1 GB).

The mesh is the built-in hammer with every face split in four ``--subdivide`` times (6: 581,632
faces; the same surface, in metres), written to a temporary STL and placed by a fresh
``python -m starforge place run FILE`` process at the default settings, ``--repeat`` times.  Peak
memory is the largest resident set of the command's processes (``ru_maxrss`` from ``wait4``).  Timings depend on the load: the JSON records the load average before each run.

Run: ``python benchmarks/bench_place_fine.py [--subdivide 6] [--repeat 1]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 10.0
TARGET_MB = 1024.0


def fine_hammer(times: int):
    """The built-in hammer with every face split into 4**times."""
    import trimesh

    from starforge.props.builtin import builtin_mesh

    m = builtin_mesh("hammer")
    v, f = m.vertices, m.faces
    for _ in range(times):
        v, f = trimesh.remesh.subdivide(v, f)
    return trimesh.Trimesh(v, f, process=False)


def run_once(path: Path, out: Path, env: dict | None = None) -> dict:
    """One ``starforge place run PATH`` in a fresh process (with ``env`` added to this one's
    environment): wall, CPU, peak RSS, stage timings."""
    load = os.getloadavg()[0]
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
    t = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "starforge", "place", "run", str(path), "--out", str(out), "-q", "--force"],
        env=env, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    if status != 0:
        raise SystemExit(f"starforge place failed on {path} (status {status})")
    timings = json.loads((out / "placement.json").read_text())["timings"]
    return {
        "seconds": round(wall, 2),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
        # the largest of the command's process and its render processes (it waits for them)
        "peak_rss_mb": round(usage.ru_maxrss / 1024.0, 1),
        "load_1min_before": round(load, 2),
        "timings": timings,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subdivide", type=int, default=6, help="times every face of the hammer is split in four")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        mesh = fine_hammer(args.subdivide)
        path = tmp / f"hammer_x{4 ** args.subdivide}.stl"
        mesh.export(path)
        runs = [run_once(path, tmp / f"out{k}") for k in range(args.repeat)]
    secs = sorted(r["seconds"] for r in runs)
    rss = max(r["peak_rss_mb"] for r in runs)
    out = {
        "faces": int(len(mesh.faces)),
        "runs": runs,
        "seconds_median": secs[len(secs) // 2],
        "peak_rss_mb": rss,
        "targets": {
            "seconds": {"target": f"<= {TARGET_S} s", "measured": secs[len(secs) // 2], "met": secs[len(secs) // 2] <= TARGET_S},
            "memory": {"target": f"<= {TARGET_MB:.0f} MB", "measured": rss, "met": rss <= TARGET_MB},
        },
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
