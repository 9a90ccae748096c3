"""A lab's bodies through ``starforge convert`` and ``starforge measure``; prints one JSON object.

* convert: 100 tracker files (the real vendor file of tests/data/vendor and its bodies written
  in every format, 100 in all) converted to each format by the command line, wall clock
  of the whole command (interpreter start included), and by the library alone;
* measure: a synthetic C3D recording (ezc3d) of 12 four-marker bodies and 2 loose markers (50
  markers), 10 minutes at 200 Hz, 0.2 mm noise, 5 % gaps, measured by the command line: wall
  clock, the child's peak resident memory, and the worst body's distance error against the truth.

``targets`` says per target of the issue what was measured and whether it is met.  Timings are
wall clock on whatever machine runs this (the JSON names it and its load); run it on an idle one.

Usage: python benchmarks/bench_convert.py [--minutes 10] [--rate 200]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from starforge.tracking.convert import convert_to, read_records
from starforge.tracking.formats import FORMATS
from starforge.tracking.recording import simulate_recording, write_c3d

ROOT = Path(__file__).resolve().parent.parent
VENDOR = ROOT / "tests" / "data" / "vendor"


def _cli(args: list[str]) -> dict:
    """Wall and CPU seconds (user + system) and peak RSS (MB) of ``python -m starforge args``,
    that child's own (os.wait4)."""
    return _child([sys.executable, "-m", "starforge", *args])


def _child(cmd: list[str]) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL)
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd[:4])} ... failed ({proc.returncode})")
    return {
        "wall_s": round(wall, 3),
        "cpu_s": round(ru.ru_utime + ru.ru_stime, 3),
        "peak_rss_mb": round(ru.ru_maxrss / 1024.0, 1),
    }


def _hundred_files(folder: Path) -> list[Path]:
    """100 tracker files: the vendor files of tests/data/vendor, then their bodies written in
    every format, round after round."""
    real = sorted(p for p in VENDOR.iterdir() if p.suffix != ".md")
    files = list(real)
    source = read_records(real)
    for k in itertools.count():
        for fmt in FORMATS:
            for rel, data in convert_to(source, fmt).files.items():
                if len(files) >= 100:
                    return files
                path = folder / f"{k}_{fmt}_{rel}"
                path.write_bytes(data)
                files.append(path)
    return files


def bench_convert(tmp: Path) -> dict:
    src = tmp / "lab"
    src.mkdir()
    files = _hundred_files(src)
    out: dict = {"files": len(files), "cli": {}, "library_s": {}}
    for fmt in FORMATS:
        if fmt == "atracsys":  # bodies of more than 6 markers: the command refuses, by design
            continue
        args = ["convert", *map(str, files), "--format", fmt, "--out", str(tmp / f"out_{fmt}"), "-q"]
        out["cli"][fmt] = _cli(args)
        t0 = time.perf_counter()
        convert_to(read_records(files), fmt)
        out["library_s"][fmt] = round(time.perf_counter() - t0, 3)
    return out


def _truth(seed: int = 0) -> list:
    """12 four-marker bodies, every pair 20-120 mm apart."""
    rng = np.random.default_rng(seed)
    truth = []
    while len(truth) < 12:
        P = rng.uniform(-50, 50, (4, 3))
        if np.linalg.norm(P[:, None] - P[None], axis=2)[np.triu_indices(4, 1)].min() > 20:
            truth.append(P)
    return truth


def write_recording(path: Path, minutes: float, rate: float) -> None:
    """The measured recording (run in a child, so that this process stays small: a child's
    peak memory counts what its parent held when it was forked)."""
    rng = np.random.default_rng(1)
    frames = int(round(minutes * 60 * rate))
    rec = simulate_recording(_truth(), frames, 0.2, 0.05, rng, rate)
    loose = rng.uniform(-2000, 2000, (frames, 2, 3))  # two markers that belong to no body
    P = np.concatenate([rec.points_mm, loose], axis=1)
    write_c3d(path, [*rec.labels, "loose1", "loose2"], P, rate)


def bench_measure(tmp: Path, minutes: float, rate: float) -> dict:
    path = tmp / "long.c3d"
    script = [sys.executable, str(Path(__file__).resolve()), "--write", str(path)]
    written = _child([*script, "--minutes", str(minutes), "--rate", str(rate)])
    run = _cli(["measure", str(path), "--out", str(tmp / "m"), "-q"])
    report = json.loads((tmp / "m" / "measure.json").read_text())
    truth = _truth()
    worst = 0.0
    for b in report["bodies"]:
        i = int(b["labels"][0].split("_")[0][1:]) - 1
        M, T = np.array(b["points_mm"]), truth[i]
        pairs = list(itertools.combinations(range(4), 2))
        d = [abs(np.linalg.norm(M[a] - M[c]) - np.linalg.norm(T[a] - T[c])) for a, c in pairs]
        worst = max(worst, float(max(d)))
    return {
        "frames": int(round(minutes * 60 * rate)),
        "markers": 50,
        "c3d_mb": round(path.stat().st_size / 1e6, 1),
        "write_c3d_s": written["wall_s"],
        "cli": run,
        "bodies_found": len(report["bodies"]),
        "worst_distance_error_mm": round(worst, 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--write", help=argparse.SUPPRESS)  # the child that writes the recording
    a = ap.parse_args()
    if a.write:
        write_recording(Path(a.write), a.minutes, a.rate)
        return
    with tempfile.TemporaryDirectory(prefix="bench_convert.") as tmp:
        tmp = Path(tmp)
        (tmp / "c").mkdir()
        (tmp / "m").mkdir()
        conv = bench_convert(tmp / "c")
        meas = bench_measure(tmp / "m", a.minutes, a.rate)
    worst_cli = max(v["wall_s"] for v in conv["cli"].values())
    m = meas["cli"]
    print(
        json.dumps(
            {
                "machine": {
                    "python": platform.python_version(),
                    "cpus": os.cpu_count(),
                    "load": os.getloadavg(),
                },
                "convert": conv,
                "measure": meas,
                "targets": {
                    "convert 100 files <= 2 s (slowest format, whole command, wall)": [
                        worst_cli,
                        bool(worst_cli <= 2.0),
                    ],
                    "measure 10-minute 200 Hz C3D of 50 markers <= 10 s (wall)": [
                        m["wall_s"],
                        bool(m["wall_s"] <= 10.0),
                    ],
                    "... and <= 1 GB": [m["peak_rss_mb"], bool(m["peak_rss_mb"] <= 1024.0)],
                    "measured bodies within 0.05 mm": [
                        meas["worst_distance_error_mm"],
                        bool(meas["worst_distance_error_mm"] <= 0.05),
                    ],
                },
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
