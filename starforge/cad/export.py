"""Family -> printable files: one STEP / STL / 3MF per star, print plates, a manifest.

Writes into a folder the caller stages (:func:`starforge.io.staged_output`), so a failure
leaves nothing half-written.  Every file is ready as written: each body lies in its printing
orientation (plate down on Z = 0, the body's up along +Z, centred on the Z axis;
:func:`starforge.cad.plate.print_transform`), and ``bodies.json`` records, per body, the
transform from that orientation back to family.json's placement frame.  Files (``<name>`` =
``star_<id>``, id zero-padded to 3)::

    <name>.step   one solid named <name>, coloured (build123d on OpenCascade)
    <name>.stl    one watertight shell (manifold3d), binary STL, mm
    <name>.3mf    the same mesh, one named, coloured object, with a thumbnail, mm
    plate.step / .stl / .3mf   every selected body on one bed (an assembly of named, coloured
                  solids in the STEP); plate_1, plate_2, ... when one bed cannot hold them
    bodies.json   per star: size, fit against the family limit, visibility, volumes, transforms
    preview/<name>.png, preview/sheet.png   with ``preview`` (one scale throughout)

Fit policy: every body (finished spheres included) is compared with the family's size limit
before any CAD work; one that does not fit stops the export (StarforgeError naming the worst
body and by how much) unless ``allow_oversize``, which exports anyway and records the excess
in bodies.json.  A family made with ``starforge stars --mount NAME`` never needs it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from starforge.cad.body import (
    Body,
    BodySpec,
    body_bounds,
    build_body,
    closest_features_mm,
    fit_report,
)
from starforge.cad.mounts import Mount
from starforge.cad.stems import sphere_letter
from starforge.cad.tools import Tool
from starforge.errors import StarforgeError
from starforge.io import atomic_write_json
from starforge.runtime.progress import stage as progress_stage
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
    from starforge.stars.model import MAX_STARS

    out: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part[1:]:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                if hi - lo + 1 + len(out) > MAX_STARS:  # before the list is built
                    raise StarforgeError(
                        f"ids {text!r} name {hi - lo + 1 + len(out):,} stars; a family holds at most {MAX_STARS:,}"
                    )
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
        except StarforgeError:
            raise
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
            b = build_body(s.id, s.vertices, family.spec.marker_mm, mount, spec)
        except StarforgeError as exc:
            raise StarforgeError(f"{s.name if isinstance(s, Tool) else f'star {s.id}'}: {exc}") from None
        bodies.append(replace(b, name=s.name) if isinstance(s, Tool) else b)  # a tool's files carry its name
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


def plate_names(n_beds: int) -> list[str]:
    """``["plate"]`` for one bed, ``["plate_1", "plate_2", ...]`` for several."""
    return ["plate"] if n_beds == 1 else [f"plate_{k + 1}" for k in range(n_beds)]


def print_layout(bodies, bed_mm, gap_mm, plate: bool = True):
    """(print transforms (one per body), bed layouts) from the bodies' geometry (no CAD kernel);
    no beds without a ``plate`` (a body larger than the bed is then no reason to refuse)."""
    from starforge.cad.plate import layout_plates, print_transform

    transforms = [print_transform(body_bounds(b, finished=True)) for b in bodies]
    bounds = []
    for b, T in zip(bodies, transforms, strict=True):
        bb = body_bounds(b, finished=True)
        corners = np.array([[bb[i, 0], bb[j, 1], bb[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        q = corners @ T[:3, :3].T + T[:3, 3]
        bounds.append([q.min(axis=0), q.max(axis=0)])
    return transforms, layout_plates(bounds, bed_mm, gap_mm) if plate else []


def expected_files(bodies, formats, plate: bool = True, preview: bool = False, n_beds: int = 1) -> list[str]:
    """The file names :func:`export_family` writes (to refuse overwrites before the work)."""
    names = [f"{b.name}.{f}" for b in bodies for f in formats]
    if plate:
        names += [f"{p}.{f}" for p in plate_names(n_beds) for f in formats]
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
    preview=None,
    allow_oversize: bool = False,
    progress=None,
    bodies=None,
    step_worker=None,
) -> ExportReport:
    """Write the bodies of a family into ``stage`` (see the module docstring for the files).

    ``progress(done, total)`` is called after each star's mesh files and after each star's STEP
    file (from the thread reading the STEP worker, :mod:`starforge.cad.step_worker`; total =
    stars x 2 with STEP).  ``bodies``: the descriptions from
    :func:`family_bodies` for the same family, ids, mount and spec, when the caller already has
    them (they are described here otherwise).  ``step_worker``: a
    :class:`~starforge.cad.step_worker.StepProcess` the caller launched earlier (so that its
    kernel loads while the caller reads and checks its inputs); one is launched here otherwise.
    ``preview(bodies, folder)``: draws the pictures into ``stage/preview``
    (:func:`starforge.render.bodies.draw_previews`); None draws none.
    """
    formats = tuple(formats)
    bad = [f for f in formats if f not in CAD_FORMATS]
    if bad:
        raise StarforgeError(f"unknown CAD format {', '.join(bad)}; known: {', '.join(CAD_FORMATS)}")
    stage = Path(stage)
    rep = ExportReport()
    t0 = time.perf_counter()
    step_job = None
    if "step" in formats and step_worker is None:
        # the exact solids (OpenCascade) are built in a second process while this one meshes
        # (OCCT holds the GIL: a thread would stall the meshes); launched first, so that it
        # loads the kernel while the bodies are described here
        from starforge.cad.step_worker import StepProcess

        step_worker = StepProcess()
    done = False
    step_stage = None
    plate_docs: list = []
    rep.timings.update(mesh_s=0.0, plate_s=0.0, step_s=0.0)
    try:
        if bodies is None:
            bodies = family_bodies(family, ids, mount, spec)
        fits = check_fit(bodies, family.spec.box_mm, mount.name, allow_oversize)
        to_print, beds = print_layout(bodies, bed_mm, gap_mm, plate)
        rep.timings["describe_s"] = time.perf_counter() - t0
        meshes: list = []
        tick = _Ticker(progress, len(bodies) * (2 if "step" in formats else 1))
        if "step" in formats:
            # each body's STEP file depends only on that body: the files are the same whichever
            # side finishes first
            from starforge.cad import step_worker as step_worker_mod
            from starforge.colours import body_colour

            plates = [(n, lay.members, lay.transforms) for n, lay in zip(plate_names(len(beds)), beds, strict=True)]
            # the STEP files are made beside the meshes and plates: a stage of their own
            step_stage = progress_stage("STEP", total=len(bodies), unit="bodies", parallel=True)
            step_job = step_worker_mod.start(
                bodies,
                to_print,
                [body_colour(b.star_id - 1) for b in bodies],
                stage,
                plates if plate else [],
                _both(tick, step_stage),
                worker=step_worker,
            )
        t1 = time.perf_counter()
        with progress_stage("mesh", total=len(bodies), unit="bodies") as mesh_stage:
            _mesh_bodies(bodies, fits, to_print, spec, formats, stage, rep, meshes, _both(tick, mesh_stage), bed_mm)
        rep.timings["mesh_s"] = time.perf_counter() - t1
        if plate:  # while the STEP worker still runs
            t3 = time.perf_counter()
            with progress_stage("plate", total=len(beds), unit="beds") as plate_stage:
                for name, lay in zip(plate_names(len(beds)), beds, strict=True):
                    plate_docs.append(_mesh_plate(name, lay, bodies, meshes, formats, stage))
                    plate_stage.update(advance=1)
            rep.timings["plate_s"] = time.perf_counter() - t3
        if step_job is not None:
            volumes, rep.timings["step_s"] = step_job.result()
            step_stage.end()
        done = True
    finally:
        if step_stage is not None:
            step_stage.end()
        if step_worker is not None and not done:
            step_worker.kill()  # an error or Ctrl-C here: no STEP file is begun after this
    if step_job is not None:
        for entry, b, vol in zip(rep.bodies, bodies, volumes, strict=True):
            entry["step_volume_mm3"] = round(vol, 6)
            entry["files"].append(f"{b.name}.step")
        for doc in plate_docs:
            doc["files"].append(f"{doc['name']}.step")
    if preview is not None:
        t4 = time.perf_counter()
        (stage / "preview").mkdir(exist_ok=True)
        preview(bodies, stage / "preview")
        rep.timings["preview_s"] = time.perf_counter() - t4
    doc = {
        "format": "starforge.bodies",
        "version": 2,
        "units": "mm",
        "family": {
            "name": family.spec.name,
            "box_mm": None if family.spec.box_mm is None else list(family.spec.box_mm),
            "marker_mm": family.spec.marker_mm,
        },
        "mount": {"name": mount.name, "kind": mount.kind, "params": mount.params},
        "body_spec": to_mapping(spec),
        "bed_mm": list(bed_mm),
        "frame": (
            "files: printing orientation (plate down on Z = 0, the body's up along +Z); per body, "
            "print_to_placement maps them back to family.json's placement frame (+y up, centres unchanged); "
            "a body's own 3MF keeps these vertices and its build item translates it by print_to_3mf_build_mm "
            "to the centre of the bed (bed_mm); a plate's files hold its bodies moved by print_to_bed"
        ),
        "bodies": rep.bodies,
        "plates": plate_docs,
        "warnings": rep.warnings,
    }
    atomic_write_json(stage / "bodies.json", doc)
    rep.files = sorted(str(p.relative_to(stage)) for p in stage.rglob("*") if p.is_file())
    rep.timings["total_s"] = time.perf_counter() - t0
    return rep


def bed_centre_offset(vertices, bed_mm) -> np.ndarray:
    """The (x, y, 0) translation (mm) that puts the centre of the vertices' footprint at the
    centre of a ``bed_mm`` (width, depth) bed whose corner is the origin."""
    v = np.asarray(vertices, float)
    centre = (v[:, :2].min(0) + v[:, :2].max(0)) / 2
    return np.array([bed_mm[0] / 2 - centre[0], bed_mm[1] / 2 - centre[1], 0.0])


def _mesh_plate(name, lay, bodies, meshes, formats, stage) -> dict:
    """One bed's STL / 3MF from the bodies' meshes (printing orientation, (v, f) arrays) moved
    by the layout's translations; its bodies.json entry (the STEP worker adds ``<name>.step``)."""
    from starforge.cad.mesh import MeshArrays, check_shell
    from starforge.cad.raster import thumbnail_png
    from starforge.cad.threemf import threemf_bytes
    from starforge.colours import body_colour
    from starforge.meshfiles import stl_bytes

    files = []
    moved = []
    for i, T in zip(lay.members, lay.transforms, strict=True):
        T = np.asarray(T, float)
        if not np.array_equal(T[:3, :3], np.eye(3)):
            raise ValueError("a bed layout only translates bodies")
        v, f = meshes[i]
        mv = MeshArrays(v + T[:3, 3], f)
        check_shell(mv.vertices, mv.faces, f"{name}: {bodies[i].name}")  # float32 rounding moves with it
        moved.append(mv)
    v = np.concatenate([m.vertices for m in moved])
    offsets = np.cumsum([0] + [len(m.vertices) for m in moved[:-1]])
    f = np.concatenate([m.faces + o for m, o in zip(moved, offsets, strict=True)])
    if "stl" in formats:
        (stage / f"{name}.stl").write_bytes(stl_bytes(v, f))
        files.append(f"{name}.stl")
    if "3mf" in formats:
        cols = [body_colour(bodies[i].star_id - 1) for i in lay.members]
        face_cols = np.repeat(np.array(cols, float), [len(m.faces) for m in moved], axis=0)
        thumb = thumbnail_png(v, f, colour=face_cols)
        (stage / f"{name}.3mf").write_bytes(threemf_bytes(moved, [bodies[i].name for i in lay.members], thumb, cols))
        files.append(f"{name}.3mf")
    return {
        "name": name,
        "bed_mm": list(lay.bed_mm),
        "gap_mm": lay.gap_mm,
        "bodies": [bodies[i].name for i in lay.members],
        "footprints_mm": np.round(lay.footprints, 6).tolist(),
        "print_to_bed": [np.round(T, 9).tolist() for T in lay.transforms],
        "files": files,
    }


