"""Props as a 3D scanner delivers them: their noise measured and smoothed, their markers placed; JSON on stdout.

For the scanned bottle and carton of ``_scans.py`` (triangles about 1 mm across) at each noise
level (``--noise``, mm, Gaussian along each vertex's normal), written to an STL and placed at the default
spec, seed 0:

* ``noise_measured_mm``: :func:`starforge.props.scan.surface_noise` of the file's mesh, and
  the repair's note when it smoothed it;
* with the smoothing (as ``starforge place`` runs) and without it (the same file repaired with
  ``smooth=False``): ``usable_sites`` (candidate sites where a marker seats, not under the
  hand), the layout's markers and its own tracked fraction, or the refusal when no layout is
  possible;
* checked on the shape itself (the same generator without noise, repaired): each marker's base centre
  moved to the nearest point of the noise-free surface, ``markers_below_margin`` (less than
  the placement error of room beyond the base to a sharp edge or a surface tilted more than
  30 degrees there, brute force over every face and edge, ``bench_props_real.margin_shortfall``)
  and ``min_margin_mm``.

``--big``: the bottle at a 0.5 mm step (437k faces) and 0.1 mm noise, placed by a fresh
``python -m starforge place run`` process: wall seconds and peak memory against the 500k-face
targets (10 s, 1 GB), its smoothing included.

Run: ``python benchmarks/bench_scans.py [--noise 0,0.05,0.1,0.2] [--big] [--write-docs]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHAPES = ("bottle", "carton")


def _shape(name: str, noise_m: float, step: float = 0.001):
    from _scans import scanned_bottle, scanned_carton

    return (scanned_bottle if name == "bottle" else scanned_carton)(noise_m, step=step)


def _on_shape(clean, res) -> dict:
    """The layout's markers checked on the noise-free shape ``clean``."""
    from bench_props_real import margin_shortfall

    points, _, face = clean.nearest.on_surface(res.marker_points)
    normals = clean.face_normals[face]
    below, rooms = margin_shortfall(clean, points, normals, res.seat.base_radius_m, res.spec.seat.placement_error_mm / 1000.0)
    return {"markers_below_margin": int(below), "min_margin_mm": round(1000.0 * float(min(rooms)), 2)}


