"""Family -> printable files: one STEP / STL / 3MF per star, a print plate, a manifest.

Writes into a folder the caller stages (:func:`starforge.io.staged_output`), so a failure
leaves nothing half-written.  Files (``<name>`` = ``star_<id>``, id zero-padded to 3)::

    <name>.step   one solid named <name> (build123d / OpenCascade)
    <name>.stl    one watertight shell (manifold3d), binary STL, mm
    <name>.3mf    the same mesh, one named object, mm
    plate.stl, plate.3mf   every selected body on one bed (bodies standing on their mounts)
    bodies.json   per star: size, fit against the family limit, visibility, volumes, files
    preview/<name>.png, preview/sheet.png   with ``preview=True``

Fit policy: every body (finished spheres included) is compared with the family's size limit
before any CAD work; one that does not fit stops the export (StarforgeError naming the worst
body and by how much) unless ``allow_oversize``, which exports anyway and records the excess
in bodies.json: a lab can then decide to print a star that sticks out a millimetre.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.cad.body import Body, BodySpec, body_bounds, build_body, fit_report
from starforge.cad.mounts import Mount
from starforge.errors import StarforgeError
from starforge.io import atomic_write_json
from starforge.spec import to_mapping

CAD_FORMATS = ("step", "stl", "3mf")


@dataclass
class ExportReport:
    """What an export wrote and found (for the CLI to print)."""

    files: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    bodies: list[dict] = field(default_factory=list)
    timings: dict = field(default_factory=dict)


def parse_ids(text: str | None) -> list[int] | None:
    """``"1,2,5"`` or ``"1-4,9"`` -> [1, 2, 5] / [1, 2, 3, 4, 9]; None or "" -> None (all)."""
    if text is None or not str(text).strip():
        return None
    out: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part[1:]:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise StarforgeError(
                f"ids must be a comma list of star ids or ranges like 1,2,5-7; got {text!r}"
            ) from None
    return list(dict.fromkeys(out))


def family_bodies(family, ids, mount: Mount, spec: BodySpec) -> list[Body]:
    """Body descriptions for the selected stars (all when ``ids`` is None)."""
    stars = family.stars if ids is None else family.by_id(ids)
    bodies = []
    for s in stars:
        try:
            bodies.append(build_body(s.id, s.vertices, family.spec.marker_mm, mount, spec))
        except StarforgeError as exc:
            raise StarforgeError(f"star {s.id}: {exc}") from None
    return bodies


def check_fit(bodies, limit_mm, mount_name: str, allow_oversize: bool) -> list:
    """Fit reports of every body; raises StarforgeError for the worst misfit unless allowed."""
    reports = [fit_report(b, limit_mm) for b in bodies]
    bad = [(r.worst_mm, b.name, r) for b, r in zip(bodies, reports, strict=True) if not r.fits]
    if bad and not allow_oversize:
        worst, name, r = max(bad, key=lambda t: t[0])
        raise StarforgeError(
            f"mount {mount_name} does not fit: {len(bad)} of {len(bodies)} bodies exceed the family's size limit; "
            f"worst {r.message(name)}; pass --allow-oversize to export anyway"
        )
    return reports


def expected_files(bodies, formats, plate: bool = True, preview: bool = False) -> list[str]:
    """The file names :func:`export_family` writes (to refuse overwrites before the work)."""
    names = [f"{b.name}.{f}" for b in bodies for f in formats]
    if plate:
        names += [f"plate.{f}" for f in ("stl", "3mf") if f in formats]
    if preview:
        names += [f"preview/{b.name}.png" for b in bodies] + ["preview/sheet.png"]
    return names + ["bodies.json"]


def export_family(
    family,
    stage: Path,
    mount: Mount,
    spec: BodySpec,
    formats=CAD_FORMATS,
    ids=None,
    bed_mm=(200.0, 200.0),
    gap_mm: float = 5.0,
    plate: bool = True,
    preview: bool = False,
    allow_oversize: bool = False,
    progress=None,
    bodies=None,
) -> ExportReport:
    """Write the bodies of a family into ``stage`` (see the module docstring for the files).

    ``progress(done, total)`` is called after each star.  ``bodies``: the descriptions from
    :func:`family_bodies` for the same family, ids, mount and spec, when the caller already has
    them (they are described here otherwise).
    """
    from starforge.cad.mesh import body_mesh
    from starforge.cad.plate import layout_plate, plate_mesh
    from starforge.cad.threemf import threemf_bytes
    from starforge.cad.visibility import sphere_visibility

    formats = tuple(formats)
    bad = [f for f in formats if f not in CAD_FORMATS]
    if bad:
        raise StarforgeError(f"unknown CAD format {', '.join(bad)}; known: {', '.join(CAD_FORMATS)}")
    stage = Path(stage)
    rep = ExportReport()
    t0 = time.perf_counter()
    if bodies is None:
        bodies = family_bodies(family, ids, mount, spec)
    fits = check_fit(bodies, family.spec.box_mm, mount.name, allow_oversize)
    layout = layout_plate([body_bounds(b, finished=True) for b in bodies], bed_mm, gap_mm) if plate else None
    rep.timings["describe_s"] = time.perf_counter() - t0
    meshes = []
    t_mesh = t_step = 0.0
    for k, (b, fit) in enumerate(zip(bodies, fits, strict=True)):
        t1 = time.perf_counter()
        mesh = body_mesh(b, spec.sphere_segments, spec.cylinder_segments)
        meshes.append(mesh)
        entry = {
            "id": b.star_id,
            "name": b.name,
            "size_mm": [round(v, 6) for v in fit.size_mm],
            "fits": fit.fits,
            "excess_mm": [round(v, 6) for v in fit.excess_mm],
            "printed_sphere_mm": b.printed_mm,
            "centres_mm": [list(c) for c in b.centres],
            "stem_roots_mm": [list(s.p0) for s in b.stems],
            "label": b.label,
            "mesh_volume_mm3": round(float(mesh.volume), 6),
            "files": [],
        }
        vis = sphere_visibility(b)
        entry["visibility"] = [round(float(v), 4) for v in vis]
        low = [f"{'ABCD'[i]} {v:.2f}" for i, v in enumerate(vis) if v < spec.min_visibility]
        if low:
            rep.warnings.append(
                f"{b.name}: sphere(s) {', '.join(low)} see less than {spec.min_visibility:.2f} of their upper hemisphere"
            )
        if not fit.fits:
            rep.warnings.append(fit.message(b.name) + " (exported with --allow-oversize)")
        if "stl" in formats:
            (stage / f"{b.name}.stl").write_bytes(mesh.export(file_type="stl"))
            entry["files"].append(f"{b.name}.stl")
        if "3mf" in formats:
            (stage / f"{b.name}.3mf").write_bytes(threemf_bytes([mesh], [b.name]))
            entry["files"].append(f"{b.name}.3mf")
        t_mesh += time.perf_counter() - t1
        if "step" in formats:
            from starforge.cad.occ import body_solid, write_step

            t2 = time.perf_counter()
            solid = body_solid(b)
            write_step(solid, stage / f"{b.name}.step")
            entry["step_volume_mm3"] = round(float(solid.volume), 6)
            entry["files"].append(f"{b.name}.step")
            t_step += time.perf_counter() - t2
        rep.bodies.append(entry)
        if progress is not None:
            progress(k + 1, len(bodies))
    rep.timings["mesh_s"] = t_mesh
    rep.timings["step_s"] = t_step
    plate_doc = None
    plate_formats = [f for f in ("stl", "3mf") if f in formats]
    if layout is not None and plate_formats:
        t3 = time.perf_counter()
        if "stl" in plate_formats:
            (stage / "plate.stl").write_bytes(plate_mesh(meshes, layout).export(file_type="stl"))
        if "3mf" in plate_formats:
            moved = []
            for m, T in zip(meshes, layout.transforms, strict=True):
                c = m.copy()
                c.apply_transform(T)
                moved.append(c)
            (stage / "plate.3mf").write_bytes(threemf_bytes(moved, [b.name for b in bodies]))
        plate_doc = {
            "bed_mm": list(layout.bed_mm),
            "gap_mm": layout.gap_mm,
            "footprints_mm": np.round(layout.footprints, 6).tolist(),
            "transforms": [np.round(T, 9).tolist() for T in layout.transforms],
            "files": [f"plate.{f}" for f in plate_formats],
        }
        rep.timings["plate_s"] = time.perf_counter() - t3
    if preview:
        from starforge.render.bodies import render_body_png, render_sheet_png

        t4 = time.perf_counter()
        (stage / "preview").mkdir(exist_ok=True)
        for b in bodies:
            render_body_png(b, stage / "preview" / f"{b.name}.png")
        render_sheet_png(bodies, stage / "preview" / "sheet.png")
        rep.timings["preview_s"] = time.perf_counter() - t4
    doc = {
        "format": "starforge.bodies",
        "version": 1,
        "units": "mm",
        "family": {
            "name": family.spec.name,
            "box_mm": list(family.spec.box_mm),
            "marker_mm": family.spec.marker_mm,
        },
        "mount": {"name": mount.name, "kind": mount.kind, "params": mount.params},
        "body_spec": to_mapping(spec),
        "frame": "placement frame of family.json; +y up (mount below), sphere centres unchanged",
        "bodies": rep.bodies,
        "plate": plate_doc,
        "warnings": rep.warnings,
    }
    atomic_write_json(stage / "bodies.json", doc)
    rep.files = sorted(str(p.relative_to(stage)) for p in stage.rglob("*") if p.is_file())
    rep.timings["total_s"] = time.perf_counter() - t0
    return rep
