"""Marker placement end to end: prop -> seated sites -> visibility table -> optimizer -> result.

:func:`run_placement` runs one placement from plain arguments (a prop name or path, a spec
name, a seed) and returns the :class:`PlacementResult`; :func:`place` does the same from a
loaded prop and spec.  The files are written by :mod:`starforge.props.files`.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from starforge.props.costs import CostBreakdown, evaluate
from starforge.props.distinct import tolerance_for
from starforge.props.evaluate import evaluate_layouts
from starforge.props.heldout import (
    VALIDATION_SEED_OFFSET,
    HeldOut,
    explain_shortfall,
    polisher,
    shortfall_warning,
    validator,
)
from starforge.props.mesh import load_prop
from starforge.props.optimizer import AnnealResult, ChainResult, anneal
from starforge.props.prepare import check_scale, prepare, prop_name_warnings
from starforge.props.result import PlacementResult, tick
from starforge.props.rig import load_rig
from starforge.props.scenarios import LOSS_SEED_OFFSET, loss_scenarios
from starforge.props.spacing import spaced_capacity, spacing_m
from starforge.props.spec import PlaceSpec, as_spec, with_overrides
from starforge.props.tracked import Problem, TrackSettings, kernels_compiled
from starforge.props.tracked_optimizer import optimize
from starforge.runtime.kernels import FIRST_RUN_NOTE
from starforge.runtime.progress import note as progress_note
from starforge.runtime.progress import report as progress_report
from starforge.spec import require
from starforge.stars.avoid import body_triangles


def run_placement(
    prop: str = "hammer",
    spec: str | PlaceSpec = "default",
    seed: int = 0,
    units: str = "m",
    grip: str | None = None,
    avoid: np.ndarray | None = None,
    progress=None,
    tolerances_mm=None,
    **overrides,
) -> PlacementResult:
    """One placement from plain arguments (the library entry point, e.g. for a batch).

    Parameters
    ----------
    prop : str
        A built-in name (``hammer``, ``builtin:hammer``) or a mesh path.
    spec : str or PlaceSpec
        A place template name or TOML path, or a spec.
    seed : int
    units : str
        Units of a mesh file (m, cm, mm).
    grip : str, optional
        ``N`` (grip N of the printed distribution), ``x0,y0,z0,x1,y1,z1[,r]`` (a fist around that
        segment, prop frame, m), ``none`` for no hand; default: the distribution of grips.
    avoid : (k, 3) float, m, optional
        Sorted side lengths of the marker triangles of bodies already in the room
        (:func:`starforge.tracking.avoid.faces_to_avoid` reads them from files, in mm).
    tolerances_mm : sequence of float, optional
        See :func:`place`.
    **overrides
        :func:`starforge.props.spec.with_overrides` keywords (``markers``, ``marker_mm``, ...).
    """
    s = as_spec(spec)
    cap = None
    if grip is not None and str(grip).strip().lower() == "none":
        overrides["hand"] = False
    elif grip is not None:
        cap = str(grip)
    s = with_overrides(s, **overrides)
    return place(load_prop(prop, units), s, seed=seed, progress=progress, avoid=avoid, grip=cap, tolerances_mm=tolerances_mm)


def _stages(progress):
    """``progress(stage, done, total)``: the caller's callback (if any) and the process's progress
    stages (:mod:`starforge.runtime.progress`)."""
    shown = progress_report()

    def both(name: str, done, total) -> None:
        shown(name, done, total)
        if progress is not None:
            progress(name, done, total)

    return both


def _prepared(prop, spec: PlaceSpec, seed: int, progress, grip):
    """What every placement starts from: ``(rng, timings, progress, warnings, prepared)``, the
    generator having drawn the sites and poses."""
    require(isinstance(seed, int) and seed >= 0, f"seed must be an integer >= 0, got {seed}")
    rng = np.random.default_rng(seed)
    timings: dict = dict(getattr(prop, "timings", {}) or {})
    progress = _stages(progress)

    warnings = prop_name_warnings(prop) + check_scale(prop, load_rig(spec.rig), spec.marker_diameter_m)
    seat = spec.marker_seat()
    if seat.name.endswith(" mm ball"):
        warnings.append(
            f"a {seat.ball_mm:g} mm marker is not in the catalogue: a generic ball on a {seat.base_mm:g} mm base with its "
            f"centre {seat.centre_height_mm:g} mm above it is assumed (--marker NAME for a catalogue marker, --base-mm for the base)"
        )
    if not kernels_compiled():
        progress_note(FIRST_RUN_NOTE)
    progress("sites", 0, None)
    prep = prepare(prop, spec, rng, lambda d, n: progress("rays", d, n), timings, grip, seed)
    return rng, timings, progress, warnings + list(prep.notes), prep


def place(
    prop, spec: PlaceSpec, seed: int = 0, progress=None, avoid=None, grip=None, on_layout=None, tolerances_mm=None
) -> PlacementResult:
    """Optimize a marker set on ``prop`` (a :class:`starforge.props.mesh.PropMesh`).

    Parameters
    ----------
    prop : PropMesh
    spec : PlaceSpec
    seed : int
        Seeds ``numpy.random.default_rng``; same seed, same result.
    progress : callable, optional
        ``progress(stage, done, total)`` for a progress bar.
    avoid : (k, 3) float or None
        Marker triangles (sorted sides, m) of props and stars already in the room (tracked
        objective): the layout's triangles keep ``avoid_tolerance_mm`` from them.
    grip : starforge.props.hand.Capsule, optional
        The hand (default: the prop's grip, when ``spec.hand``).
    on_layout : callable, optional
        ``on_layout(result)`` as soon as the layout is chosen, before the fresh-pose evaluation
        (the tracked objective): ``result`` then lacks only ``evaluation`` and that step's
        warnings (the CLI starts drawing the pictures, which need neither).
    tolerances_mm : sequence of float, optional
        The triangle tolerance (mm) for each marker count (tracked objective;
        :func:`starforge.props.distinct.tolerance_for`): a layout of ``n`` markers is designed
        and scored with entry ``n``, also when it is grown past its target, and the result's
        spec carries the one of its final count.  None: ``avoid_tolerance_mm`` for every count.
    """
    rng, timings, progress, warnings, prep = _prepared(prop, spec, seed, progress, grip)
    if spec.objective == "tracked":
        return _place_tracked(prop, spec, seed, rng, prep, timings, warnings, avoid, progress, on_layout, tolerances_mm)
    res = _place_paper(prop, spec, seed, rng, prep, timings, warnings, progress)
    if on_layout is not None:
        on_layout(res)
    return res


def place_copies(
    prop, spec: PlaceSpec, copies: int, seed: int = 0, progress=None, avoid=None, grip=None, tolerances_mm=None
) -> list[PlacementResult]:
    """``copies`` layouts on one prop (an airframe, a tool a lab owns several of) that a tracker
    tells apart: optimized one after the other on one visibility table, each avoiding the
    triangles of every layout before it and of ``avoid`` (sorted sides, m) by
    ``track.avoid_tolerance_mm``, as well as its own (:mod:`starforge.props.distinct`).  The
    first equals :func:`place` with the same seed; each later one continues its random stream,
    so the set is deterministic.  Every copy is scored on the same scenarios (the hand, camera
    loss) and checked on the same fresh poses.  Tracked objective only; ``tolerances_mm`` as
    :func:`place` takes it."""
    require(isinstance(copies, int) and copies >= 1, f"copies must be an integer >= 1, got {copies}")
    require(
        spec.objective == "tracked",
        f"copies need the tracked objective (the default spec); the spec's objective is {spec.objective!r}",
    )
    rng, timings, progress, warnings, prep = _prepared(prop, spec, seed, progress, grip)
    faces = np.zeros((0, 3)) if avoid is None else np.asarray(avoid, float).reshape(-1, 3)
    out = []
    for _ in range(copies):
        res = _place_tracked(prop, spec, seed, rng, prep, dict(timings), warnings, faces, progress, None, tolerances_mm)
        out.append(res)
        faces = np.concatenate([faces, body_triangles(res.centres())])
    return out


def _place_paper(prop, spec, seed, rng, prep, timings, warnings, progress) -> PlacementResult:
    """The paper's objective (eq. 1-5) and RJMCMC (eq. 6-9) on the prepared table."""
    table, sites = prep.table, prep.sites
    v = table.site_visibility
    t = time.perf_counter()
    run_cb = lambda d, n: progress("optimise", d, n)  # noqa: E731
    run_cb(0, spec.chain.restarts)
    pose_seen = table.seen.any(axis=2)  # (s, p): some pair sees the site at the pose
    result = anneal(sites.points, v, spec.costs, spec.chain, rng, on_run=run_cb, site_pose_seen=pose_seen)
    t = tick(timings, "optimize_s", t)
    chosen = tuple(int(s) for s in result.best.sites)
    seen_any = pose_seen[list(chosen)]
    cost = evaluate(sites.points[list(chosen)], v[list(chosen)], spec.costs, marker_pose_seen=seen_any)
    tick(timings, "score_s", t)
    return PlacementResult(
        prop, spec, seed, prep.rig, prep.poses, sites, prep.removed["constrained"], v, chosen, cost, result,
        seen_any, timings, table.rays, warnings=tuple(warnings), seat=prep.seat, seat_report=prep.seat_report,
        capsules=prep.capsules, removed=prep.removed, marker_masks=table.masks[list(chosen)], grips=prep.grips,
        part=prep.part,
    )  # fmt: skip



def _held_out_tracked(opt) -> float:
    """The winner's tracked fraction on the held-out ranking sample."""
    sel = opt.baselines["selection"]
    return float(sel["candidates"][sel["winner"]]["validation_tracked"])


#: one-sided 95 % normal quantile: a layout is grown until its held-out tracked fraction clears
#: the target at this confidence
CONFIDENCE_Z = 1.6449


def confirmed_tracked(fraction: float, poses: int, z: float = CONFIDENCE_Z) -> float:
    """The lower Wilson score bound of a tracked ``fraction`` measured on ``poses`` held-out poses
    (each pose counted once: its camera-loss scenarios are not independent).  The held-out sample
    also ranks and polishes the candidates, so the winner's own fraction is biased upward; the
    bound asks the target of what the sample can vouch for."""
    if poses <= 0:
        return fraction
    n, p = float(poses), float(fraction)
    centre = p + z * z / (2 * n)
    spread = z * math.sqrt(max(p * (1 - p), 0.0) / n + z * z / (4 * n * n))
    return (centre - spread) / (1 + z * z / n)


def _grown(opt, prob: Problem, centres, rng, run_cb, validate, polish, tolerances_mm):
    """``(opt, prob, notes)``: while the layout's held-out tracked fraction does not clear
    ``target_tracked`` at 95 % confidence (:func:`confirmed_tracked`), the optimization again
    with one marker more (up to ``max_markers``, and while that many fit the spacing), started
    also from the layout kept so far with markers added to it, and its triangles kept the
    tolerance for that many markers
    (:func:`starforge.props.distinct.tolerance_for`); the first that reaches the target, else the
    one tracked most (a layout replaces the one kept only with more markers and more scenarios
    tracked).  The held-out sample ranks; the evaluation's fresh poses stay unseen.  ``prob``:
    the problem the kept layout was optimized in; ``notes``: one line when markers were added."""
    ts = prob.settings
    first = best = opt
    kept = prob
    n = ts.target_markers
    while confirmed_tracked(_held_out_tracked(best), ts.validation_poses) < ts.target_tracked and n < ts.max_markers:
        if spaced_capacity(centres, prob.spacing, n + 1) <= n:
            break
        n += 1
        tol = tolerance_for(tolerances_mm, n, ts.avoid_tolerance_mm)
        trial = replace(prob, settings=replace(ts, target_markers=n, avoid_tolerance_mm=tol))
        tuned = None if polish is None else lambda sites, others=(), trial=trial: polish(sites, others, trial)
        grown = optimize(trial, rng, run_cb, validate, tuned, start=best.sites)
        if len(grown.sites) > len(best.sites) and _held_out_tracked(grown) > _held_out_tracked(best):
            best, kept = grown, trial
    if best is first:
        return first, prob, []
    return best, kept, [
        f"{len(first.sites)} markers were tracked in {100 * _held_out_tracked(first):.1f} % of the held-out scenarios, "
        f"not clearly above the {100 * ts.target_tracked:g} % target (95 % confidence): {len(best.sites)} placed, tracked in "
        f"{100 * _held_out_tracked(best):.1f} % (--markers N places exactly N)"
    ]


def _scored_at_count(opt, prob: Problem, tolerances_mm):
    """``(opt, prob)`` with the layout's terms at the tolerance for its own marker count (a search
    for ``n`` markers may keep fewer; the tolerance never grows as the count falls, so the
    layout keeps it)."""
    tol = tolerance_for(tolerances_mm, len(opt.sites), prob.settings.avoid_tolerance_mm)
    if tol == prob.settings.avoid_tolerance_mm:
        return opt, prob
    prob = replace(prob, settings=replace(prob.settings, avoid_tolerance_mm=tol))
    return replace(opt, terms=prob.terms(list(opt.sites))), prob


def _place_tracked(
    prop, spec, seed, rng, prep, timings, warnings, avoid, progress, on_layout=None, tolerances_mm=None
) -> PlacementResult:
    """The tracked objective (:mod:`starforge.props.tracked`) over camera-loss scenarios, then
    the chosen layout and both baselines checked on fresh poses (:mod:`starforge.props.evaluate`)."""
    t = time.perf_counter()
    ts, table, sites, rig = spec.track, prep.table, prep.sites, prep.rig
    centres = sites.points + prep.seat.centre_height_m * sites.normals
    seen, _ = loss_scenarios(table.masks, len(rig.cameras), ts.cameras_lost, ts.loss_patterns, np.random.default_rng(seed + LOSS_SEED_OFFSET))
    ext = np.sort(prop.extents_m)
    spacing = spacing_m(ts.marker_mm, rig, ts.gap_px)
    warnings = list(warnings)
    fit = spaced_capacity(centres, spacing, ts.target_markers)
    if fit < ts.target_markers:  # a small prop: markers closer than the spacing merge in the images
        n = max(ts.min_markers, fit)
        warnings.append(
            f"only {fit} markers fit {spacing * 1000:.1f} mm apart on the usable sites: {n} markers placed, "
            f"not {ts.target_markers}" + (" (some closer than the spacing)" if n > fit else "")
        )
        ts = replace(ts, target_markers=n)
    ts = replace(ts, avoid_tolerance_mm=tolerance_for(tolerances_mm, ts.target_markers, ts.avoid_tolerance_mm))
    prob = Problem(
        centres,
        seen,
        seen.mean(axis=1),
        ts,
        spacing,
        max(ts.spread_fraction * float(ext[1]), 1e-4),
        None if avoid is None or not len(avoid) else np.asarray(avoid, float),
        margin=prep.seat_report.margin_m,
        margin_target=spec.seat.margin_cap_mm / 1000.0,
    )
    run_cb = lambda d, n: progress("optimise", d, n)  # noqa: E731
    run_cb(0, ts.restarts)
    validate = polish = ranking = None
    if ts.validation_poses:
        ranking = HeldOut(prop, spec, seed, prep, VALIDATION_SEED_OFFSET)
        validate = validator(ranking, spec, centres, prob)
        polish = polisher(prop, spec, seed, prep, centres, prob)
    opt = optimize(prob, rng, run_cb, validate, polish)
    if ts.grow_markers and validate is not None:
        opt, prob, note = _grown(opt, prob, centres, rng, run_cb, validate, polish, tolerances_mm)
        warnings += note
    opt, prob = _scored_at_count(opt, prob, tolerances_mm)
    ts = prob.settings
    if ts.avoid_tolerance_mm != spec.track.avoid_tolerance_mm:  # the result says what the layout keeps
        spec = replace(spec, track=replace(spec.track, avoid_tolerance_mm=ts.avoid_tolerance_mm))
    t = tick(timings, "optimize_s", t)
    chosen, terms = opt.sites, opt.terms
    shortfall = {}
    won = opt.baselines["selection"]["candidates"][opt.baselines["selection"]["winner"]]
    if won["validation_tracked"] is not None and won["validation_tracked"] < ts.target_tracked:
        shortfall = explain_shortfall(ranking, spec, prep, prob, chosen, prep.removed, fit)
        warnings.append(shortfall_warning(shortfall, prob.spacing, bool(prep.capsules)))
        t = tick(timings, "shortfall_s", t)
    ann = _as_anneal(opt)
    cost = _tracked_cost(terms)
    res = PlacementResult(
        prop, spec, seed, rig, prep.poses, sites, prep.removed["constrained"], prob.visibility, chosen, cost, ann,
        seen[list(chosen)], timings, table.rays, opt, (), prob.spacing, seat=prep.seat,
        seat_report=prep.seat_report, capsules=prep.capsules, removed=prep.removed,
        marker_masks=table.masks[list(chosen)], shortfall=shortfall, grips=prep.grips, part=prep.part,
    )  # fmt: skip
    if on_layout is not None:
        on_layout(res)
    progress("evaluate", 0, None)  # the layouts on fresh poses
    layouts = {"default": chosen, "greedy_local_search": opt.baselines["greedy_local_search"]["sites"]}
    if opt.baselines["best_of_random"]["sites"] is not None:
        layouts["best_of_random"] = opt.baselines["best_of_random"]["sites"]
    ev = evaluate_layouts(
        prop,
        {k: (centres[list(v)], sites.normals[list(v)]) for k, v in layouts.items()},
        rig,
        prep.poses.pivot,
        spec.evaluation,
        seed,
        ts.min_height_mm,
        prep.grips,
        spec.grazing_limit_deg,
    )
    t = tick(timings, "evaluate_s", t)
    warnings += _layout_warnings(terms, ts, seen.shape[1], len(prep.poses), len(rig.cameras), prob.spacing)
    warnings += _baselines_ahead(ev)
    return replace(res, warnings=tuple(warnings), evaluation=ev)


def _as_anneal(opt) -> AnnealResult:
    """The tracked optimizer's chains as the paper's optimizer reports them (what the convergence
    picture and placement.json read); one chain of the chosen layout when none ran."""
    chosen, terms = opt.sites, opt.terms
    runs = tuple(
        ChainResult(c.sites, c.cost, c.iterations, c.history, c.history, np.full(len(c.history), len(c.sites), np.int16), {}, {"all": c.accepted})
        for c in opt.runs
    ) or (
        ChainResult(chosen, terms["total"], 0, np.array([terms["total"]]), np.array([terms["total"]]), np.array([len(chosen)], np.int16)),
    )  # fmt: skip
    return AnnealResult(min(runs, key=lambda c: c.cost), runs)


def _tracked_cost(terms: dict) -> CostBreakdown:
    """The tracked objective's terms in the paper's breakdown (placement.json's ``cost``)."""
    return CostBreakdown(
        total=terms["total"],
        visibility=1.0 - terms["mean_visibility"],
        count=0.0,
        overlap=float(terms["close_pairs"]),
        symmetry=0.0,
        near_symmetry=0.0,
        mean_visibility=terms["mean_visibility"],
        overlapping_pairs=terms["close_pairs"],
        symmetric=terms["near_symmetry_margin_m"] == 0.0,
        margin_m=terms["near_symmetry_margin_m"],
        markers=terms["markers"],
        coverage=terms["untracked"],
    )


def _layout_warnings(terms: dict, ts: TrackSettings, scenarios: int, poses: int, cameras: int, spacing: float) -> list[str]:
    """What the chosen layout leaves short on the searched scenarios: untracked ones, close pairs,
    triangles a tracker may mistake for another prop's or its own."""
    warnings = []
    lost = int(round(ts.cameras_lost * cameras))
    if terms["untracked"] > 0:
        warnings.append(
            f"{100 * terms['untracked']:.1f} % of the scenarios ({round(terms['untracked'] * scenarios)} of "
            f"{scenarios}: {poses} poses, {lost} of {cameras} cameras lost at random) "
            "are not tracked (fewer than 3 markers seen, or in a line)"
        )
    if terms["close_pairs"]:
        warnings.append(f"{terms['close_pairs']} marker pair(s) closer than the spacing {spacing * 1000:.1f} mm")
    if terms["avoid_conflicts"]:
        warnings.append(
            f"{terms['avoid_conflicts']} marker triangle(s) within {ts.avoid_tolerance_mm:g} mm of another prop's"
        )
    if terms.get("own_conflicts"):
        warnings.append(
            f"{terms['own_conflicts']} of the layout's own triangles lie within {ts.avoid_tolerance_mm:g} mm of another "
            f"of them or of themselves relabelled (self-margin {terms['self_margin_m'] * 1000:.2f} mm): a tracker that "
            "sees only those three markers may report a wrong pose; try more --sites or fewer --markers"
        )
    return warnings


def _baselines_ahead(ev: dict) -> list[str]:
    """A warning when a baseline layout tracked more fresh evaluation poses than the chosen one."""
    ahead = [
        f"{k.replace('_', ' ')} ({v['poses_only_it_tracks']} poses only it tracks, {v['poses_only_default_tracks']} "
        f"only the chosen one; paired exact test p = {v['paired_p_value']:.2g}"
        + ("" if v["paired_p_value"] < 0.05 else ": within the evaluation's noise") + ")"
        for k, v in ev.items()
        if not k.startswith("_") and k != "default" and ev.get("default") and v["tracked"] > ev["default"]["tracked"]
    ]
    if not ahead:
        return []
    return [
        f"on the {ev['_poses']} fresh evaluation poses a baseline layout tracked more poses than the chosen one: "
        + "; ".join(ahead)
    ]
