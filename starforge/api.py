"""The few calls a notebook needs; the command line calls the same ones.

Each call takes plain values (names of shipped templates, paths, numbers in the units their
names give) and returns a typed result: a :class:`~starforge.stars.model.Family`, a
:class:`~starforge.props.placement.PlacementResult`, an :class:`ExportResult`, a
:class:`CheckResult`.  Files are written only by the ``write_*`` and ``export_*`` calls, into a
staging folder published at once (nothing half-written is left behind), and never over
existing files without ``force=True``.

>>> import starforge.api as sf
>>> plan = sf.plan_family(box_mm=(14, 10, 30), delta_mm=2.0)
>>> family = sf.make_family(plan)
>>> len(family) > 0 and family.spec.box_mm == (14.0, 10.0, 30.0)
True
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.catalog import load_template
from starforge.errors import StarforgeError
from starforge.io import atomic_write_json, check_name, check_writable, staged_output
from starforge.markers import marker_diameter_mm
from starforge.runtime import progress as runtime_progress
from starforge.stars.enumerate import check_memory, check_size
from starforge.stars.family import make_family as _make_family
from starforge.stars.model import Family, family_csv
from starforge.stars.spec import MAX_NOISE_MM, StarSpec, spec_from_mapping
from starforge.stars.verify import check_family
from starforge.tracking.presets import design_tolerance_mm, star_spec_overrides

__all__ = [
    "StarPlan",
    "ExportResult",
    "CheckResult",
    "plan_family",
    "make_family",
    "write_family",
    "export_bodies",
    "write_tracker_files",
    "place_markers",
    "write_placement",
    "check",
]

#: files :func:`write_family` writes (``family.png`` too with ``preview``)
FAMILY_FILES = ("family.json", "family.csv", "run.json")


@dataclass(frozen=True)
class StarPlan:
    """What :func:`make_family` makes: the validated spec, and the mount's check of each star.

    Attributes
    ----------
    spec : StarSpec
        Box, marker, pool and rules, validated (mm).
    star_filter : callable or None
        ``star_filter(vertices (n, 4, 3) mm) -> (n,) bool``: the stars whose printed body with
        the plan's mount fits the box (None without a mount).
    """

    spec: StarSpec
    star_filter: Callable[[np.ndarray], np.ndarray] | None = None


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_bodies` wrote.

    Attributes
    ----------
    folder : Path
        The output folder.
    files : tuple of str
        Every file written, relative to ``folder``.
    bodies : int
        Printable bodies written.
    entries : tuple of dict
        ``bodies.json``'s entry of each body (files, size, fit, visibility, volumes).
    warnings : tuple of str
    """

    folder: Path
    files: tuple[str, ...]
    bodies: int
    entries: tuple[dict, ...] = field(repr=False)
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class CheckResult:
    """How often a simulated tracker identifies each body (:func:`check`).

    Rates are fractions of (body, frame) events in [0, 1].

    Attributes
    ----------
    rule : str
        The identification rule of the headline rates.
    identified, wrong_body, wrong_pose, missed : float
        Right body with the right labels; another body reported; the right body with its
        markers relabelled (a wrong pose); nothing reported.
    document : dict
        The whole ``check.json`` document (every rule, worst pairs, accuracy).
    """

    rule: str
    identified: float
    wrong_body: float
    wrong_pose: float
    missed: float
    document: dict = field(repr=False)


