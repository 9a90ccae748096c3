"""Fleets a tracker must tell apart from three markers: JSON on stdout.

Two runs of ``starforge place-batch`` at the default spec (what a user gets):

* ``props``: four real props in one batch (a bottle, a gable-top milk carton, a mug and a drill,
  the meshes of ``bench_props_real.py``);
* ``copies``: ``place-batch hammer --copies 10``, ten layouts on one hammer.

Each fleet is then checked by ``starforge check``'s simulator (:func:`starforge.tracking.check.
run_check`, the rules :mod:`tests.test_tracking_bruteforce` re-checks by brute force) on the
placement.json files the command wrote, read back as ``check`` reads them: exactly three markers
of every layout seen, 0.2 mm noise, every headline rule, ``--frames`` frames (a seed of its own,
not the command's).  Reported per fleet: the wrong body + wrong pose rate under each rule and the
worst (target <= 0.1 %), each layout's tracked fraction on the placement's fresh poses (the hand,
half the cameras lost), its self-margins from any 3 and any 4 markers and its closest other
layout, the closest pair, the layouts placed again, and the wall time.

Run: ``python benchmarks/bench_fleet.py [--frames 10000] [--copies 10] [--workers 1] [--spec default]
[--write-docs]`` (``--write-docs`` also writes the figures into the docs' results page,
``docs/results.md``, section ``fleet``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_props_real import props as real_props  # noqa: E402

REAL = ("bottle", "milk_carton", "mug", "drill")
NOISE_MM = 0.2
TARGET = 0.001


def check_fleet(folder: Path, frames: int, seed: int) -> dict:
    """The fleet written to ``folder`` (one placement.json per layout, as batch.csv lists them)
    through ``check``'s reader and simulator, exactly 3 markers of every layout seen."""
    import csv

    from starforge.props.distinct import subset_margin
    from starforge.tracking.bodies import Body, BodySet, load_bodies
    from starforge.tracking.check import CheckSettings, run_check
    from starforge.tracking.library import build_library, drop1_margin_mm

    rows = list(csv.DictReader((folder / "batch.csv").read_text().splitlines()))
    bodies = []
    for i, r in enumerate(rows):
        b = load_bodies([folder / r["job"] / "placement.json"]).bodies[0]
        bodies.append(Body(r["job"], i + 1, b.points_mm))
    nmax = max(len(b.points_mm) for b in bodies)
    s = CheckSettings(
        noise_mm=NOISE_MM, drop=nmax - 3, drop_exact=True, frames=frames, seed=seed, curve_points=0
    )
    doc = run_check(BodySet("placement", (), tuple(bodies)), s)
    by_rule = {
        r: {k: v[k] for k in ("identification_rate", "wrong_body_rate", "flip_rate", "mislabel_rate")}
        for r, v in doc["by_rule"].items()
    }
    worst = max(by_rule[r]["mislabel_rate"] for r in doc["headline_rules"])
    layouts = []
    for r, b in zip(rows, bodies, strict=True):
        pdoc = json.loads((folder / r["job"] / "placement.json").read_text())
        layouts.append({
            "layout": r["job"],
            "markers": len(b.points_mm),
            "tracked_fresh_poses": (pdoc.get("evaluation") or {}).get("default", {}).get("tracked"),
            "self_margin_3_mm": round(float(drop1_margin_mm(build_library([b.points_mm]))), 3),
            "self_margin_4_mm": round(float(subset_margin(b.points_mm, 4)), 3),
            "closest": r["closest"],
            "closest_margin_mm": float(r["closest_margin_mm"]) if r["closest_margin_mm"] else None,
        })  # fmt: skip
    for x, r in zip(layouts, rows, strict=True):
        x["placed_again"] = r["placed_again"] == "1"
    pair = min(layouts, key=lambda x: x["closest_margin_mm"] if x["closest_margin_mm"] is not None else 1e9)
    return {
        "frames": frames,
        "window_mm": round(doc["settings"]["match_mm"], 4),
        "window_source": doc["settings"]["window_source"],
        "by_rule": by_rule,
        "wrong_rate_worst_headline": worst,
        "target_wrong_rate": TARGET,
        "target_met": worst <= TARGET,
        "closest_pair": {"a": pair["layout"], "b": pair["closest"], "margin_mm": pair["closest_margin_mm"]},
        "placed_again": [x["layout"] for x in layouts if x["placed_again"]],
        "min_self_margin_3_mm": min(x["self_margin_3_mm"] for x in layouts),
        "min_tracked_fresh_poses": min(x["tracked_fresh_poses"] or 0.0 for x in layouts),
        "layouts": layouts,
    }


