"""Batch placement: many props, one prop under many rigs, or copies of one prop, as tasks of
:mod:`starforge.runtime.engine`, made into a fleet a tracker tells apart.

Each job is ``(prop, units, spec, rig, seed, copies, avoid, distinct_mm, tolerances_mm)``; :func:`place_job`
runs the ordinary placement (:func:`starforge.props.placement.run_placement`, or
:func:`starforge.props.placement.place_copies` for several copies of one prop on one visibility
table) and returns each layout's files as bytes, so a worker writes nothing and the command
publishes every job's folder at once, or none.

**Distinct layouts.** The jobs run in parallel, each keeping its own triangles and those of
``avoid`` (other bodies in the room) ``distinct_mm`` apart.  :func:`make_distinct` then repairs
the fleet in job order: a layout whose triangles come within ``distinct_mm`` of another
layout's (the earlier ones as repaired, the later ones as placed) is placed again avoiding all
of them, so every later repair avoids it in turn and the fleet ends with no two layouts a
tracker seeing three markers can mistake (when the re-placement finds such a layout; a
remaining clash is reported).  The layouts of one room keep the tolerance designed for the largest
marker count among them (``tolerances_mm``, one per count: a tracker's window widens with the
count, and the files of one room carry one window).  Jobs that do not clash keep their parallel result; a sequential
placement (each prop avoiding all before it) would give up the parallelism for every prop
instead of only for the few that clash.
"""

from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path

import numpy as np

from starforge.props.distinct import clashes, face_tree, tolerance_for
from starforge.stars.avoid import body_triangles


def place_job(args: tuple) -> list[dict[str, bytes]]:
    """One job: ``args = (prop, units, spec, rig, seed, copies, avoid, distinct_mm, tolerances_mm)``
    -> one {file name: bytes} per layout (``copies`` of them); ``avoid``: (k, 3) sorted triangle
    sides of other bodies, m, or None; ``distinct_mm``: the spec's ``avoid_tolerance_mm`` when
    given; ``tolerances_mm``: the tolerance per marker count
    (:func:`starforge.props.placement.place`), or None."""
    from starforge.props.files import write_outputs
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place_copies, run_placement
    from starforge.props.spec import as_spec, with_overrides

    prop, units, spec, rig, seed, copies, avoid, distinct, table = args
    if copies == 1:
        results = [
            run_placement(
                prop, spec, seed=int(seed), units=units, rig=rig, avoid=avoid, distinct_mm=distinct, tolerances_mm=table
            )
        ]
    else:
        s = with_overrides(as_spec(spec), rig=rig, distinct_mm=distinct)
        results = place_copies(load_prop(prop, units), s, int(copies), seed=int(seed), avoid=avoid, tolerances_mm=table)
    out = []
    for res in results:
        with tempfile.TemporaryDirectory(prefix="starforge-place-") as d:
            names = write_outputs(res, Path(d), render=False)
            out.append({n: (Path(d) / n).read_bytes() for n in names})
    return out


def layout_centres(files: dict[str, bytes]) -> np.ndarray:
    """(n, 3) the marker ball centres (m) a layout's placement.json records (its surface points
    when it records no centres)."""
    doc = json.loads(files["placement.json"])
    centres = (doc.get("tracked") or {}).get("marker_centres_m")
    return np.asarray(
        centres if centres is not None else [m["position"] for m in doc["markers"]], float
    ).reshape(-1, 3)


def make_distinct(layouts: list, replace, distinct_m, avoid=None, groups=None) -> list[int]:
    """Repair a fleet in place (see the module docstring): ``layouts`` is a list of (n_i, 3)
    marker centres, m; ``replace(i, faces)`` places layout ``i`` again avoiding ``faces`` ((k, 3)
    sorted sides, m) and returns its new centres; ``avoid`` holds other bodies' triangles;
    ``groups`` (one label per layout, default all one) keeps layouts of different groups (rigs:
    different rooms) from constraining each other; ``distinct_m``: the tolerance, m, or a callable
    ``distinct_m(i)`` giving layout ``i``'s when it is checked.  Returns the indices placed again."""
    groups = [0] * len(layouts) if groups is None else list(groups)
    base = np.zeros((0, 3)) if avoid is None else np.asarray(avoid, float).reshape(-1, 3)
    redone = []
    for i in range(len(layouts)):
        others = [
            body_triangles(layouts[j]) for j in range(len(layouts)) if j != i and groups[j] == groups[i]
        ]
        faces = np.concatenate([base, *others]) if others else base
        if clashes(layouts[i], face_tree(faces), distinct_m(i) if callable(distinct_m) else distinct_m):
            layouts[i] = replace(i, faces)
            redone.append(i)
    return redone


