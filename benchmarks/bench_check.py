"""Identification figures as JSON: issue 11's targets, each with every setting it depends on.

    python benchmarks/bench_check.py [--frames 10000] [--big-frames 1000] [--seed 0]

Families: the finger case's 25 most accurate, well separated stars (``starforge stars --count
25``) and the whole default finger family.  Each run is ``starforge check``'s simulation and
identification (no curve, no plot), open world unless it says closed, 0.2 mm noise per axis,
exactly one marker hidden per body and frame unless it says otherwise, match window = the
family's tolerance, residual = half of it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np


def _run(lib, frames, seed, **kw) -> dict:
    from starforge.tracking.identify import run

    args = {
        "noise_mm": 0.2,
        "drop": 1,
        "ghosts": 0,
        "drop_exact": True,
        "world": "open",
        "presence": 1.0,
        **kw,
    }
    t = time.perf_counter()
    tally = run(
        lib,
        frames,
        args["noise_mm"],
        args["drop"],
        args["ghosts"],
        np.random.default_rng(seed),
        args["match_mm"],
        args["residual_mm"],
        drop_exact=args["drop_exact"],
        world=args["world"],
        presence=args["presence"],
    )
    dt = time.perf_counter() - t
    r = tally.rates()
    return {
        "settings": {k: v for k, v in args.items()} | {"frames": frames},
        "seconds": round(dt, 2),
        "identified_percent": round(100 * r["identification_rate"], 4),
        "wrong_body_percent": round(100 * r["wrong_body_rate"], 4),
        "flip_percent": round(100 * r["flip_rate"], 4),
        "missed_percent": round(100 * r["missed_rate"], 4),
        "body_appearances": tally.instances,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--big-frames", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()

    from starforge.stars.family import make_family
    from starforge.stars.spec import StarSpec
    from starforge.tracking.identify import build_library

    base = StarSpec(box_mm=(20.8, 12.6, 48.3), marker_mm=4.0, delta_mm=1.5, name="finger")
    out: dict = {"cpu_count": os.cpu_count(), "machine": platform.machine()}
    t = time.perf_counter()
    fam25 = make_family(StarSpec(**{**base.__dict__, "count": 25}))
    out["family25_seconds"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    famall = make_family(base)
    out["family_all_seconds"] = round(time.perf_counter() - t, 2)
    win = {"match_mm": base.tol_mm, "residual_mm": base.tol_mm / 2}
    for label, fam in (("25", fam25), ("all", famall)):
        lib = build_library([s.vertices for s in fam.stars], [f"s{s.id}" for s in fam.stars])
        n = a.frames if label == "25" else a.big_frames
        rows = {
            "open_drop1_exact_no_ghosts": _run(lib, n, a.seed, **win),
            "open_drop1_exact_2_ghosts": _run(lib, n, a.seed, ghosts=2, **win),
            "open_drop0to1_no_ghosts": _run(lib, n, a.seed, drop_exact=False, **win),
            "closed_drop1_exact_no_ghosts": _run(lib, n, a.seed, world="closed", **win),
            "open_presence_0.5": _run(lib, n, a.seed, presence=0.5, **win),
        }
        out[f"family_{label}"] = {
            "stars": len(fam.stars),
            "face_separation_mm": fam.summary["selection"].get("face_separation_mm", base.tol_mm),
            "runs": rows,
        }
    out["targets"] = {
        "family_25.open_drop1_exact_no_ghosts": ">= 99.9 % identified, <= 0.05 % wrong body, 10,000 frames <= 30 s",
        "family_all.open_drop1_exact_no_ghosts": "rates reported; 1,000 frames <= 60 s",
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
