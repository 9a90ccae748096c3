"""Speed figures of ``starforge place`` (prints one JSON object).

* ``e2e_default_s``: ``starforge place hammer`` with default settings (1000 sites, 4^3 = 64
  positions, 8 cameras, the default spec), end to end through the CLI in a fresh process,
  start-up included (median of 3).
* ``optimization_s``: sampling + visibility table + annealing (all restarts) in-process with the
  default settings; the paper needed 585 s for one optimization.  Split in ``stages_s``.
* ``chain_iterations_per_s``: annealing steps per second at a fixed temperature of 1 (every
  proposal scored, the slowest case), 200,000 steps on the hammer's default sites.
* ``e2e_res12_s``: the CLI with ``--resolution 12`` (1728 positions).
* ``big_mesh``: a 200k-face prop with 5000 sites through the CLI: wall time and peak RSS (MB)
  of that process (``resource.getrusage(RUSAGE_CHILDREN)`` in a wrapper process).

Run: ``python benchmarks/bench_place.py``.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _cli(args, cwd) -> float:
    t = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "starforge", *args],
        cwd=cwd,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return time.perf_counter() - t


_RSS = """
import resource, subprocess, sys, time, json
t = time.perf_counter()
subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
print(json.dumps({"wall_s": time.perf_counter() - t,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
"""


def _big_mesh(path: Path) -> int:
    import numpy as np
    import trimesh

    m = trimesh.creation.uv_sphere(radius=0.15, count=[224, 224])
    v = m.vertices
    bump = 1 + 0.08 * np.sin(7 * np.arctan2(v[:, 1], v[:, 0])) * np.cos(5 * v[:, 2] / 0.15)
    m.vertices = v * bump[:, None] * np.array([1.0, 0.7, 1.6])
    m.export(path)
    return len(m.faces)


def main() -> None:
    import numpy as np

    from starforge.props.mesh import load_prop
    from starforge.props.optimizer import ChainSettings, run_chain
    from starforge.props.placement import load_spec, place

    out: dict = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(),
        }
    }
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        _cli(["place", "hammer", "--out", str(tmp / "warm"), "-q"], tmp)  # warm the file cache
        runs = [_cli(["place", "hammer", "--out", str(tmp / f"d{k}"), "-q"], tmp) for k in range(3)]
        out["e2e_default_s"] = round(statistics.median(runs), 3)
        out["e2e_default_runs_s"] = [round(r, 3) for r in runs]

        spec = load_spec("default")
        prop = load_prop("hammer")
        res = place(prop, spec, seed=0)
        stages = {k: v for k, v in res.timings.items() if k.endswith("_s")}
        out["optimization_s"] = round(stages["sample_s"] + stages["visibility_s"] + stages["optimize_s"], 3)
        out["stages_s"] = stages
        out["rays"] = res.rays
        out["chain_iterations_default"] = int(sum(r.iterations for r in res.anneal.runs))
        out["paper_s_per_optimization"] = 585.44

        pts, vis = res.sites.points, res.site_visibility
        ch = ChainSettings(fixed_temperature=1.0, max_iterations=200_000)
        t = time.perf_counter()
        r = run_chain(pts, vis, spec.costs, ch, np.random.default_rng(0))
        dt = time.perf_counter() - t
        out["chain_iterations_per_s"] = int(r.iterations / dt)

        out["e2e_res12_s"] = round(
            _cli(["place", "hammer", "--resolution", "12", "--out", str(tmp / "r12"), "-q"], tmp), 3
        )

        faces = _big_mesh(tmp / "big.ply")
        proc = subprocess.run(
            [
                sys.executable,
                "-c",
                _RSS,
                sys.executable,
                "-m",
                "starforge",
                "place",
                str(tmp / "big.ply"),
                "--sites",
                "5000",
                "--out",
                str(tmp / "big"),
                "-q",
            ],
            check=True,
            capture_output=True,
            text=True,
            cwd=tmp,
        )
        big = json.loads(proc.stdout)
        out["big_mesh"] = {
            "faces": faces,
            "sites": 5000,
            "wall_s": round(big["wall_s"], 3),
            "peak_rss_mb": round(big["peak_rss_mb"], 1),
        }
    out["targets"] = {
        "e2e_default_s": 3.0,
        "optimization_s": 1.0,
        "chain_iterations_per_s": 20000,
        "e2e_res12_s": 15.0,
        "big_mesh_peak_rss_mb": 2048,
    }
    out["pass"] = bool(
        out["e2e_default_s"] < 3
        and out["optimization_s"] < 1
        and out["chain_iterations_per_s"] >= 20000
        and out["e2e_res12_s"] < 15
        and out["big_mesh"]["peak_rss_mb"] < 2048
    )
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
