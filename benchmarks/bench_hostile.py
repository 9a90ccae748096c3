"""The hostile suite as one figure: every case of tests/test_hostile_inputs.py,
tests/test_hostile_readers.py and tests/test_hostile_matrix.py (each the real CLI in a child process with a capped address space,
a CPU budget and a wall-clock limit; a full disk; concurrent runs on one folder), counted.

Prints JSON: cases clean / total and per kind of case (one line, exit 2 or a correct result, nothing left behind, no
process left, no traceback or warning on stderr, at most 10 CPU s and 2 GB), the slowest case in
CPU and in wall-clock seconds (the machine's load average is printed beside them), and the
largest peak memory of a command (the child's own maximum resident set).  With ``--all`` the
runtime cases (tests/test_hostile_runtime.py: scheduler endpoints, lost workers, signals) run
too and are counted by pytest's outcome (benchmarks/bench_scheduler.py and
benchmarks/bench_signals.py repeat those with figures of their own).

Run from the repository root: ``python benchmarks/bench_hostile.py [--all] [-k EXPR]``.
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

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all", action="store_true", help="also the runtime cases (minutes: clusters and signals)")
    ap.add_argument("-k", default=None, help="only the cases matching this pytest expression")
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as d:
        report = Path(d) / "cases.jsonl"
        junit = Path(d) / "junit.xml"
        files = ["tests/test_hostile_inputs.py", "tests/test_hostile_readers.py", "tests/test_hostile_matrix.py"]
        files += ["tests/test_hostile_runtime.py"] if opts.all else []
        cmd = [sys.executable, "-m", "pytest", *files, "-q", "-p", "no:cacheprovider", "-m", "",
               f"--junitxml={junit}",
               # the in-process twins of the cases check the same things without the figures
               "-k", f"not in_process and ({opts.k})" if opts.k else "not in_process"]
        env = {**os.environ, "STARFORGE_HOSTILE_REPORT": str(report), "PYTHONPATH": str(ROOT)}
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        wall = time.perf_counter() - t0
        rows = [json.loads(line) for line in report.read_text().splitlines()] if report.exists() else []
        tests, failed = _junit_counts(junit)
    timed = [r for r in rows if r["seconds"] is not None]
    peaks = [r for r in rows if r["peak_kb"] is not None]
    slowest = max(timed, key=lambda r: r["seconds"], default=None)
    busiest = max((r for r in rows if r.get("cpu_seconds") is not None), key=lambda r: r["cpu_seconds"], default=None)
    largest = max(peaks, key=lambda r: r["peak_kb"], default=None)
    print(json.dumps({
        "cases_clean": sum(r["clean"] for r in rows),
        "cases_total": len(rows),
        "per_kind": {k: f"{sum(r['clean'] for r in rows if r.get('kind') == k)}/"
                        f"{sum(1 for r in rows if r.get('kind') == k)}"
                     for k in sorted({r.get("kind") or "" for r in rows})},
        "not_clean": [{k: r.get(k) for k in ("case", "code", "said", "why")} for r in rows if not r["clean"]],
        "worst_seconds": round(slowest["seconds"], 2) if slowest else None,
        "worst_seconds_case": slowest["case"] if slowest else None,
        "worst_cpu_seconds": round(busiest["cpu_seconds"], 2) if busiest else None,
        "worst_cpu_seconds_case": busiest["case"] if busiest else None,
        "worst_peak_mb": round(largest["peak_kb"] / 1024, 1) if largest else None,
        "worst_peak_case": largest["case"] if largest else None,
        "pytest_tests": tests,
        "pytest_failed": len(failed),
        "pytest_failed_tests": failed,
        "wall_seconds": round(wall, 1),
        "load_average": os.getloadavg(),
    }, indent=2))


def _junit_counts(path: Path) -> tuple[int, list[str]]:
    """(tests run, the names of the tests that failed or errored) from pytest's JUnit XML report."""
    import xml.etree.ElementTree as ET

    if not path.exists():
        return 0, []
    suite = ET.parse(path).getroot()
    suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
    failed = [case.get("name") for case in suite.iter("testcase")
              if case.find("failure") is not None or case.find("error") is not None]
    return int(suite.get("tests", 0)), failed


if __name__ == "__main__":
    main()