def plan_family(
    spec: str | Path | None = None,
    *,
    box_mm: Sequence[float] | None = None,
    marker: str | float | None = None,
    mount: str | None = None,
    seat: str | None = None,
    preset: str | None = None,
    reserve_mm: Sequence[float] | None = None,
    **overrides,
) -> StarPlan:
    """The spec of a family: a template (``finger``, ``limb``, ``paper`` or a TOML path) with
    a tracker preset's tolerances, a mount's room and keyword overrides on top.

    Parameters
    ----------
    spec : str or Path, optional
        Template name or TOML file (default ``finger``, or a custom spec when ``box_mm`` is given).
    box_mm : (3,) float, mm, optional
        Size limit of the physical star.
    marker : str or float, optional
        Marker diameter in mm, or a catalogue marker (``starforge templates markers``).
    mount : str, optional
        Design for this mount: its room is reserved and every printed body is checked.
    seat : str, optional
        With ``mount``: what each stem ends in (sphere, glue, post, screw, insert).
    preset : str, optional
        Design for a tracker (``starforge templates presets``): its rules, and faces apart by
        twice its window at the spec's noise (``noise_mm``), unless ``tolerance_mm`` is given.
        ``noise_mm`` alone designs for starforge's default tracker the same way.
    reserve_mm : (3,) float, mm, optional
        Room kept free for a mount by hand (``mount`` computes it otherwise).
    **overrides
        Any key of a stars template (``delta_mm``, ``count``, ``rule``, ``tolerance_mm``, ``name``...).

    Examples
    --------
    >>> plan = plan_family("finger", count=25)
    >>> plan.spec.count, plan.spec.box_mm
    (25, (20.8, 12.6, 48.3))
    """
    if spec is not None:
        name, data = load_template("stars", spec)
    elif box_mm is None:
        name, data = load_template("stars", "finger")
    else:
        name, data = "custom", {}
    data = dict(data)
    if preset is not None:
        data.update(star_spec_overrides(preset))
    noise = overrides.get("noise_mm")
    if (preset is not None or noise is not None) and overrides.get("tolerance_mm") is None:
        # designed for the tracker: faces apart by twice its window at this noise
        nz = noise if noise is not None else float(data.get("noise_mm", 0.2))
        if not 0 <= nz <= MAX_NOISE_MM:
            raise StarforgeError(f"noise_mm must be in [0, {MAX_NOISE_MM:g}] mm (sigma per axis), got {nz:g}")
        floor = star_spec_overrides(preset).get("tolerance_mm") if preset is not None else None
        data["tolerance_mm"] = round(design_tolerance_mm(preset, nz, floor), 6)
    marker_name = None
    if marker is not None:
        try:
            float(str(marker).strip().removesuffix("mm"))
        except ValueError:
            marker_name = str(marker).strip()
        data["marker_mm"] = marker_diameter_mm(marker)
    given = {
        "box_mm": list(box_mm) if box_mm is not None else None,
        "marker": marker_name,
        "seat": seat,
        "mount": mount,
        "reserve_mm": list(reserve_mm) if reserve_mm is not None else None,
        **overrides,
    }
    data.update({k: v for k, v in given.items() if v is not None})
    data.setdefault("name", name)
    star_filter = None
    if data.get("mount") is not None:
        from starforge.cad.body import body_spec_for
        from starforge.cad.mounts import load_mount
        from starforge.cad.reserve import bodies_fit, mount_reserve_mm

        m = load_mount(data["mount"])
        marker_mm = float(data.get("marker_mm", 4.0))
        body = body_spec_for(data.get("marker"), data.get("seat"), marker_mm)
        if reserve_mm is None:
            data["reserve_mm"] = list(mount_reserve_mm(m, marker_mm, body))
        box = data["box_mm"]

        def star_filter(V, _m=m, _b=body, _d=marker_mm, _box=box):
            return bodies_fit(V, _d, _box, _m, _b)
    elif seat is not None:
        raise StarforgeError("--seat shapes the printed body: give --mount too (see `starforge mounts`)")
    s = spec_from_mapping(data)
    check_name(s.name, "--name")
    return StarPlan(s, star_filter)


