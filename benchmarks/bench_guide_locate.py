"""How well the rigging guide's landmark readings locate each marker; JSON on stdout.

For the built-in hammer and the eight props of ``bench_props_real.py`` (placed by
``run_placement`` at the default spec, seed 0), per marker:

* the guide's stated locating error (``placement.json``'s ``locating_error_mm``: how far 95 %
  of marks set from its three readings land, under the tape model of
  :mod:`starforge.props.guide`) for the three landmarks it names, and the same model's figure
  for the nearest three landmarks (what the guide named before it chose);
* both checked by brute force (:mod:`_locate`): ``TRIALS`` sets of noisy readings each solved
  over a dense sample of the surface round the mark, the 95th percentile of how far the
  solutions land (``solved_p95_mm``) and the share within the stated error
  (``within_stated``);
* how many markers the readings place within the seat's placement error (the rest the guide
  sends to the drawings), and how many are set off one landmark on their own face in a named
  direction instead (``set_off_one``: judged by eye, so not solved here).

Run: ``python benchmarks/bench_guide_locate.py [--props hammer,bottle] [--write-docs]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TRIALS = 200


def _props() -> dict:
    from bench_props_real import props

    from starforge.props.builtin import builtin_mesh

    return {"hammer": builtin_mesh("hammer"), **props()}


def _marker_rows(res, rng) -> list[dict]:
    from _locate import solved_offsets

    from starforge.props.guide import locating_errors, surface_sample

    mesh = res.prop.mesh
    features, marks = res.rigging
    lp = np.array([f["point"] for f in features])
    index = {f["name"]: i for i, f in enumerate(features)}
    surface = surface_sample(mesh)
    rows = []
    for p, n, m in zip(res.marker_points, res.marker_normals, marks, strict=True):
        chosen = [index[x["name"]] for x in m["measure_from"]]
        near = np.argsort(np.linalg.norm(lp - p, axis=1), kind="stable")[:3]
        poor = float(locating_errors(p, n, lp, [near], surface)[0]) if len(near) == 3 else np.inf
        row = {"stated_mm": m["locating_error_mm"], "nearest_stated_mm": round(poor, 2) if np.isfinite(poor) else None}
        row["set_off_one"] = "towards" in m["measure_from"][0]  # the direction judged by eye: no readings to solve
        for key, which in (("chosen", chosen), ("nearest", near)):
            if len(which) != 3:
                row[f"{key}_solved_p95_mm"] = row[f"{key}_within_stated"] = None
                continue
            off = solved_offsets(mesh, p, n, lp[which], rng, TRIALS)
            row[f"{key}_solved_p95_mm"] = round(float(np.percentile(off, 95)), 2)
            stated = row["stated_mm" if key == "chosen" else "nearest_stated_mm"]
            row[f"{key}_within_stated"] = None if stated is None else round(float(np.mean(off <= stated)), 3)
        rows.append(row)
    return rows


def _mm(x) -> float | None:
    """``x`` rounded to 0.01 mm; None (no figure: the readings cannot place it) when infinite."""
    return round(float(x), 2) if np.isfinite(x) else None


def _median(values) -> float | None:
    """The median of the figures that are there (None: none is)."""
    got = [v for v in values if v is not None]
    return round(float(np.median(got)), 2) if got else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--props", default="")
    ap.add_argument("--write-docs", action="store_true", help="also write the table into docs/results.md")
    args = ap.parse_args(argv)
    from starforge.props.placement import run_placement

    meshes = _props()
    wanted = [p for p in args.props.split(",") if p] or list(meshes)
    out = {"trials": TRIALS, "props": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name in wanted:
            t0 = time.perf_counter()
            if name == "hammer":
                res = run_placement("hammer", seed=0)
            else:
                path = Path(tmp) / f"{name}.stl"
                meshes[name].export(path)
                res = run_placement(str(path), seed=0)
            rows = _marker_rows(res, np.random.default_rng(5))
            err = res.spec.seat.placement_error_mm
            stated = np.array([np.inf if r["stated_mm"] is None else r["stated_mm"] for r in rows])
            nearest = np.array([np.inf if r["nearest_stated_mm"] is None else r["nearest_stated_mm"] for r in rows])
            out["props"][name] = {
                "markers": len(rows),
                "placement_error_mm": err,
                "within_placement_error": int((stated <= err).sum()),
                "nearest_within_placement_error": int((nearest <= err).sum()),
                "median_stated_mm": _mm(np.median(stated)),
                "median_nearest_stated_mm": _mm(np.median(nearest)),
                "set_off_one": sum(r["set_off_one"] for r in rows),
                "median_solved_p95_mm": _median(r["chosen_solved_p95_mm"] for r in rows),
                "median_nearest_solved_p95_mm": _median(r["nearest_solved_p95_mm"] for r in rows),
                "landmarks": len(res.rigging[0]),
                "min_within_stated": min((r["chosen_within_stated"] for r in rows if r["chosen_within_stated"] is not None), default=None),
                "seconds": round(time.perf_counter() - t0, 1),
                "per_marker": rows,
            }
            print(f"{name}: {out['props'][name]['within_placement_error']}/{len(rows)} within {err:g} mm", file=sys.stderr)
    props_ = out["props"].values()
    out["within_placement_error"] = sum(v["within_placement_error"] for v in props_)
    out["nearest_within_placement_error"] = sum(v["nearest_within_placement_error"] for v in props_)
    out["markers"] = sum(v["markers"] for v in props_)
    print(json.dumps(out, indent=1))
    if args.write_docs:
        write_docs(out)
    return 0


def write_docs(out: dict) -> None:
    """The figures of ``out`` as the results page's section on the guide's landmark readings."""
    from _results import table, write_section

    def cell(x) -> str:  # None: the readings cannot place it (fewer than three landmarks)
        return "-" if x is None else f"{x:g}"

    rows = [
        [name, v["markers"], v["landmarks"], f'{v["within_placement_error"]} ({v["nearest_within_placement_error"]})', v["set_off_one"],
         f'{cell(v["median_stated_mm"])} ({cell(v["median_nearest_stated_mm"])})',
         f'{cell(v["median_solved_p95_mm"])} ({cell(v["median_nearest_solved_p95_mm"])})', cell(v["min_within_stated"])]
        for name, v in out["props"].items()
    ]  # fmt: skip
    body = (
        "How tightly the rigging guide's three landmark readings locate each marker, for the built-in hammer and "
        "the eight props above (default spec, seed 0).  The guide names, per marker, the three landmarks whose "
        "readings locate it best under its tape model (each distance read to 0.5 mm + 0.5 %) and states the "
        "error 95 % of marks stay within; in brackets, the nearest three landmarks (what the guide named before).  "
        f"Solved: {out['trials']} sets of noisy readings per marker, each solved by brute force over a dense sample "
        "of the surface round the mark (`benchmarks/_locate.py`), the median over markers of the 95th percentile "
        "of how far the solutions land; within stated: the least share, over the markers, of solutions within "
        "the stated error (0.95 if the statement is right).  Within the placement error: the markers the "
        "readings alone place within the seat's placement error (2 mm); the guide sends the others to its "
        "drawings.  Landmarks: the prop's ends and corners a person finds by hand.  Set off one: markers the "
        "guide sets off a landmark on their own face in a named direction instead (judged by eye to 15 degrees: "
        "a model the brute force cannot check, so they are not solved).  A dash: no figure (the median marker's "
        "readings cannot place it at all, or no marker is measured from three landmarks).  "
        f"In all, the readings place {out['within_placement_error']} of the {out['markers']} markers within "
        f"it ({out['nearest_within_placement_error']} from the nearest three): on round and large props a tape cannot "
        "keep to the margin the seats leave, and the template (at 1:1 where the prop fits the sheet) or a jig must.\n\n"
        + table(["prop", "markers", "landmarks", "within placement error", "set off one", "median stated (mm)", "median solved p95 (mm)",
                 "least within stated"], rows)
    )  # fmt: skip
    write_section("guide-locate", "The rigging guide's landmark readings", body)


if __name__ == "__main__":
    raise SystemExit(main())
