"""Printable bodies, judged by what the printer meets; prints one JSON object.

For every mount: the finger case's 25 stars made for that mount (``starforge stars --count 25
--mount M``), exported as STEP + STL + 3MF with plates (in process, timed), then

* every file through the layer analysis (:mod:`starforge.cad.printability`): islands that start
  in mid-air, first-layer contact, overhang area;
* every single-star STL and 3MF and every plate through the PrusaSlicer command line, when it is
  installed: exit status, and the sliced height against the body's printing height;
* STEP against STL volumes.

A mount that cannot fit the finger limit at all is reported with the reason.

Usage: python benchmarks/bench_cad.py [--no-slicer] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import platform
import re
import shutil
import subprocess
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

MOUNTS = ("flat", "saddle", "magnet", "adhesive", "strap")


def _slice(path: Path, out: Path) -> dict:
    g = out / (path.name + ".gcode")
    t = time.perf_counter()
    res = subprocess.run(
        ["prusa-slicer", "--export-gcode", str(path), "--output", str(g)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    zs = [float(m) for m in re.findall(r"^;Z:([0-9.]+)", g.read_text(), flags=re.M)] if g.exists() else []
    return {
        "file": path.name,
        "ok": res.returncode == 0 and g.exists(),
        "sliced_top_mm": max(zs) if zs else None,
        "seconds": round(time.perf_counter() - t, 2),
        "error": "" if res.returncode == 0 else (res.stdout + res.stderr)[-300:],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--no-slicer", action="store_true")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()

    import trimesh

    from starforge.cad.body import BodySpec
    from starforge.cad.export import export_family, family_bodies
    from starforge.cad.mounts import load_mount
    from starforge.cad.printability import layer_report
    from starforge.cad.reserve import bodies_fit, mount_reserve_mm
    from starforge.errors import StarforgeError
    from starforge.stars.family import make_family
    from starforge.stars.spec import StarSpec

    slicer = shutil.which("prusa-slicer") if not args.no_slicer else None
    out: dict = {"machine": platform.machine(), "prusa_slicer": slicer, "mounts": {}}
    t = time.perf_counter()
    import build123d  # noqa: F401  (the one-off import, not part of the export timing)

    out["import_build123d_s"] = round(time.perf_counter() - t, 2)
    box = (20.8, 12.6, 48.3)
    for name in MOUNTS:
        m = load_mount(name)
        row: dict = {}
        try:
            reserve = mount_reserve_mm(m, 4.0)
            spec = StarSpec(box_mm=box, count=25, name=f"finger25_{name}", mount=name, reserve_mm=reserve)
            fam = make_family(spec, star_filter=lambda V, _m=m: bodies_fit(V, 4.0, box, _m))
        except StarforgeError as exc:
            out["mounts"][name] = {"refused": str(exc)}
            continue
        row["reserve_mm"] = list(reserve)
        bodies = family_bodies(fam, None, m, BodySpec())
        with tempfile.TemporaryDirectory() as tmp:
            stage = Path(tmp)
            t = time.perf_counter()
            rep = export_family(fam, stage, m, BodySpec(), bodies=bodies)
            row["export_25_with_plate_s"] = round(time.perf_counter() - t, 2)
            row["bodies_fit"] = sum(b["fits"] for b in rep.bodies)
            vols = [abs(b["mesh_volume_mm3"] / b["step_volume_mm3"] - 1) * 100 for b in rep.bodies]
            row["step_vs_stl_volume_percent_worst"] = round(max(vols), 5)
            files = sorted(stage.glob("*.stl")) + sorted(stage.glob("*.3mf"))
            reports = {f.name: layer_report(trimesh.load(f, force="mesh")) for f in stage.glob("*.stl")}
            row["midair_islands_total"] = sum(len(r["midair_islands"]) for r in reports.values())
            row["first_layer_mm2_min"] = min(r["first_layer_mm2"] for r in reports.values())
            row["overhang_mm2_max"] = max(r["overhang_mm2"] for r in reports.values())
            if slicer:
                heights = {b["name"]: b["print_height_mm"] for b in rep.bodies}
                with ThreadPoolExecutor(args.jobs) as ex:
                    sliced = list(ex.map(_slice, files, [stage] * len(files)))
                bad_h = [
                    s["file"]
                    for s in sliced
                    if s["ok"]
                    and Path(s["file"]).stem in heights
                    and abs(s["sliced_top_mm"] - heights[Path(s["file"]).stem]) > 0.35
                ]
                row["slicer_files"] = len(sliced)
                row["slicer_ok"] = sum(s["ok"] for s in sliced)
                row["slicer_failures"] = [s for s in sliced if not s["ok"]][:5]
                row["height_mismatches"] = bad_h
        out["mounts"][name] = row
    out["targets"] = {
        "every mount": "every single-star STL/3MF and plate slices; sliced height = printing height; no mid-air start; "
        "STEP vs STL volume within 0.01 %",
        "export_25_with_plate_s": "<= 5 s in process",
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
