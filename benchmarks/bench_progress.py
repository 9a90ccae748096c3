"""How good the progress estimates are: a family's enumeration and an export, stage by stage, against the clock.

Runs ``make_family`` for a stars spec, then (``--export``) ``export_bodies`` of the default
family's first 25 stars with its plate and previews, each with a listener that records every
count and the time left the stage estimated then (:mod:`starforge.runtime.progress`), and prints
JSON: per stage its seconds and counts, and for the counts after the second the ratio of the
estimate to the time that really remained (within [0.5, 2] is the target; counts less than
0.5 s before the stage's total are left out: a person reads "about 1 s left" there).

    python benchmarks/bench_progress.py --delta 1.0 [--export]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

from starforge import api
from starforge.catalog import load_template
from starforge.runtime import progress
from starforge.stars.family import make_family
from starforge.stars.spec import spec_from_mapping


class Recorder:
    def __init__(self) -> None:
        self.events: list = []

    def started(self, st) -> None:
        self.events.append(("start", st.name, time.monotonic(), 0, st.total, None))

    def changed(self, st) -> None:
        self.events.append(("count", st.name, time.monotonic(), st.done, st.total, st.eta_s()))

    def ended(self, st) -> None:
        self.events.append(("end", st.name, time.monotonic(), st.done, st.total, None))

    def note(self, text: str) -> None:
        pass


def _at_total(counts, end: float) -> float:
    """When a stage's count first reached its total (its end when it never did)."""
    return next((t for t, done, total, _ in counts if total and done >= total), end)


def summary(rec: Recorder) -> dict:
    """Per stage: seconds, counts, the time after its total, and the estimate's ratio range."""
    stages: dict = {}
    for kind, name, t, done, total, eta in rec.events:
        s = stages.setdefault(name, {"start": t, "end": None, "counts": []})
        if kind == "end":
            s["end"] = t
        elif kind == "count":
            s["counts"].append((t, done, total, eta))
    out = {}
    for name, s in stages.items():
        end = s["end"] or time.monotonic()
        # before the count reaches its total (after it, the time left is the stage's wrap-up)
        ratios = [
            eta / (last - t)
            for t, done, total, eta in s["counts"][2:]
            if eta is not None and total and done < total and (last := _at_total(s["counts"], end)) - t > 0.5
        ]
        out[name] = {
            "seconds": round(end - s["start"], 2),
            "counts": len(s["counts"]),
            "after_the_total_s": round(end - _at_total(s["counts"], end), 2),
            "eta_over_actual_min": round(min(ratios), 3) if ratios else None,
            "eta_over_actual_max": round(max(ratios), 3) if ratios else None,
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spec", default="finger")
    ap.add_argument("--delta", type=float, default=1.0)
    ap.add_argument("--export", action="store_true", help="also export 25 bodies with plate and previews")
    args = ap.parse_args()
    spec = spec_from_mapping({**load_template("stars", args.spec)[1], "delta_mm": args.delta})
    rec = Recorder()
    t0 = time.monotonic()
    with progress.reporting(rec):
        enumerate_ = progress.stage("enumerate", unit="candidates")
        make_family(spec, progress=lambda d, n: enumerate_.update(d, n))
    out = {"spec": args.spec, "delta_mm": args.delta, "total_s": round(time.monotonic() - t0, 2)}
    out["stages"] = summary(rec)
    if args.export:
        family = api.make_family(api.plan_family(count=25, mount="flat"))
        rec = Recorder()
        t0 = time.monotonic()
        with tempfile.TemporaryDirectory() as tmp, progress.reporting(rec):
            api.export_bodies(family, f"{tmp}/bodies", preview=True)
        out["export"] = {"bodies": len(family), "total_s": round(time.monotonic() - t0, 2), "stages": summary(rec)}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
