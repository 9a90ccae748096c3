"""Families designed for the tracker: identification targets and the price of safety, as JSON.

    python benchmarks/bench_tracker.py [--frames 2000] [--seed 0] [--ghosts 0,1,2,3]
        [--part all|targets|presets|price] [--png docs/img/tracker-price.png] [--write-docs]

The finger box (the default ``starforge stars`` template), 0.2 mm noise per axis, the open
world, ``check``'s default tracker (the tolerances written into vendor files, its ambiguity
ratio) and its two headline rules (fit, sides), one seed:

* ``targets``: the default family and ``--count 25``: identified and wrong body + wrong pose
  under every headline rule with up to one marker hidden and no ghosts; all four markers seen
  with 2 ghosts; one hidden (exactly) with 0..3 ghosts (the curve of wrong poses and bodies
  against the ghost count), and at 2 ghosts without withholding ambiguous matches
  (``ambiguity`` 1: the best match is always reported); ``met``: each target with its flag.
* ``presets``: for each preset whose rules the finger box admits, the family made with
  ``--preset X`` and checked with ``--preset X``, the same cases and targets, and the window the
  vendor's files carry against its bounds (>= 3 sigma of a distance, <= half the key margin).
* ``price``: family size against the tracker's window and the noise (``design_margin_mm``), the
  pool step half the tolerance (at least 1.5 mm), as a table and a picture (``--png``).

``--write-docs`` also writes each part run into its own section of the docs' results page
(``docs/results.md``: ``tracker-targets``, ``tracker-presets``, ``tracker-price``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path


def _family(**over):
    from starforge.catalog import load_template
    from starforge.stars.family import make_family
    from starforge.stars.spec import spec_from_mapping

    _, data = load_template("stars", "finger")
    data.update(over)
    return make_family(spec_from_mapping(data, name="bench"))


def _bodyset(fam):
    from starforge.geometry.rigid import default_tip_mm
    from starforge.tracking.bodies import Body, BodySet

    tip = tuple(float(x) for x in default_tip_mm(fam.spec.box_mm))
    bodies = tuple(Body(f"s{s.id:03d}", s.id, s.vertices, tip) for s in fam.stars)
    return BodySet("family", ("bench",), bodies, float(fam.spec.tol_mm), float(fam.spec.marker_mm), tip)


def _rates(bodyset, frames, seed, **kw) -> dict:
    from starforge.tracking.check import CheckSettings, run_check

    doc = run_check(bodyset, CheckSettings(frames=frames, seed=seed, curve_points=0, noise_mm=0.2, **kw))
    out = {
        "match_mm": doc["settings"]["match_mm"],
        "residual_mm": doc["settings"]["residual_mm"],
        "ambiguity": doc["settings"]["ambiguity_likelihood_ratio"],
        "headline_rule": doc["headline_rule"],
        "safe_under": doc["safe_under"],
        "key_margin_mm": doc["settings"]["key_margin_mm"],
    }
    for r in doc["headline_rules"]:
        v = doc["by_rule"][r]
        out[r] = {
            "identified_percent": round(100 * v["identification_rate"], 4),
            "wrong_body_percent": round(100 * v["wrong_body_rate"], 4),
            "wrong_pose_percent": round(100 * v["flip_rate"], 4),
            "missed_percent": round(100 * v["missed_rate"], 4),
        }
    return out


#: wrong body + wrong pose, %, with one marker hidden and 2 ghosts, that the issue measured on the tour's
#: family (a best-fit and a sorted-sides tracker); the target is a 4-fold cut
GHOST_BEFORE = {"fit": 3.0, "sides": 4.6}


def _wrong(rates: dict, rule: str) -> float:
    return rates[rule]["wrong_body_percent"] + rates[rule]["wrong_pose_percent"]


def _met(row: dict) -> dict:
    """The identification targets, each with its flag: >= 99.9 % identified and <= 0.01 % wrong
    with up to one hidden and no ghosts; <= 0.1 % wrong with all seen and 2 ghosts; the wrong
    rate with one hidden and 2 ghosts cut 4-fold from :data:`GHOST_BEFORE`."""
    rules = ("fit", "sides")
    d, a, g = row["drop1_ghosts0"], row["all_seen_ghosts2"], row["one_hidden_2_ghosts"]
    return {
        "drop1_identified_999": all(d[r]["identified_percent"] >= 99.9 for r in rules),
        "drop1_wrong_001": all(_wrong(d, r) <= 0.01 for r in rules),
        "all_seen_ghosts2_wrong_01": all(_wrong(a, r) <= 0.1 for r in rules),
        "one_hidden_ghosts2_cut_4fold": all(_wrong(g, r) <= GHOST_BEFORE[r] / 4 for r in rules),
    }


def targets(frames: int, seed: int, ghost_counts) -> dict:
    rows = {}
    for name, over in (("default", {}), ("count25", {"count": 25})):
        t0 = time.perf_counter()
        fam = _family(**over)
        bs = _bodyset(fam)
        row = {
            "stars": len(fam.stars),
            "tolerance_mm": fam.spec.tol_mm,
            "make_s": round(time.perf_counter() - t0, 2),
        }
        row["drop1_ghosts0"] = _rates(bs, frames, seed, drop=1)
        row["all_seen_ghosts2"] = _rates(bs, frames, seed, drop=0, ghosts=2)
        row["one_hidden_by_ghosts"] = {
            str(g): _rates(bs, frames, seed, drop=1, drop_exact=True, ghosts=g) for g in ghost_counts
        }
        row["one_hidden_2_ghosts"] = row["one_hidden_by_ghosts"].get("2") or _rates(
            bs, frames, seed, drop=1, drop_exact=True, ghosts=2
        )
        # the best match always reported (nothing withheld), at 2 ghosts
        row["one_hidden_2_ghosts_best_match"] = _rates(
            bs, frames, seed, drop=1, drop_exact=True, ghosts=2, ambiguity=1.0
        )
        row["met"] = _met(row)
        rows[name] = row
    return rows


#: a box for a preset whose rules the finger box cannot hold (ART's distances over 30 mm), mm
LARGE_BOX_MM = [60.0, 40.0, 80.0]


def presets(frames: int, seed: int) -> dict:
    from starforge.errors import StarforgeError
    from starforge.tracking.presets import design_tolerance_mm, load_preset, preset_names, star_spec_overrides

    rows = {}
    for name in preset_names():
        over = star_spec_overrides(name)
        over["tolerance_mm"] = design_tolerance_mm(name, 0.2, over.get("tolerance_mm"))
        note = None
        try:
            fam = _family(**over)
        except StarforgeError as e:  # e.g. ART's 30 mm distances in a finger box
            note = f"the finger box cannot hold it ({e}); made in {LARGE_BOX_MM} mm"
            fam = _family(**over, box_mm=LARGE_BOX_MM)
        bs = _bodyset(fam)
        # a tracker that identifies from all 4 markers has no hidden-marker case: nothing hidden
        hide = 1 if load_preset(name).tracker.identify_markers <= 3 else 0
        row = {
            "stars": len(fam.stars),
            "box_mm": list(fam.spec.box_mm),
            "tolerance_mm": round(fam.spec.tol_mm, 6),
            "markers_hidden": hide,
            "drop1_ghosts0": _rates(bs, frames, seed, drop=hide, preset=name),
            "all_seen_ghosts2": _rates(bs, frames, seed, drop=0, ghosts=2, preset=name),
            "one_hidden_2_ghosts": _rates(
                bs, frames, seed, drop=hide, drop_exact=hide > 0, ghosts=2, preset=name
            ),
        }
        if note:
            row["note"] = note
        row["met"] = _met(row)
        # the window the vendor's files carry: >= 3 sigma of a distance (two points' noise), <= half
        # the family's smallest key margin
        window = row["drop1_ghosts0"]["match_mm"]
        row["window_mm"] = window
        row["met"]["window_ge_3_sigma"] = window >= 3 * 0.2 * math.sqrt(2) - 1e-9
        row["met"]["window_le_half_margin"] = window <= row["drop1_ghosts0"]["key_margin_mm"] / 2 + 1e-9
        rows[name] = row
    return rows


def price(noises=(0.1, 0.2, 0.3, 0.5), windows=(None, 2.0)) -> list[dict]:
    from starforge.tracking.tolerances import design_margin_mm

    rows = []
    for w in windows:
        for nz in noises:
            tol = design_margin_mm(nz, w)
            delta = max(1.5, tol / 2)
            t0 = time.perf_counter()
            fam = _family(tolerance_mm=tol, delta_mm=delta, noise_mm=nz)
            rows.append(
                {
                    "window_mm": "noise (written)" if w is None else w,
                    "noise_mm": nz,
                    "key_margin_mm": round(tol, 4),
                    "pool_step_mm": round(delta, 4),
                    "stars": len(fam.stars),
                    "upper_bound": fam.summary["upper_bound"],
                    "seconds": round(time.perf_counter() - t0, 2),
                }
            )
    return rows


def price_png(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for w in dict.fromkeys(r["window_mm"] for r in rows):
        rr = [r for r in rows if r["window_mm"] == w]
        label = "window from the noise" if not isinstance(w, float) else f"fixed {w:g} mm window"
        ax.plot([r["noise_mm"] for r in rr], [r["stars"] for r in rr], "o-", label=label)
        for r in rr:
            ax.annotate(
                f"{r['key_margin_mm']:.1f}",
                (r["noise_mm"], r["stars"]),
                fontsize=7,
                xytext=(3, 3),
                textcoords="offset points",
            )
    ax.set_xlabel("marker noise sigma per axis [mm]")
    ax.set_ylabel("stars in the finger box")
    ax.set_yscale("log")
    ax.set_title("Tracker-safe finger families (labels: key margin, mm)", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _cell(rates: dict) -> str:
    """identified / wrong body + wrong pose, %, the worse of the headline rules (fit, sides)."""
    rules = ("fit", "sides")
    ident = min(rates[r]["identified_percent"] for r in rules)
    wrong = max(_wrong(rates, r) for r in rules)
    return f"{ident:.2f} / {wrong:.2f}"


def _flags(met: dict) -> str:
    return f"{sum(met.values())} of {len(met)}" + ("" if all(met.values()) else ": not " + ", ".join(k for k, v in met.items() if not v))


def write_targets(rows: dict, frames: int, seed: int) -> None:
    from _results import table, write_section

    ghosts = next(iter(rows.values()))["one_hidden_by_ghosts"]
    header = ["family", "stars", "key margin (mm)", "up to 1 hidden, no ghosts", "all 4 seen, 2 ghosts",
              *(f"1 hidden, {g} ghost{'s' if g != '1' else ''}" for g in ghosts),
              "1 hidden, 2 ghosts, best match always reported", "targets met"]  # fmt: skip
    body = []
    for name, row in rows.items():
        body.append([
            {"default": "default", "count25": "`--count 25`"}[name], row["stars"], row["drop1_ghosts0"]["key_margin_mm"],
            _cell(row["drop1_ghosts0"]), _cell(row["all_seen_ghosts2"]),
            *(_cell(v) for v in row["one_hidden_by_ghosts"].values()),
            _cell(row["one_hidden_2_ghosts_best_match"]), _flags(row["met"]),
        ])  # fmt: skip
    text = (
        f"The finger box (the default `starforge stars` template), 0.2 mm noise per axis, the open world, "
        f"{frames:,} frames, seed {seed}, `check`'s default tracker (the window written into vendor files, its "
        "ambiguity ratio).  Each cell: identified / wrong body + wrong pose, %, the worse of the two headline "
        "rules (best fit and sorted sides).  Targets: >= 99.9 % identified and <= 0.01 % wrong with up to one "
        "marker hidden; <= 0.1 % wrong with all four seen and 2 ghosts; with one hidden and 2 ghosts, the wrong "
        f"rate cut 4-fold from {GHOST_BEFORE['fit']} % (fit) and {GHOST_BEFORE['sides']} % (sides), the rates of a "
        "25-star family not designed for the tracker.  The last column but one reports the best "
        "match always, as a tracker without an ambiguity test does: the ghosts' wrong poses that withholding "
        "near-ties turns into missed frames.\n\n" + table(header, body)
    )
    write_section("tracker-targets", "Families designed for the tracker", text)


def write_presets(rows: dict, frames: int) -> None:
    from _results import table, write_section

    header = ["preset", "stars", "box (mm)", "window (mm)", "markers hidden", "no ghosts", "all 4 seen, 2 ghosts",
              "same markers hidden, 2 ghosts", "targets met"]  # fmt: skip
    body = [
        [f"`{name}`", row["stars"], " x ".join(f"{x:g}" for x in row["box_mm"]), row["window_mm"], row["markers_hidden"],
         _cell(row["drop1_ghosts0"]), _cell(row["all_seen_ghosts2"]), _cell(row["one_hidden_2_ghosts"]), _flags(row["met"])]
        for name, row in rows.items()
    ]  # fmt: skip
    text = (
        f"Each preset's family made with `starforge stars --preset NAME --noise 0.2` and checked with `check "
        f"--preset NAME` ({frames:,} frames): identified / wrong body + wrong pose, %, the worse of the headline "
        "rules.  The window is the one the vendor's files carry; its targets: at least 3 sigma of a distance "
        "(0.85 mm) and at most half the family's smallest key margin.  A tracker that identifies from all four "
        "markers (ART's DTrack) is checked with none hidden; a preset whose distances the finger box cannot hold "
        f"is made in {' x '.join(f'{x:g}' for x in LARGE_BOX_MM)} mm.\n\n" + table(header, body)
    )
    write_section("tracker-presets", "Families designed for each vendor's tracker", text)


def write_price(rows: list[dict], png: Path) -> None:
    from _results import table, write_section

    body = [
        ["from the noise (written)" if isinstance(r["window_mm"], str) else f"fixed {r['window_mm']:g} mm", r["noise_mm"],
         r["key_margin_mm"], r["pool_step_mm"], f"{r['stars']} ({r['upper_bound']})", r["seconds"]]
        for r in rows
    ]  # fmt: skip
    rel = os.path.relpath(png.resolve(), (Path(__file__).resolve().parents[1] / "docs"))
    text = (
        "The price of safety: family size in the finger box against the tracker's window and the noise.  The "
        "key margin is twice the window (`design_margin_mm`), the pool step half the margin (at least 1.5 mm); "
        "stars: the family made, and in brackets the selection's upper bound.\n\n"
        + table(["tracker window", "noise (mm)", "key margin (mm)", "pool step (mm)", "stars (bound)", "seconds"], body)
        + f"\n\n![Stars in the finger box against the noise, for a window from the noise and a fixed 2 mm window]({rel})"
    )
    write_section("tracker-price", "Families designed for the tracker: the price", text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ghosts", default="0,1,2,3")
    ap.add_argument("--part", choices=("all", "targets", "presets", "price"), default="all")
    ap.add_argument("--png", type=Path, default=Path("docs/img/tracker-price.png"))
    ap.add_argument("--write-docs", action="store_true", help="also write the tables into docs/results.md")
    a = ap.parse_args()
    out = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load": os.getloadavg()[0]},
        "frames": a.frames,
        "seed": a.seed,
        "noise_mm": 0.2,
    }
    if a.part in ("all", "targets"):
        out["targets"] = targets(a.frames, a.seed, [int(x) for x in a.ghosts.split(",")])
    if a.part in ("all", "presets"):
        out["presets"] = presets(a.frames, a.seed)
    if a.part in ("all", "price"):
        out["price"] = price()
        price_png(out["price"], a.png)
        out["price_png"] = str(a.png)
    print(json.dumps(out, indent=2))
    if a.write_docs:
        if "targets" in out:
            write_targets(out["targets"], a.frames, a.seed)
        if "presets" in out:
            write_presets(out["presets"], a.frames)
        if "price" in out:
            write_price(out["price"], a.png)


if __name__ == "__main__":
    main()