def _both(tick, stage):
    """One unit of work done: the caller's count (``tick``) and the progress stage's."""

    def both() -> None:
        tick()
        stage.update(advance=1)

    return both


class _Ticker:
    """``progress(done, total)`` after each unit of work, from either thread (one lock)."""

    def __init__(self, progress, total: int) -> None:
        import threading

        self.progress, self.total, self.done, self.lock = progress, total, 0, threading.Lock()

    def __call__(self) -> None:
        if self.progress is None:
            return
        with self.lock:
            self.done += 1
            self.progress(self.done, self.total)


def _mesh_bodies(bodies, fits, to_print, spec, formats, stage, rep, meshes, tick, bed_mm) -> None:
    """Per body: the mesh in its printing orientation (appended to ``meshes``), its STL / 3MF
    files and its bodies.json entry (appended to ``rep.bodies``).  A body's 3MF build item
    centres it on a ``bed_mm`` bed (:func:`bed_centre_offset`)."""
    from starforge.cad.mesh import MeshArrays, body_arrays, check_shell, mesh_volume
    from starforge.cad.raster import thumbnail_png
    from starforge.cad.threemf import threemf_bytes
    from starforge.cad.visibility import sphere_visibility
    from starforge.colours import body_colour
    from starforge.meshfiles import stl_bytes

    for b, fit, T in zip(bodies, fits, to_print, strict=True):
        v, f = body_arrays(b, spec.sphere_segments, spec.cylinder_segments, check=False)  # checked below
        T = np.asarray(T, float)
        mesh = MeshArrays(v @ T[:3, :3].T + T[:3, 3], f)  # printing orientation: plate down on Z = 0
        check_shell(mesh.vertices, mesh.faces, b.name)  # as the file will hold it (float32)
        meshes.append(mesh)
        colour = body_colour(b.star_id - 1)
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
            "colour_rgb": list(colour),
            "print_height_mm": round(float(mesh.vertices[:, 2].max()), 6),
            "placement_to_print": np.round(T, 9).tolist(),
            "print_to_placement": np.round(np.linalg.inv(T), 9).tolist(),
            "mesh_volume_mm3": round(mesh_volume(mesh.vertices, mesh.faces), 6),
            "files": [],
        }
        entry["closest_features_mm"] = round(closest_features_mm(b), 6)  # two markers' stems/spheres
        if b.label_counters:  # what must stay standing in the engraved id, printing frame
            entry["label_counters_print_mm"] = [
                np.round(np.array([[x0, b.label_face_y, z0], [x1, b.label_face_y, z1]]) @ T[:3, :3].T + T[:3, 3], 6)
                .tolist()
                for x0, x1, z0, z1 in b.label_counters
            ]
        vis = sphere_visibility(b)
        entry["visibility"] = [round(float(v), 4) for v in vis]
        low = [f"{sphere_letter(i)} {v:.2f}" for i, v in enumerate(vis) if v < spec.min_visibility]
        if low:
            rep.warnings.append(
                f"{b.name}: sphere(s) {', '.join(low)} see less than {spec.min_visibility:.2f} of their upper hemisphere"
            )
        if not fit.fits:
            rep.warnings.append(fit.message(b.name) + " (exported with --allow-oversize)")
        if "stl" in formats:
            (stage / f"{b.name}.stl").write_bytes(stl_bytes(mesh.vertices, mesh.faces))
            entry["files"].append(f"{b.name}.stl")
        if "3mf" in formats:
            thumb = thumbnail_png(mesh.vertices, mesh.faces, colour=colour)
            offset = bed_centre_offset(mesh.vertices, bed_mm)
            (stage / f"{b.name}.3mf").write_bytes(threemf_bytes([mesh], [b.name], thumb, [colour], [offset]))
            entry["print_to_3mf_build_mm"] = np.round(offset, 6).tolist()
            entry["files"].append(f"{b.name}.3mf")
        rep.bodies.append(entry)
        tick()
