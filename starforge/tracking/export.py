"""Writing a body set in tracker formats: one file per body per format, through the format
registry (:mod:`starforge.tracking.formats`), with the tolerances of
:mod:`starforge.tracking.tolerances` and a summary (``trackers.json``) that names the noise the
files assume."""

from __future__ import annotations

from pathlib import Path

from starforge.errors import StarforgeError
from starforge.tracking.formats import FORMATS, WriteContext, check_id_start, parse_formats


def check_exportable(bodyset, formats, id_start: int = 1) -> None:
    """Refuse, before anything is written, what a format cannot hold (an Atracsys geometry: at
    most 6 fiducials and a 32-bit id; an NDI tool definition: at most 20 markers)."""
    check_id_start(id_start, len(bodyset.bodies))
    for fmt in formats:
        f = FORMATS[fmt]
        if f.max_markers is None:
            continue
        big = [b for b in bodyset.bodies if b.n_markers > f.max_markers]
        if big:
            raise StarforgeError(
                f"a {f.vendor} {fmt} file holds at most {f.max_markers} markers; {big[0].name} has "
                f"{big[0].n_markers} (and {len(big) - 1} more bodies are too large); leave out {fmt}"
            )


def write_bodies(bodyset, formats, out_dir: Path, id_start: int = 1, noise_mm: float = 0.2) -> dict:
    """Write every body of ``bodyset`` (a :class:`~starforge.tracking.bodies.BodySet`) in each
    format into ``out_dir/<format>/<name><suffix>``.

    Returns a summary: the paths written, the numeric id of every body (``id_start`` + index,
    unique across a lab that gives each family its own range: Atracsys geometry ids) and the
    tolerances written (:func:`starforge.tracking.tolerances.export_tolerances` at ``noise_mm``).
    """
    from starforge.io import atomic_write_bytes
    from starforge.tracking.tolerances import export_tolerances

    formats = parse_formats(formats)
    check_exportable(bodyset, formats, id_start)
    out_dir = Path(out_dir)
    radius = (bodyset.marker_mm or 4.0) / 2.0
    tol = export_tolerances([b.points_mm for b in bodyset.bodies], noise_mm)
    ids = {b.name: id_start + k for k, b in enumerate(bodyset.bodies)}
    written: list[Path] = []
    for fmt in formats:
        f = FORMATS[fmt]
        for k, b in enumerate(bodyset.bodies):
            ctx = WriteContext(
                index=k,
                geometry_id=ids[b.name],
                marker_radius_mm=radius,
                normals=b.normals,
                tolerances=tol,
                min_markers=3,
            )
            path = out_dir / fmt / f"{b.name}{f.suffix}"
            atomic_write_bytes(path, f.write(b.name, b.points_mm, ctx))
            written.append(path)
    return {
        "files": [str(p.relative_to(out_dir)) for p in written],
        "atracsys_ids": ids,
        "tolerances": tol,
        "qtm": {k: tol[k] for k in ("margin_mm", "bone_length_tolerance_mm", "maximum_residual_mm")},
    }


def write_rigid_bodies(input_paths, formats, out_dir: Path, id_start: int = 1, noise_mm: float = 0.2) -> dict:
    """Read a family, placement or tracker file (or several) and write its bodies (see
    :func:`write_bodies`).  Raises StarforgeError on a bad input file or an unknown format."""
    from starforge.tracking.bodies import load_bodies

    fmts = parse_formats(formats)
    return write_bodies(load_bodies(input_paths), fmts, Path(out_dir), id_start, noise_mm)