def make_family(
    plan: StarPlan | str | None = None,
    *,
    avoid: Sequence[str | Path] = (),
    progress: Callable[[int, int | None], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
    warn: Callable[[str], None] | None = None,
) -> Family:
    """Enumerate, select, place and independently verify a family.

    Parameters
    ----------
    plan : StarPlan or str, optional
        From :func:`plan_family`, or a template name (default ``finger``).
    avoid : sequence of path
        Bodies a lab already owns (family.json, placement.json, tracker files): no face of a
        new star comes within the tolerance of theirs.
    progress : callable, optional
        ``progress(done, total)`` during the enumeration.
    on_stage : callable, optional
        ``on_stage(name)`` as each stage starts (``"select"``).
    warn : callable, optional
        ``warn(text)`` for each warning about the ``avoid`` files (bodies left out), as soon as
        they are read, before the enumeration.

    Raises
    ------
    StarforgeError
        When the spec is too large for the memory or time limit (before any work), when no
        star fits, or when a requested count is not achievable.

    Examples
    --------
    >>> fam = make_family(plan_family(box_mm=(14, 10, 30), delta_mm=2.0, count=3))
    >>> len(fam), [s.id for s in fam.stars]
    (3, [1, 2, 3])
    """
    if not isinstance(plan, StarPlan):
        plan = plan_family(plan)
    s = plan.spec
    check_memory(s, allow_stream=True)
    check_size(s, allow_stream=True)
    avoid_faces = avoid_sources = None
    if avoid:
        from starforge.tracking.avoid import faces_to_avoid

        avoid_faces, avoid_sources = faces_to_avoid([Path(a) for a in avoid])
        for src in avoid_sources if warn is not None else ():
            for text in src.get("warnings", ()):
                warn(text)
    family = _make_family(
        s,
        progress=progress,
        avoid_faces_mm=avoid_faces,
        avoid_sources=avoid_sources,
        star_filter=plan.star_filter,
        on_stage=on_stage,
    )
    with runtime_progress.stage("verify", total=len(family), unit="stars"):
        problems = check_family(json.loads(json.dumps(family.to_json())))
    if problems:  # the generator and the independent checker disagree: a bug, never a user error
        raise RuntimeError(f"internal error: the family failed its independent check: {problems[0]}")
    return family


def write_family(
    family: Family, out: str | Path | None = None, *, preview: bool = False, force: bool = False
) -> Path:
    """Write ``family.json`` (the source of truth), ``family.csv`` and ``run.json`` (timings),
    and with ``preview`` ``family.png``; returns the folder (default ``out/<name>``).

    Examples
    --------
    >>> import tempfile
    >>> fam = make_family(plan_family(box_mm=(14, 10, 30), delta_mm=2.0, count=2))
    >>> folder = write_family(fam, Path(tempfile.mkdtemp()) / "small")
    >>> sorted(p.name for p in folder.iterdir())
    ['family.csv', 'family.json', 'run.json']
    """
    from starforge import __version__

    folder = Path(out) if out is not None else Path("out") / family.spec.name
    names = list(FAMILY_FILES) + (["family.png"] if preview else [])
    check_writable(folder, names, force)
    with staged_output(folder, force) as stage:
        (stage / "family.json").write_text(json.dumps(family.to_json(), indent=2) + "\n", encoding="utf-8")
        (stage / "family.csv").write_text(family_csv(family), encoding="utf-8")
        atomic_write_json(stage / "run.json", {"seconds": family.timings, "verified": True, "starforge": __version__})
        if preview:
            from starforge.render.stars import family_sheet

            with runtime_progress.stage("render", unit="pictures"):
                family_sheet(family, stage / "family.png")
    return folder


def export_bodies(
    family: Family | str | Path,
    out: str | Path,
    *,
    mount: str | None = None,
    formats: Sequence[str] = ("step", "stl", "3mf"),
    ids: str | None = None,
    sets: Sequence[str] = (),
    plate: bool = True,
    preview: bool = False,
    allow_oversize: bool = False,
    force: bool = False,
) -> ExportResult:
    """Printable bodies of a family: spheres, stems and the mount, as STEP and watertight
    STL/3MF, and a print plate.

    Parameters
    ----------
    family : Family or path
        A family, or its ``family.json`` (or folder).
    out : path
        Output folder.
    mount : str, optional
        Mount template name or TOML file (``starforge mounts``); default the family's, else ``flat``.
    formats : sequence of str
        Any of ``step``, ``stl``, ``3mf``.
    ids : str, optional
        Star ids, e.g. ``"1,2,5"`` or ``"1-4"`` (default: all).
    sets : sequence of str
        Mount parameters, ``"KEY=VALUE"``.
    allow_oversize : bool
        Write bodies that do not fit the family's size limit (refused otherwise, naming the
        ``starforge stars --mount`` command that makes a family that fits).

    Examples
    --------
    >>> import tempfile
    >>> fam = make_family(plan_family(box_mm=(20.8, 12.6, 48.3), count=2, mount="flat"))
    >>> res = export_bodies(fam, Path(tempfile.mkdtemp()) / "bodies", formats=("stl",), plate=False)
    >>> res.bodies, sorted(res.files)[:2]
    (2, ['bodies.json', 'star_001.stl'])
    """
    from starforge.cad.describe import describe_bodies
    from starforge.cad.export import CAD_FORMATS, export_family
    from starforge.stars.model import load_family

    fam = family if isinstance(family, Family) else load_family(family)
    bad = [f for f in formats if f not in CAD_FORMATS]
    if bad:
        raise StarforgeError(f"unknown CAD format {bad[0]!r}; known: {', '.join(CAD_FORMATS)}")
    m, spec, ids, bodies = describe_bodies(fam, mount, sets, ids, allow_oversize)
    folder = Path(out)
    previews = None
    if preview:
        from functools import partial

        from starforge.render.bodies import draw_previews

        previews = partial(draw_previews, box_mm=fam.spec.box_mm)  # the sheet draws the limit
    with staged_output(folder, force) as stage:
        rep = export_family(
            fam, stage, m, spec, formats=tuple(formats), ids=ids, plate=plate, preview=previews, bodies=bodies,
            allow_oversize=allow_oversize,
        )
        files = tuple(sorted(str(p.relative_to(stage)) for p in stage.rglob("*") if p.is_file()))
    return ExportResult(folder, files, len(bodies), tuple(rep.bodies), tuple(rep.warnings))


def write_tracker_files(
    sources: Sequence[str | Path],
    out: str | Path,
    *,
    formats: Sequence[str] = ("qtm", "vsk", "atracsys", "csv"),
    noise_mm: float = 0.2,
    force: bool = False,
) -> dict:
    """Rigid-body files trackers load, for every body in ``sources`` (family.json,
    placement.json or tracker files); returns ``trackers.json``'s content.

    Parameters
    ----------
    formats : sequence of str
        Any of the registry's (``starforge templates`` lists them): ``qtm``, ``vsk``,
        ``atracsys``, ``rom``, ``motive``, ``csv``.
    noise_mm : float
        Marker noise the written tolerances assume, sigma per axis, mm.
    """
    from starforge.tracking.export import write_rigid_bodies

    folder = Path(out)
    with staged_output(folder, force) as stage:
        doc = write_rigid_bodies([Path(p) for p in sources], list(formats), stage, noise_mm=noise_mm)
    return doc


def place_markers(
    prop: str = "hammer",
    *,
    spec: str = "default",
    seed: int = 0,
    units: str = "m",
    avoid: Sequence[str | Path] = (),
    grip: str | None = None,
    progress=None,
    **overrides,
):
    """Where to stick markers on a prop: a built-in name or a mesh file, optimized by
    reversible-jump MCMC so that a tracker keeps it while a hand holds it and cameras drop out.

    Parameters
    ----------
    prop : str
        Built-in prop (``hammer``, ``sword``, ...) or a mesh path (STL, OBJ, PLY, GLB...).
    spec : str
        Place template name or TOML file (``starforge templates place``).
    units : str
        Units of a mesh file: ``m``, ``cm`` or ``mm``.
    avoid : sequence of path
        Bodies already in the room (placements, families, tracker files).
    **overrides
        Template keys (``markers``, ``sites``, ``resolution``, ``orientations``, ``marker_mm``...).

    Returns
    -------
    PlacementResult

    Examples
    --------
    >>> res = place_markers("box", sites=150, resolution=1, orientations=6, seed=1)
    >>> len(res.marker_points) >= 4 and res.marker_points.shape[1] == 3
    True
    """
    from starforge.props.placement import run_placement

    faces = None
    if avoid:
        from starforge.tracking.avoid import faces_to_avoid

        faces = faces_to_avoid([Path(a) for a in avoid])[0] / 1000.0  # mm -> m
    return run_placement(prop, spec, seed=seed, units=units, grip=grip, avoid=faces, progress=progress, **overrides)


def write_placement(result, out: str | Path, *, pictures: bool = True, force: bool = False) -> Path:
    """Write a placement's files (``placement.json``, ``markers.csv``, the prop with its markers,
    and with ``pictures`` the layout, convergence and rigging-guide pictures); returns the folder."""
    from starforge.props.files import write_outputs

    renderer = None
    if pictures:
        from starforge.render.props import BackgroundRenderer

        renderer = BackgroundRenderer(enabled=False)
    folder = Path(out)
    with staged_output(folder, force) as stage:
        write_outputs(result, stage, render=pictures, renderer=renderer)
    return folder


def check(
    sources: Sequence[str | Path],
    *,
    noise_mm: float = 0.2,
    drop: int = 1,
    ghosts: int = 0,
    frames: int = 2000,
    seed: int = 0,
    preset: str | None = None,
    **settings,
) -> CheckResult:
    """Simulate tracker frames for the bodies in ``sources`` and identify them as trackers do.

    Parameters
    ----------
    sources : sequence of path
        Families, placements and a lab's tracker files, in any mix.
    noise_mm : float
        Marker centre noise, sigma per axis, mm.
    drop : int
        Up to this many markers hidden per body and frame.
    ghosts : int
        Stray points near each body per frame.
    **settings
        Other :class:`starforge.tracking.check.CheckSettings` fields.
    """
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.check import CheckSettings, run_check

    s = CheckSettings(
        noise_mm=noise_mm, drop=drop, ghosts=ghosts, frames=frames, seed=seed, preset=preset, **settings
    )
    doc = run_check(load_bodies([Path(p) for p in sources]), s)
    return CheckResult(
        rule=doc["headline_rule"],
        identified=doc["identification_rate"],
        wrong_body=doc["wrong_body_rate"],
        wrong_pose=doc["flip_rate"],
        missed=doc["missed_rate"],
        document=doc,
    )
