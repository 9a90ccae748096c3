"""Identification speed: 10,000 frames of a 25-star family with drop 1; prints one JSON object.

The family is the paper's finger case (20.8 x 12.6 x 48.3 mm, 4 mm markers, delta 1.5 mm,
face rule) cut to 25 stars.  Timed: simulation + identification (``starforge check``'s main
run, no curve, no plot), with 0..1 markers hidden per body and frame.  Also timed: exactly one
hidden (``_exact_drop``), and 2 ghost points per body (``_ghosts2``).

    python benchmarks/bench_check.py [--frames 10000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()

    from starforge.stars.family import make_family
    from starforge.stars.spec import StarSpec
    from starforge.tracking.identify import build_library, run

    t0 = time.perf_counter()
    fam = make_family(StarSpec(box_mm=(20.8, 12.6, 48.3), count=25))
    t_family = time.perf_counter() - t0
    lib = build_library([s.vertices for s in fam.stars])
    tol = fam.spec.tol_mm
    out = {
        "benchmark": "check",
        "bodies": len(fam.stars),
        "frames": a.frames,
        "drop": 1,
        "drop_mode": "uniform 0..drop",
        "noise_mm": 0.2,
        "match_mm": tol,
        "residual_mm": tol / 2,
        "family_seconds": round(t_family, 3),
    }
    for ghosts, exact in ((0, False), (0, True), (2, False)):
        rng = np.random.default_rng(a.seed)
        t = time.perf_counter()
        tally = run(lib, a.frames, 0.2, 1, ghosts, rng, match_mm=tol, residual_mm=tol / 2, drop_exact=exact)
        dt = time.perf_counter() - t
        r = tally.rates()
        key = ("" if ghosts == 0 else f"_ghosts{ghosts}") + ("_exact_drop" if exact else "")
        out[f"seconds{key}"] = round(dt, 3)
        out[f"frames_per_s{key}"] = round(a.frames / dt, 1)
        out[f"body_ids_per_s{key}"] = round(a.frames * len(fam.stars) / dt, 1)
        out[f"identification_rate{key}"] = r["identification_rate"]
        out[f"mislabel_rate{key}"] = r["mislabel_rate"]
    out["under_30_s"] = out["seconds"] < 30.0
    out["cpu"] = platform.processor() or platform.machine()
    out["cores"] = os.cpu_count()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