def room_tolerance_mm(counts, distinct_mm: float, tolerances_mm=None) -> float:
    """The tolerance (mm) the layouts of one room keep: the entry of ``tolerances_mm`` (one per
    marker count) for the largest of their marker ``counts``, at least ``distinct_mm``.

    >>> room_tolerance_mm([7, 11, 7], 2.6, (2.6,) * 8 + (2.62, 2.65, 2.68, 2.7, 2.72))
    2.7
    """
    return max(float(distinct_mm), tolerance_for(tolerances_mm, max(counts, default=0), distinct_mm))


def fleet(todo, results, distinct_mm: float, avoid=None, tolerances_mm=None) -> tuple[list, list[int]]:
    """The batch's layouts made distinct (:func:`make_distinct`, one fleet per rig): ``todo`` as
    :func:`jobs` gives it and ``results`` the :func:`place_job` results in its order; with
    ``tolerances_mm`` (one per marker count) each rig's layouts keep the entry of its largest
    count (at least ``distinct_mm``), and a layout placed again is designed with it.  Returns
    ``(rows, redone)``: rows ``(folder name, job, files, centres m)`` one per layout, and the rows
    placed again (in this process)."""
    rows = [[name, job, files, layout_centres(files)] for (names, job), group in zip(todo, results, strict=True)
            for name, files in zip(names, group, strict=True)]  # fmt: skip

    def room_mm(i):  # the tolerance of layout i's room: its largest marker count's
        return room_tolerance_mm([len(r[3]) for r in rows if r[1][3] == rows[i][1][3]], distinct_mm, tolerances_mm)

    def again(i, faces):
        floor = room_mm(i)
        table = None if tolerances_mm is None else tuple(max(t, floor) for t in tolerances_mm)
        files = place_job((*rows[i][1][:5], 1, faces, floor, table))[0]
        rows[i][2:] = [files, layout_centres(files)]
        return rows[i][3]

    redone = make_distinct(
        [r[3] for r in rows], again, lambda i: room_mm(i) / 1000.0, avoid, [r[1][3] for r in rows]
    )
    return [tuple(r) for r in rows], redone


def job_bytes(spec, rig: str | None) -> float:
    """Rough peak memory of one placement, bytes: the visibility table's estimate of
    :func:`starforge.props.prepare.check_cost` (sites x poses x (camera pairs + 8 + 3 loss
    patterns + 16)) plus the process's libraries (about 400 MB measured for ``place hammer``)."""
    from starforge.props.rig import load_rig
    from starforge.props.spec import as_spec, with_overrides

    s = with_overrides(as_spec(spec), rig=rig)
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


def jobs(
    props, rigs, units: str, spec, seed: int, copies: int = 1, avoid=None, distinct_mm=None, tolerances_mm=None
) -> list[tuple[list[str], tuple]]:
    """(folder names, job) for every prop x rig, in the order given: one folder per copy
    (``<name>-01``, ``-02``, ... when ``copies`` > 1).  A name is never reused, nor one that
    differs from another only in case (one folder on macOS and Windows): a name taken already
    gets the first free ``-2``, ``-3``, ... (``a b.stl`` and ``a_b.stl`` give ``a_b`` and
    ``a_b-2``)."""
    rigs = list(rigs) or [None]
    out, taken = [], set()
    room = 100 - (0 if copies == 1 else 1 + max(2, len(str(copies))))  # a name's length, its copy's suffix left
    for p in props:
        for r in rigs:
            base = job_name(p, r, len(rigs) > 1)[:room]
            name, k = base, 1
            while name.casefold() in taken or any(
                f"{name}-{c:02d}".casefold() in taken for c in range(1, copies + 1)
            ):
                k += 1
                name = f"{base[: room - len(str(k)) - 1]}-{k}"
            folders = [name] if copies == 1 else [f"{name}-{c:02d}" for c in range(1, copies + 1)]
            taken.update(f.casefold() for f in folders)
            out.append((folders, (p, units, spec, r, seed, copies, avoid, distinct_mm, tolerances_mm)))
    return out


def check_props(props, units: str) -> None:
    """Read every distinct prop once (a mesh file: exists, parses, holds triangles, sane size;
    a built-in: known), so that a bad one is refused in one line before any job starts."""
    from starforge.props.mesh import load_prop

    for p in dict.fromkeys(str(x) for x in props):
        load_prop(p, units, repair=False)
