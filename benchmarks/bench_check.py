"""Identification figures as JSON: issue 11's targets, each with every setting it depends on.

    python benchmarks/bench_check.py [--frames 10000] [--big-frames 1000] [--ghost-frames 200] [--seed 0]

Families: the finger case's 25 most accurate, well separated stars (``starforge stars --count
25``) and the whole default finger family.  Each run is ``starforge check``'s simulation and
identification (:func:`starforge.tracking.check.run_check`, no curve, no plot).  Unless a run's
name says otherwise: open world (each cluster identified on its own), 0.2 mm noise per axis,
exactly one marker hidden per body and frame, no ghosts, the family's tolerance as the match
window, half of it as the residual limit, best-fit ranking.  ``seconds`` is the simulation and
identification alone (``check.json``'s ``seconds.main``).

The whole family with 2 ghosts per body costs about ten times the ghost-free run, so it runs
``--ghost-frames`` frames (its ``frames`` says how many).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time


def _bodyset(fam):
    from starforge.geometry.rigid import default_tip_mm
    from starforge.tracking.bodies import Body, BodySet

    tip = fam.spec.tip_mm if fam.spec.tip_mm is not None else default_tip_mm(fam.spec.box_mm)
    tip = tuple(float(x) for x in tip)
    bodies = tuple(Body(f"s{s.id:03d}", s.id, s.vertices, tip) for s in fam.stars)
    return BodySet("family", ("bench",), bodies, float(fam.spec.tol_mm), float(fam.spec.marker_mm), tip)


def _run(bodyset, frames, seed, **kw) -> dict:
    from starforge.tracking.check import CheckSettings, run_check

    s = CheckSettings(
        **{"frames": frames, "seed": seed, "curve_points": 0, "drop": 1, "drop_exact": True, **kw}
    )
    doc = run_check(bodyset, s)
    st = doc["settings"]
    row = {
        "settings": {
            k: st[k]
            for k in (
                "frames",
                "noise_mm",
                "drop",
                "drop_mode",
                "ghosts",
                "world",
                "presence",
                "match_mm",
                "residual_mm",
                "identify_from_markers",
                "choose",
                "preset",
            )
        },
        "seconds": doc["seconds"]["main"],
        "identified_percent": round(100 * doc["identification_rate"], 4),
        "wrong_body_percent": round(100 * doc["wrong_body_rate"], 4),
        "flip_percent": round(100 * doc["flip_rate"], 4),
        "missed_percent": round(100 * doc["missed_rate"], 4),
        "body_appearances": doc["instances"],
    }
    if "rules" in doc:
        rules: dict = {}
        for v in doc["rules"]["violations"]:
            rules[v["rule"]] = rules.get(v["rule"], 0) + 1
        row["rule_violations"] = rules
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--big-frames", type=int, default=1000)
    ap.add_argument("--ghost-frames", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()

    from starforge.stars.family import make_family
    from starforge.stars.spec import StarSpec

    base = StarSpec(box_mm=(20.8, 12.6, 48.3), marker_mm=4.0, delta_mm=1.5, name="finger")
    out: dict = {"benchmark": "check", "cpu_count": os.cpu_count(), "machine": platform.machine()}
    t = time.perf_counter()
    fam25 = make_family(StarSpec(**{**base.__dict__, "count": 25}))
    out["family25_seconds"] = round(time.perf_counter() - t, 2)
    t = time.perf_counter()
    famall = make_family(base)
    out["family_all_seconds"] = round(time.perf_counter() - t, 2)
    for label, fam in (("25", fam25), ("all", famall)):
        bs = _bodyset(fam)
        n = a.frames if label == "25" else a.big_frames
        rows = {
            "open_drop1_exact_no_ghosts": _run(bs, n, a.seed),
            "open_drop1_exact_2_ghosts": _run(bs, n if label == "25" else a.ghost_frames, a.seed, ghosts=2),
            "closed_drop1_exact_no_ghosts": _run(bs, n, a.seed, world="closed"),
        }
        if label == "25":
            rows["open_drop0to1_no_ghosts"] = _run(bs, n, a.seed, drop_exact=False)
            rows["closed_presence_0.5_no_ghosts"] = _run(bs, n, a.seed, world="closed", presence=0.5)
            rows["open_drop1_exact_choose_window"] = _run(bs, n, a.seed, choose="window")
            for preset in ("qualisys", "ndi", "optitrack"):
                rows[f"preset_{preset}_drop1_exact"] = _run(bs, n // 5, a.seed, preset=preset)
            # ART identifies from 4 markers only: nothing is hidden
            rows["preset_art_drop0"] = _run(bs, n // 5, a.seed, preset="art", drop=0, drop_exact=False)
        out[f"family_{label}"] = {
            "stars": len(fam.stars),
            "face_separation_mm": fam.summary["selection"].get("face_separation_mm", base.tol_mm),
            "runs": rows,
        }
    r25 = out["family_25"]["runs"]["open_drop1_exact_no_ghosts"]
    rall = out["family_all"]["runs"]["open_drop1_exact_no_ghosts"]
    out["targets"] = {
        "family_25 identified >= 99.9 %": [r25["identified_percent"], r25["identified_percent"] >= 99.9],
        "family_25 wrong body <= 0.05 %": [r25["wrong_body_percent"], r25["wrong_body_percent"] <= 0.05],
        "family_25 10,000 frames <= 30 s": [
            round(r25["seconds"] * 10000 / r25["settings"]["frames"], 2),
            r25["seconds"] * 10000 / r25["settings"]["frames"] <= 30,
        ],
        "family_all 1,000 frames <= 60 s": [
            round(rall["seconds"] * 1000 / rall["settings"]["frames"], 2),
            rall["seconds"] * 1000 / rall["settings"]["frames"] <= 60,
        ],
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
