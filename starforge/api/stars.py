"""Star families: a spec from a template and options, the family made and verified, its files.

``starforge stars`` is :func:`run_stars`; a notebook calls :func:`plan_family`,
:func:`make_family` and :func:`write_family` one by one.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starforge.catalog import load_template, values_from
from starforge.errors import StarforgeError
from starforge.io import atomic_write_json, check_name, check_writable, staged_output
from starforge.markers import marker_diameter_mm
from starforge.runtime import progress as runtime_progress
from starforge.stars.model import Family, family_csv
from starforge.stars.spec import MAX_NOISE_MM, StarSpec, spec_from_mapping
from starforge.tol import tol
from starforge.tracking.presets import design_tolerance_mm, star_spec_overrides
from starforge.words import counted

__all__ = [
    "FAMILY_FILES",
    "STAR_OPTIONS",
    "StarPlan",
    "StarsRun",
    "as_options",
    "describe_family",
    "make_family",
    "plan_family",
    "run_stars",
    "write_family",
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
    # a bad value the spec file gave (and no option replaced) names the file
    with values_from(spec or "", given={k for k, v in given.items() if v is not None}):
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
    # the enumeration's compiled kernels load here, not when the API is imported
    from starforge.stars.estimate import check_memory, check_size
    from starforge.stars.family import make_family as make_stars
    from starforge.stars.verify import check_family

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
    family = make_stars(
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


def tolerance_warning(s: StarSpec) -> str | None:
    """What to say when a face-rule family keeps its faces closer than the default tracker's
    design margin at the spec's noise (twice its window), or None.  Such a family is the paper's
    (faces one pool step apart): more stars, and frames where a tracker may take one star, or
    one face relabelled, for another."""
    if s.rule != "face":
        return None
    needed = design_tolerance_mm(None, s.noise_mm)
    if s.tol_mm >= needed - tol.compare_mm:  # a designed tolerance is stored to 1e-6 mm
        return None
    return (
        f"faces are {s.tol_mm:.2f} mm apart, under the {needed:.2f} mm the default tracker needs at "
        f"{s.noise_mm:g} mm noise to tell every star and face apart; give --noise (your tracker's) or --preset to design "
        f"for it, or --tolerance {needed:.2f}"
    )


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




@dataclass(frozen=True)
class StarsRun:
    """What :func:`run_stars` made and wrote.

    Attributes
    ----------
    family : Family
        The verified family.
    folder : Path
        Where its files are.
    seconds : float
        Wall time of the whole run, s.
    """

    family: Family
    folder: Path
    seconds: float


#: the option that sets each StarSpec field, for messages
STAR_OPTIONS = {
    "box_mm": "--box",
    "marker_mm": "--marker",
    "delta_mm": "--delta",
    "gap_mm": "--gap",
    "tolerance_mm": "--tolerance",
    "min_depth_mm": "--min-depth",
    "tip_mm": "--tip",
    "noise_mm": "--noise",
    "work": "--work",
    "reserve_mm": "--reserve",
}

_OPTION_KEYS = re.compile(r"\b(" + "|".join(STAR_OPTIONS) + r")\b(?:\[(\d)\])?")


def as_options(message: str) -> str:
    """A library message with each StarSpec field named by its option: ``delta_mm`` -> ``--delta``,
    ``box_mm[0]`` -> ``--box's value 1``.

    Examples
    --------
    >>> as_options("box_mm[2] must be > 0 and delta_mm too")
    "--box's value 3 must be > 0 and --delta too"
    """

    def one(m: re.Match) -> str:
        flag = STAR_OPTIONS[m.group(1)]
        return f"{flag}'s value {int(m.group(2)) + 1}" if m.group(2) is not None else flag

    return _OPTION_KEYS.sub(one, message)


def command_with(changes: dict) -> str:
    """``starforge stars`` with the options in ``changes`` (flag -> value or list of values): the
    command a message suggests when the user's own command line is not known."""
    words = [str(w) for flag, v in changes.items() for w in (flag, *([v] if isinstance(v, str) else v))]
    return " ".join(["starforge stars", *words])


