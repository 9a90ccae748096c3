"""Speed of the printable-body export; prints one JSON object.

Figures (seconds, wall clock, this machine):
- one_star_step_stl_3mf_s: one finger star with the flat mount: body description, STEP
  (build123d solid + file), STL and 3MF (manifold3d mesh + files); median of repeats after one
  warm-up, build123d already imported (first_star_s: the warm-up itself);
- family25_with_plate_s: the paper's 25-star finger set (StarSpec finger box, count=25),
  every star as STEP + STL + 3MF plus plate.stl / plate.3mf and bodies.json, in-process
  (family25_cli_s adds interpreter start-up and the build123d import: `starforge export`);
- preview25_s: the 25 PNGs and the sheet;
- import_build123d_s: the one-off import cost;
- per-mount one-star times.

Usage: python benchmarks/bench_cad.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    from starforge.stars.family import make_family
    from starforge.stars.spec import StarSpec

    t = time.perf_counter()
    fam = make_family(StarSpec(box_mm=(20.8, 12.6, 48.3), count=25, name="finger25"))
    family_s = time.perf_counter() - t

    t = time.perf_counter()
    import build123d  # noqa: F401

    import_s = time.perf_counter() - t

    from starforge.cad.body import BodySpec, build_body
    from starforge.cad.export import export_family
    from starforge.cad.mesh import body_mesh
    from starforge.cad.mounts import load_mount
    from starforge.cad.occ import body_solid, write_step
    from starforge.cad.threemf import threemf_bytes

    spec = BodySpec()

    def one(star, mount, folder: Path) -> float:
        t0 = time.perf_counter()
        b = build_body(star.id, star.vertices, fam.spec.marker_mm, mount, spec)
        mesh = body_mesh(b, spec.sphere_segments, spec.cylinder_segments)
        (folder / f"{b.name}.stl").write_bytes(mesh.export(file_type="stl"))
        (folder / f"{b.name}.3mf").write_bytes(threemf_bytes([mesh], [b.name]))
        write_step(body_solid(b), folder / f"{b.name}.step")
        return time.perf_counter() - t0

    res: dict = {
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "family": {"box_mm": list(fam.spec.box_mm), "stars": len(fam), "make_family_s": round(family_s, 3)},
        "import_build123d_s": round(import_s, 3),
    }
    star = fam.stars[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        flat = load_mount("flat")
        res["first_star_s"] = round(one(star, flat, tmp), 4)
        times = [one(star, flat, tmp) for _ in range(args.repeats)]
        res["one_star_step_stl_3mf_s"] = round(statistics.median(times), 4)
        res["one_star_by_mount_s"] = {}
        for name in ("flat", "strap", "saddle", "adhesive", "magnet"):
            m = load_mount(name)
            res["one_star_by_mount_s"][name] = round(
                statistics.median(one(star, m, tmp) for _ in range(3)), 4
            )

        out = tmp / "fam"
        out.mkdir()
        t0 = time.perf_counter()
        rep = export_family(fam, out, flat, spec, allow_oversize=True)
        res["family25_with_plate_s"] = round(time.perf_counter() - t0, 3)
        res["family25_breakdown_s"] = {k: round(v, 3) for k, v in rep.timings.items()}
        res["family25_fit"] = sum(b["fits"] for b in rep.bodies)
        res["family25_min_visibility"] = min(min(b["visibility"]) for b in rep.bodies)
        res["files"] = len(rep.files)

        pv = tmp / "pv"
        pv.mkdir()
        from starforge.cad.export import family_bodies
        from starforge.render.bodies import render_body_png, render_sheet_png

        bodies = family_bodies(fam, None, flat, spec)
        t0 = time.perf_counter()
        for b in bodies:
            render_body_png(b, pv / f"{b.name}.png")
        render_sheet_png(bodies, pv / "sheet.png")
        res["preview25_s"] = round(time.perf_counter() - t0, 3)

        (tmp / "cli").mkdir()
        fj = tmp / "cli" / "family.json"
        fj.write_text(json.dumps(fam.to_json()))
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "starforge", "export", str(fj), "--allow-oversize", "-q"],
            check=True,
            capture_output=True,
        )
        res["family25_cli_s"] = round(time.perf_counter() - t0, 3)
    res["targets"] = {"one_star_s": 0.5, "family25_with_plate_s": 20.0}
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