def run(args_cli: list[str], out: Path) -> tuple[float, str]:
    """``starforge place-batch`` in this process; (wall seconds, its output)."""
    import contextlib
    import io

    from starforge.cli import main

    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        rc = main(["place-batch", *args_cli, "--out", str(out), "--noise", str(NOISE_MM)])
    if rc != 0:
        raise SystemExit(f"place-batch failed ({rc}): {' '.join(args_cli)}")
    return time.perf_counter() - t0, buf.getvalue()


def write_docs(out: dict) -> None:
    """The fleets of ``out`` as the results page's section on fleets."""
    from _results import table, write_section

    def pct(x):
        return f"{100 * x:.3f} %"

    rows, layouts = [], []
    for key, title in (("props", "4 real props (" + ", ".join(REAL) + ")"), ("copies", "")):
        if key not in out:
            continue
        f = out[key]
        title = title or f"`{f['prop']}` x {f['copies']} copies"
        rules = ", ".join(f"{r} {pct(v['mislabel_rate'])}" for r, v in f["by_rule"].items())
        rows.append([title, len(f["layouts"]), f"{f['closest_pair']['a']} / {f['closest_pair']['b']}: {f['closest_pair']['margin_mm']:g}",
                     f["min_self_margin_3_mm"], f["window_mm"], rules, pct(f["wrong_rate_worst_headline"]),
                     "yes" if f["target_met"] else "no", f["min_tracked_fresh_poses"], ", ".join(f["placed_again"]) or "none", f["seconds"]])  # fmt: skip
        layouts += [[title if i == 0 else "", x["layout"], x["markers"], x["tracked_fresh_poses"], x["self_margin_3_mm"],
                     x["self_margin_4_mm"], f"{x['closest']} ({x['closest_margin_mm']:g})"] for i, x in enumerate(f["layouts"])]  # fmt: skip
    frames = next(out[k]["frames"] for k in ("props", "copies") if k in out)
    body = (
        f"`starforge place-batch` at the `{out['spec']}` spec with `--noise {out['noise_mm']:g}`, each fleet then "
        "read back from its placement.json files and checked by `starforge check`'s simulator (its own seed, "
        f"{frames:,} frames): exactly {out['markers_seen']} markers of every layout seen, 0.2 mm noise, every rule; "
        "wrong: wrong body + wrong pose (target <= 0.1 % under every headline rule).  Closest pair: the two "
        "layouts whose marker triangles come closest (mm); self-margin: the least distance between two of a "
        "layout's own triangles, or one relabelled (mm); tracked: the least, over the layouts, of the share of "
        "the placement's fresh poses (the hand, half the cameras lost) tracked; placed again: layouts the "
        "batch re-optimized to keep apart from the others.\n\n"
        + table(["fleet", "layouts", "closest pair (mm)", "least self-margin (mm)", "window (mm)", "wrong, by rule",
                 "wrong, worst headline", "target met", "least tracked", "placed again", "seconds"], rows)
        + "\n\nEach layout:\n\n"
        + table(["fleet", "layout", "markers", "tracked", "self-margin, 3 (mm)", "self-margin, 4 (mm)", "closest (mm)"], layouts)
    )  # fmt: skip
    write_section("fleet", "Fleets a tracker tells apart from three markers", body)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10000, help="frames of the independent check")
    ap.add_argument("--copies", type=int, default=10)
    ap.add_argument("--workers", default="1", help="place-batch --workers (1: in this process)")
    ap.add_argument("--spec", default="default", help="place-batch --spec (the figures: default)")
    ap.add_argument("--part", default="props,copies")
    ap.add_argument("--write-docs", action="store_true", help="also write the figures into docs/results.md")
    args = ap.parse_args(argv)
    parts = args.part.split(",")
    meshes = real_props()
    out = {"spec": args.spec, "noise_mm": NOISE_MM, "markers_seen": 3}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        common = ["--spec", args.spec, "--workers", args.workers, "-q"]
        if "props" in parts:
            paths = []
            for name in REAL:
                p = tmp / f"{name}.stl"
                meshes[name].export(p)
                paths.append(str(p))
            sec, _ = run([*paths, *common], tmp / "props")
            out["props"] = {
                "props": list(REAL),
                "seconds": round(sec, 1),
                **check_fleet(tmp / "props", args.frames, 1),
            }
            print("props", json.dumps(out["props"]), file=sys.stderr)
        if "copies" in parts:
            sec, _ = run(["hammer", "--copies", str(args.copies), *common], tmp / "copies")
            out["copies"] = {
                "prop": "hammer",
                "copies": args.copies,
                "seconds": round(sec, 1),
                **check_fleet(tmp / "copies", args.frames, 2),
            }
    print(json.dumps(out, indent=2))
    if args.write_docs:
        write_docs(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