def run_stars(
    spec: str | Path | None = None,
    *,
    out: str | Path | None = None,
    avoid: Sequence[str | Path] = (),
    preview: bool = False,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
    retype: Callable[[dict], str] = command_with,
    **options,
) -> StarsRun:
    """``starforge stars`` as one call: plan the family (:func:`plan_family`), refuse before any
    work what cannot be written, fit in memory or be planned (each refusal names the options,
    and where a larger ``box_mm`` or a coarser ``delta_mm`` would do, the command with it), make
    and verify it (:func:`make_family`, a first run compiling in a helper process) and write it
    (:func:`write_family`).

    Parameters
    ----------
    spec : str or Path, optional
        Template name or TOML file (see :func:`plan_family`).
    out : path, optional
        Output folder (default ``out/<name>``).
    avoid : sequence of path
        Bodies the lab already owns (see :func:`make_family`).
    retype : callable
        ``retype(changes) -> str``: the user's command with the options in ``changes`` changed
        (flag -> value), for a refusal to suggest.
    **options
        :func:`plan_family`'s keywords (``box_mm``, ``marker``, ``mount``, ``delta_mm``...);
        None means not given.

    Examples
    --------
    >>> import tempfile
    >>> run = run_stars(box_mm=(14, 10, 30), delta_mm=2.0, count=2, out=Path(tempfile.mkdtemp()) / "f")
    >>> len(run.family), sorted(p.name for p in run.folder.iterdir())
    (2, ['family.csv', 'family.json', 'run.json'])
    """
    from starforge.stars import warmup
    from starforge.tracking.bodies import check_body_files

    if avoid:  # the files to avoid exist and are readable before any work starts
        check_body_files([Path(a) for a in avoid], "--avoid file")
    t0 = time.perf_counter()
    if options.get("seat") is not None and options.get("mount") is None and spec is None:
        raise StarforgeError(
            "--seat shapes the printed body, so it needs --mount (see `starforge mounts`), e.g. "
            + retype({"--mount": "flat"})
        )
    plan = _plan_or_hint(spec, options, retype)
    folder = Path(out) if out is not None else Path("out") / plan.spec.name
    check_writable(folder, [*FAMILY_FILES, *(["family.png"] if preview else [])], force)  # before the work
    _check_memory_or_hint(plan.spec, spec, options, retype)  # refused before anything compiles
    helper = warmup.start()  # a first run compiles on two cores (nothing on a warm cache)
    try:
        if helper is not None:
            with runtime_progress.stage("compile"):
                warmup.compile_fit_decision()
                warmup.ready("enumerate")  # the helper's kernels: loaded, not compiled a second time
        enumerate_ = runtime_progress.stage("enumerate", unit="candidates")
        try:
            family = make_family(
                plan,
                avoid=avoid,
                progress=lambda done, total: enumerate_.update(done, total),
                on_stage=warmup.ready,  # a first run's helper may still be compiling the selection
                warn=warn,
            )
        except StarforgeError as exc:  # the time estimate, no star, a count not achievable
            raise StarforgeError(as_options(str(exc))) from None
    except BaseException:
        warmup.finish(helper, 0.0)  # an error or Ctrl-C does not wait for the helper
        raise
    warmup.finish(helper)
    write_family(family, folder, preview=preview, force=True)
    return StarsRun(family, folder, time.perf_counter() - t0)


def _plan_or_hint(spec, options: dict, retype: Callable[[dict], str]) -> StarPlan:
    """:func:`plan_family`; a refusal names the options, and when a larger box makes the spec
    valid, the command with that box."""
    try:
        return plan_family(spec, **options)
    except StarforgeError as exc:
        written = load_template("stars", spec or "finger")[1]
        key = re.match(r"unknown keys? '(\w+)'|(\w+) must", str(exc))
        if spec is not None and key and (key[1] or key[2]) in {*written, key[1]} and options.get(key[2]) is None:
            raise StarforgeError(f"spec file {spec}: {exc}") from None  # the file's own key, as written there
        message = as_options(str(exc))
        box = options.get("box_mm") or written.get("box_mm")
        for k in range(1, 17) if box is not None else ():
            bigger = [round(float(x) * 1.25**k, 1) for x in box]
            try:
                plan_family(spec, **{**options, "box_mm": bigger})
            except StarforgeError:
                continue
            message += f"; a larger --box fits: e.g. {retype({'--box': [f'{x:g}' for x in bigger]})}"
            break
        raise StarforgeError(message) from None


def _check_memory_or_hint(s: StarSpec, spec, options: dict, retype: Callable[[dict], str]) -> None:
    """Refuse a spec whose enumeration would not fit in memory, naming the options and, when a
    coarser delta fits, the command with it."""
    from starforge.stars.estimate import check_memory

    try:
        check_memory(s, allow_stream=True)
        return
    except StarforgeError as exc:
        message = as_options(str(exc))
    for k in range(1, 12):
        delta = float(f"{s.delta_mm * 1.5**k:.2g}")
        try:
            check_memory(plan_family(spec, **{**options, "delta_mm": delta}).spec, allow_stream=True)
        except StarforgeError:
            continue
        message += f"; e.g. {retype({'--delta': f'{delta:g}'})}"
        break
    raise StarforgeError(message)


def describe_family(family: Family, seconds: float) -> str:
    """One line: how many stars, under which rule and selection, how far from the best possible,
    what the enumeration kept at each test, and the time each stage took."""
    sm = family.summary
    ub = sm.get("upper_bound")
    if family.spec.count is not None:
        bound = f" (any family of this spec has at most {ub})" if ub is not None else ""
    elif sm.get("optimal"):
        bound = f", optimal: proven upper bound {ub}"
    else:
        bound = f", certified upper bound {ub} (gap {sm['gap']})" if ub is not None else ""
    en = sm["enumeration"]
    und = f", {en['undecided']:,} undecided (fit within 0.01 mm, if at all)" if en.get("undecided") else ""
    return (
        f"{counted(len(family), 'star')}, rule {family.spec.rule}, select {sm['select']}{bound}; "
        f"{en['labelled']:,} labelled candidates: {en['realisable']:,} realisable, {en['deep_enough']:,} at least "
        f"{sm['min_depth_mm']:g} mm deep, {en['kyfan_ok']:,} pass the necessary fit tests, {sm['candidates']:,} fit{und}; "
        f"enumerate {family.timings['enumerate']:.2f} s, select {family.timings['select']:.2f} s, "
        f"total {seconds:.2f} s; verified independently"
    )
