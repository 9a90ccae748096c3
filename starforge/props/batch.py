"""Batch placement: one prop under many rigs, or many props, as tasks of :mod:`starforge.runtime.engine`.

Each job is ``(prop, units, spec, rig, seed)``; :func:`place_job` runs the ordinary placement
(:func:`starforge.props.placement.run_placement`, then :func:`starforge.props.files.write_outputs`
without pictures) and returns the files' bytes, so a worker writes nothing and the command
publishes every job's folder at once, or none.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path


def place_job(args: tuple) -> dict[str, bytes]:
    """One placement: ``args = (prop, units, spec, rig, seed)`` -> {file name: bytes}."""
    from starforge.props.files import write_outputs
    from starforge.props.placement import run_placement

    prop, units, spec, rig, seed = args
    res = run_placement(prop, spec, seed=int(seed), units=units, rig=rig)
    with tempfile.TemporaryDirectory(prefix="starforge-place-") as d:
        names = write_outputs(res, Path(d), render=False)
        return {n: (Path(d) / n).read_bytes() for n in names}


def job_bytes(spec: str, rig: str | None) -> float:
    """Rough peak memory of one placement, bytes: the visibility table's estimate of
    :func:`starforge.props.placement.check_cost` (sites x poses x (camera pairs + 8 + 3 loss
    patterns + 16)) plus the process's libraries (about 400 MB measured for ``place hammer``)."""
    from starforge.props.rig import load_rig
    from starforge.props.spec import load_spec, with_overrides

    s = with_overrides(load_spec(spec), rig=rig)
    r = load_rig(s.rig)
    poses = s.resolution**3 * s.orientations
    patterns = s.track.loss_patterns if s.objective == "tracked" else 1
    return s.sites * poses * (len(r.pairs) + 8 + 3 * patterns + 16) + 400e6


def job_name(prop: str, rig: str | None, many_rigs: bool) -> str:
    """The job's output folder name: the prop's (file stem or built-in name), with the rig's
    when several rigs are given."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(prop).stem or prop).lstrip("._-") or "prop"
    if many_rigs and rig:
        stem += "-" + (re.sub(r"[^A-Za-z0-9._-]+", "_", Path(rig).stem).lstrip("._-") or "rig")
    return stem[:100]


def jobs(props, rigs, units: str, spec: str, seed: int) -> list[tuple[str, tuple]]:
    """(folder name, job) for every prop x rig, in the order given.  A name is never reused,
    nor one that differs from another only in case (one folder on macOS and Windows): a name
    taken already gets the first free ``-2``, ``-3``, ... (``a b.stl`` and ``a_b.stl`` give
    ``a_b`` and ``a_b-2``)."""
    rigs = list(rigs) or [None]
    out, taken = [], set()
    for p in props:
        for r in rigs:
            base = job_name(p, r, len(rigs) > 1)
            name, k = base, 1
            while name.casefold() in taken:
                k += 1
                name = f"{base[: 100 - len(str(k)) - 1]}-{k}"
            taken.add(name.casefold())
            out.append((name, (p, units, spec, r, seed)))
    return out


def check_props(props, units: str) -> None:
    """Read every distinct prop once (a mesh file: exists, parses, holds triangles, sane size;
    a built-in: known), so that a bad one is refused in one line before any job starts."""
    from starforge.props.mesh import load_prop

    for p in dict.fromkeys(str(x) for x in props):
        load_prop(p, units, repair=False)
