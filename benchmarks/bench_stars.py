"""Star-engine speed figures as JSON (the paper's finger case unless told otherwise).

    python benchmarks/bench_stars.py [--rule face|pair] [--repeat 3]

Measures: `starforge --help` start-up; enumeration alone (in process); the whole
`starforge stars` CLI run end to end in a fresh process (start-up, enumeration, selection,
verification, writing); candidates per second; selection time; family size, bound and gap.
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


def _wall(cmd: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rule", default="face", choices=["face", "pair"])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    from starforge.stars.enumerate import enumerate_candidates
    from starforge.stars.spec import StarSpec

    spec = StarSpec(box_mm=(20.8, 12.6, 48.3), marker_mm=4.0, delta_mm=1.5, rule=args.rule)
    exe = [sys.executable, "-m", "starforge"]
    help_s = min(_wall([*exe, "--help"]) for _ in range(args.repeat))
    enum_s = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        c = enumerate_candidates(spec)
        enum_s.append(time.perf_counter() - t)
    e2e = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            out = Path(tmp) / f"run{i}"
            e2e.append(
                _wall([*exe, "stars", "--box", "20.8", "12.6", "48.3", "--marker", "4", "--delta", "1.5",
                       "--rule", args.rule, "--out", str(out), "-q"])
            )
        doc = json.loads((Path(tmp) / "run0" / "family.json").read_text())
        run = json.loads((Path(tmp) / "run0" / "run.json").read_text())
    sm = doc["summary"]
    print(json.dumps({
        "case": "finger 20.8 x 12.6 x 48.3 mm, 4 mm markers, delta 1.5 mm",
        "rule": args.rule,
        "select": doc["spec"]["select"],
        "cpu_count": os.cpu_count(),
        "help_s": round(help_s, 3),
        "enumerate_s": round(min(enum_s), 3),
        "labelled_candidates": c.stats["labelled"],
        "candidates_per_s": round(c.stats["labelled"] / min(enum_s)),
        "fitting_candidates": c.stats["fitting"],
        "end_to_end_cli_s": round(min(e2e), 3),
        "cli_stage_s": run["seconds"],
        "family_size": sm["size"],
        "upper_bound": sm["upper_bound"],
        "gap": sm["gap"],
        "paper_family_size": 25,
    }, indent=2))


if __name__ == "__main__":
    main()