def _placed(prop, spec, clean) -> dict:
    from starforge.errors import StarforgeError
    from starforge.props.placement import place

    t0 = time.perf_counter()
    try:
        res = place(prop, spec, seed=0)
    except StarforgeError as exc:
        return {"refused": str(exc), "seconds": round(time.perf_counter() - t0, 1)}
    out = {
        "usable_sites": len(res.sites),
        "markers": len(res.marker_sites),
        "own_tracked": round(res.evaluation.get("default", {}).get("tracked", float("nan")), 4),
        **_on_shape(clean, res),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    return out


def case(name: str, noise_mm: float, tmp: Path) -> dict:
    """One shape at one noise level, with and without the smoothing."""
    from starforge.props.mesh import PropMesh, load_mesh_file, load_prop, merge_vertices, repair_mesh
    from starforge.props.scan import surface_noise
    from starforge.props.spec import load_spec

    path = tmp / f"{name}_{noise_mm:g}.stl"
    scan = _shape(name, noise_mm / 1000.0)
    scan.export(path)
    clean = repair_mesh(_shape(name, 0.0), smooth=False)[0]  # the shape: its poles' slivers merged
    spec = load_spec("default")
    raw = load_mesh_file(path)
    merged = merge_vertices(raw.vertices, raw.faces)  # an STL stores every face's own corners
    row = {"faces": len(raw.faces), "noise_measured_mm": round(1000.0 * surface_noise(*merged), 4)}
    smoothed = load_prop(str(path))
    row["note"] = next((n for n in smoothed.notes if "smoothed" in n), None)
    row["smoothed"] = _placed(smoothed, spec, clean)
    mesh, origin, notes = repair_mesh(raw, smooth=False)
    kept = PropMesh.of(mesh, path.stem, str(path), "m", origin, tuple(notes), len(raw.faces), {})
    row["not_smoothed"] = _placed(kept, spec, clean)
    print(f"{name} {noise_mm:g} mm: {json.dumps(row)}", file=sys.stderr)
    return row


def big(tmp: Path) -> dict:
    """The 437k-face scanned bottle placed by a fresh process: seconds and peak memory."""
    path = tmp / "bottle_big.stl"
    mesh = _shape("bottle", 1e-4, step=0.0005)
    mesh.export(path)
    faces = len(mesh.faces)
    del mesh
    out = tmp / "big"
    from bench_place_fine import run_once

    from starforge.runtime.cache import cache_dir

    # a first run on the file: an empty cache folder, the compiled kernels where they are
    run = run_once(path, out, {"STARFORGE_CACHE_DIR": str(tmp / "cache"),
                               "NUMBA_CACHE_DIR": os.environ.get("NUMBA_CACHE_DIR") or os.path.join(cache_dir(), "numba")})  # fmt: skip
    doc = json.loads((out / "placement.json").read_text())
    return {
        "faces": faces,
        "seconds": run["seconds"],
        "peak_rss_mb": run["peak_rss_mb"],
        "load_1min_before": run["load_1min_before"],
        "repair_s": run["timings"].get("repair_s"),
        "notes": [n for n in doc["prop"].get("repairs", []) if "smoothed" in n],
        "targets": {"seconds <= 10": run["seconds"] <= 10.0, "memory <= 1024 MB": run["peak_rss_mb"] <= 1024.0},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise", default="0,0.05,0.1,0.2", help="noise levels, mm")
    ap.add_argument("--shapes", default=",".join(SHAPES))
    ap.add_argument("--big", action="store_true", help="also time a 437k-face scan in a fresh process")
    ap.add_argument("--write-docs", action="store_true", help="also write the table into docs/results.md")
    args = ap.parse_args(argv)
    levels = [float(x) for x in args.noise.split(",") if x]
    out: dict = {"cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        if args.big:  # first: a child's peak memory counts its parent's at the fork, small yet
            out["big"] = big(Path(tmp))
        for name in [s for s in args.shapes.split(",") if s]:
            out["cases"][name] = {f"{x:g}": case(name, x, Path(tmp)) for x in levels}
    print(json.dumps(out, indent=1))
    if args.write_docs:
        write_docs(out)
    return 0


def write_docs(out: dict) -> None:
    """The figures of ``out`` as the results page's section on scanned props."""
    from _results import table, write_section

    def cell(r: dict) -> str:
        if "refused" in r:
            return "refused: no site seats a marker" if "candidate sites seat" in r["refused"] else "refused"
        return f"{r['usable_sites']} sites, {r['markers']} markers, own {r['own_tracked']:g}, {r['markers_below_margin']} below margin ({r['min_margin_mm']:g} mm)"

    rows = [
        [name, level, r["faces"], r["noise_measured_mm"], cell(r["smoothed"]), cell(r["not_smoothed"])]
        for name, levels in out["cases"].items()
        for level, r in levels.items()
    ]
    body = (
        "Props as a 3D scanner delivers them (`benchmarks/_scans.py`: a 70 mm bottle meshed ring by ring and a "
        "70 x 70 x 200 mm carton, triangles about 1 mm across, every vertex moved along its normal by Gaussian "
        "noise of the given size: a scanner's depth noise), placed at the default spec, seed 0, as `starforge place` runs (the repair "
        "smooths a mesh whose noise tilts its faces, `starforge.props.scan`) and with the smoothing off.  Measured: "
        "the noise the repair reads off the file.  Each cell: the candidate sites where a marker seats, the "
        "markers placed, the layout's own tracked fraction, and, checked on the noise-free shape (each base "
        "centre moved to the nearest point of it; brute force over every face and edge), the markers with less "
        "than the 2 mm placement error of room to a sharp edge or a surface tilted more than 30 degrees, and the "
        "least room.\n\n"
        + table(["shape", "noise (mm)", "faces", "measured (mm)", "smoothed (as `place` runs)", "not smoothed"], rows)
    )
    if "big" in out:
        b = out["big"]
        body += (
            f"\n\nA {b['faces']:,}-face scan of the bottle (0.5 mm triangles, 0.1 mm noise), placed by a fresh "
            f"`starforge place run` process: {b['seconds']} s, {b['peak_rss_mb']:.0f} MB peak (load {b['load_1min_before']} before; "
            f"the repair, its smoothing included, {b['repair_s']:.2f} s)."
        )
    write_section("scans", "Scanned props", body)


if __name__ == "__main__":
    raise SystemExit(main())
