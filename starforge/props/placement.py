"""Marker placement end to end: spec -> sites -> visibility table -> annealing -> files.

``placement.json`` is the source of truth (read back with :func:`load_placement`); the CSV,
the mesh and the pictures are derived from the same result.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.costs import CostBreakdown, CostSettings, evaluate
from starforge.props.optimizer import AnnealResult, ChainSettings, anneal
from starforge.props.sites import Constraints, Sites
from starforge.props.tracked import TrackSettings
from starforge.spec import in_range, require

FORMAT = "starforge.placement"
VERSION = 1
CSV_HEADER = ("id", "x_m", "y_m", "z_m", "nx", "ny", "nz")
HISTORY_POINTS = 400


@dataclass(frozen=True)
class PlaceSpec:
    """Everything a placement run needs besides the prop and the seed (``templates/place/*.toml``)."""

    description: str = ""
    objective: Literal["tracked", "paper"] = "paper"
    sites: int = 1000
    resolution: int = 4
    orientations: int = 1
    grazing_limit_deg: float = 80.0
    occlusion: bool = True
    rig: str = "default"
    mesh_format: Literal["glb", "stl"] = "glb"
    costs: CostSettings = field(default_factory=CostSettings)
    chain: ChainSettings = field(default_factory=ChainSettings)
    track: TrackSettings = field(default_factory=TrackSettings)
    constraints: Constraints = field(default_factory=Constraints)
    name: str = "custom"

    def __post_init__(self):
        require(
            self.objective in ("tracked", "paper"),
            f"objective must be tracked or paper, got {self.objective!r}",
        )
        in_range("sites", self.sites, 1, 100000)
        in_range("resolution", self.resolution, 1, 64)
        in_range("orientations", self.orientations, 1, 1000)
        in_range("grazing_limit_deg", self.grazing_limit_deg, 1e-6, 180.0)

    @property
    def marker_diameter_m(self) -> float:
        """The marker ball in effect, m."""
        return self.track.marker_mm / 1000.0 if self.objective == "tracked" else self.costs.marker_diameter_m


def load_spec(name_or_path: str = "default") -> PlaceSpec:
    """A placement spec from a shipped template (``default``, ``long``, ``paper``) or a TOML file."""
    from starforge.catalog import load_template
    from starforge.spec import from_mapping

    name, data = load_template("place", name_or_path)
    data = dict(data)
    data.setdefault("name", name)
    return from_mapping(PlaceSpec, data, where=f"place spec {name}")


def with_overrides(
    spec: PlaceSpec,
    markers: int | None = None,
    resolution: int | None = None,
    orientations: int | None = None,
    sites: int | None = None,
    restarts: int | None = None,
    rig: str | None = None,
    constraints: Constraints | None = None,
    mesh_format: str | None = None,
    marker_mm: str | float | None = None,
) -> PlaceSpec:
    """The spec with CLI options applied (each validated by the dataclasses).  ``marker_mm``: a
    diameter in mm or a marker catalogue name (:mod:`starforge.markers`)."""
    if markers is not None:
        cs = spec.track if spec.objective == "tracked" else spec.costs
        require(
            cs.min_markers <= markers <= cs.max_markers,
            f"markers must be in [{cs.min_markers}, {cs.max_markers}], got {markers}",
        )
        if spec.objective == "tracked":
            spec = replace(spec, track=replace(spec.track, target_markers=int(markers)))
        else:
            spec = replace(spec, costs=replace(spec.costs, target_markers=int(markers)))
    if marker_mm is not None:
        from starforge.markers import marker_diameter_mm

        d = marker_diameter_mm(marker_mm)
        spec = replace(
            spec,
            track=replace(spec.track, marker_mm=d),
            costs=replace(spec.costs, marker_diameter_m=d / 1000),
        )
    if restarts is not None:
        spec = replace(
            spec,
            chain=replace(spec.chain, restarts=int(restarts)),
            track=replace(spec.track, restarts=int(restarts)),
        )
    kw = {
        k: v
        for k, v in dict(
            resolution=resolution,
            orientations=orientations,
            sites=sites,
            rig=rig,
            constraints=constraints,
            mesh_format=mesh_format,
        ).items()
        if v is not None
    }
    if "mesh_format" in kw:
        require(
            kw["mesh_format"] in ("glb", "stl"), f"mesh format must be glb or stl, got {kw['mesh_format']!r}"
        )
    return replace(spec, **kw) if kw else spec


@dataclass(frozen=True)
class PlacementResult:
    """One optimized placement with everything needed to re-check it."""

    prop: object  # PropMesh
    spec: PlaceSpec
    seed: int
    rig: object  # Rig
    poses: object  # Poses
    sites: Sites
    forbidden: int
    site_visibility: np.ndarray = field(repr=False)
    marker_sites: tuple[int, ...] = ()
    cost: CostBreakdown | None = None
    anneal: AnnealResult | None = None
    marker_pose_seen: np.ndarray = field(default=None, repr=False)  # (m, poses) any pair sees
    timings: dict = field(default_factory=dict)
    rays: int = 0
    tracked: object = None  # starforge.props.tracked.Optimized for the tracked objective
    warnings: tuple[str, ...] = ()
    spacing_m: float = 0.0
    avoid: tuple = ()

    @property
    def marker_points(self) -> np.ndarray:
        return self.sites.points[list(self.marker_sites)]

    @property
    def marker_normals(self) -> np.ndarray:
        return self.sites.normals[list(self.marker_sites)]

    @property
    def marker_visibility(self) -> np.ndarray:
        return self.site_visibility[list(self.marker_sites)]


def _tick(timings: dict, key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = round(now - t0, 4)
    return now


def prepare(prop, spec: PlaceSpec, rng: np.random.Generator, progress=None, timings=None):
    """Sites (with constrained areas removed), rig, poses and the visibility table."""
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.sites import forbidden_sites, sample_sites
    from starforge.props.visibility import compute_table

    timings = {} if timings is None else timings
    t = time.perf_counter()
    rig = load_rig(spec.rig)
    sites = sample_sites(prop.mesh, spec.sites, rng)
    if spec.constraints.empty:
        bad = np.zeros(len(sites), dtype=bool)
    else:
        bad = forbidden_sites(sites, spec.constraints, prop.face_origin, prop.source_faces)
    kept = sites.subset(~bad)
    if len(kept) == 0:
        raise StarforgeError(f"every one of the {len(sites)} candidate sites lies in a constrained area")
    if len(kept) < spec.costs.min_markers:
        raise StarforgeError(
            f"only {len(kept)} candidate sites are outside the constrained areas, "
            f"fewer than min_markers = {spec.costs.min_markers}"
        )
    t = _tick(timings, "sample_s", t)
    pivot = np.asarray(prop.mesh.bounds, dtype=float).mean(axis=0)
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    check_cost(prop, spec, rig, len(kept), len(poses))
    table = compute_table(
        prop.mesh,
        kept.points,
        kept.normals,
        rig,
        poses,
        spec.grazing_limit_deg,
        progress=progress,
        radius_m=spec.marker_diameter_m / 2,
        occlusion=spec.occlusion,
    )
    _tick(timings, "visibility_s", t)
    return kept, int(bad.sum()), rig, poses, table


def check_cost(prop, spec: PlaceSpec, rig, sites: int, poses: int) -> None:
    """Refuse, before the visibility table, work past the memory or time limit (one line)."""
    from starforge.budget import require_memory, require_time

    cams, pairs = len(rig.cameras), len(rig.pairs)
    what = f"a visibility table of {sites:,} sites x {poses:,} poses x {cams} cameras"
    advice = "lower --resolution, --orientations or --sites"
    batch = min(1_000_000, sites * cams * max(1, 1_000_000 // max(1, sites * cams)))
    require_memory(sites * poses * (pairs + 9) + batch * 200 + 50e6, what, advice)
    require_time(sites * poses * cams * 4e-7 + 1.0, what, advice)


def check_scale(prop, rig, marker_m: float) -> list[str]:
    """Refuse a prop whose size says it is in other units; warn when it does not fit the volume.

    A prop larger than twice the capture volume, or smaller than four markers, cannot be what was
    meant: the message names the ``--units`` that would make it a plausible size.
    """
    ext = float(np.max(prop.mesh.extents))
    vol = float(np.max(rig.volume.size))
    if ext > 2 * vol or ext < 4 * marker_m:
        from starforge.props.mesh import UNITS_TO_M

        here = UNITS_TO_M.get(prop.units, 1.0)
        fits = [u for u, f in UNITS_TO_M.items() if 4 * marker_m <= ext / here * f <= vol]
        # of the units that make it plausible, the one nearest a hand-held size (0.3 m)
        fits.sort(key=lambda u: abs(math.log(ext / here * UNITS_TO_M[u] / 0.3)))
        hint = f"; pass --units {fits[0]}" if fits else ""
        size = " x ".join(f"{e:.4g}" for e in prop.mesh.extents)
        raise StarforgeError(
            f"prop {prop.name} is {size} m read as {prop.units}: "
            + (f"larger than twice the capture volume ({vol:g} m)" if ext > 2 * vol
               else f"smaller than four markers ({4 * marker_m * 1000:g} mm)")
            + hint
        )
    if np.any(np.asarray(prop.mesh.extents) > np.asarray(rig.volume.size)):
        return [
            f"the prop ({' x '.join(f'{e:.3g}' for e in prop.mesh.extents)} m) does not fit inside the capture volume ({' x '.join(f'{e:g}' for e in rig.volume.size)} m)"
        ]
    return []


def place(prop, spec: PlaceSpec, seed: int = 0, progress=None, avoid=None) -> PlacementResult:
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
    """
    require(isinstance(seed, int) and seed >= 0, f"seed must be an integer >= 0, got {seed}")
    rng = np.random.default_rng(seed)
    timings: dict = dict(getattr(prop, "timings", {}) or {})
    vis_cb = (lambda d, n: progress("visibility", d, n)) if progress else None
    from starforge.props.rig import load_rig

    warnings = check_scale(prop, load_rig(spec.rig), spec.marker_diameter_m)
    sites, n_bad, rig, poses, table = prepare(prop, spec, rng, vis_cb, timings)
    if spec.objective == "tracked":
        return _place_tracked(
            prop, spec, seed, rng, sites, n_bad, rig, poses, table, timings, warnings, avoid, progress
        )
    v = table.site_visibility
    t = time.perf_counter()
    run_cb = (lambda d, n: progress("annealing", d, n)) if progress else None
    pose_seen = table.seen.any(axis=2)  # (s, p): some pair sees the site at the pose
    result = anneal(sites.points, v, spec.costs, spec.chain, rng, on_run=run_cb, site_pose_seen=pose_seen)
    t = _tick(timings, "optimize_s", t)
    chosen = tuple(int(s) for s in result.best.sites)
    seen_any = pose_seen[list(chosen)]
    cost = evaluate(sites.points[list(chosen)], v[list(chosen)], spec.costs, marker_pose_seen=seen_any)
    _tick(timings, "score_s", t)
    return PlacementResult(
        prop,
        spec,
        seed,
        rig,
        poses,
        sites,
        n_bad,
        v,
        chosen,
        cost,
        result,
        seen_any,
        timings,
        table.rays,
        warnings=tuple(warnings),
    )


def _place_tracked(
    prop, spec, seed, rng, sites, n_bad, rig, poses, table, timings, warnings, avoid, progress
):
    """The tracked objective (:mod:`starforge.props.tracked`) on a prepared table."""
    from starforge.props.optimizer import AnnealResult, ChainResult
    from starforge.props.tracked import Problem, optimize, spacing_m

    t = time.perf_counter()
    ts = spec.track
    r = ts.marker_mm / 2000.0
    centres = sites.points + r * sites.normals
    pose_seen = table.seen.any(axis=2)
    ext = np.sort(np.asarray(prop.mesh.extents))
    prob = Problem(
        centres,
        pose_seen,
        table.site_visibility,
        ts,
        spacing_m(ts.marker_mm, rig, ts.gap_px),
        max(ts.spread_fraction * float(ext[1]), 1e-4),
        None if avoid is None or not len(avoid) else np.asarray(avoid, float),
    )
    run_cb = (lambda d, n: progress("optimizing", d, n)) if progress else None
    opt = optimize(prob, rng, run_cb)
    t = _tick(timings, "optimize_s", t)
    chosen = opt.sites
    terms = opt.terms
    runs = tuple(
        ChainResult(
            c.sites,
            c.cost,
            c.iterations,
            c.history,
            c.history,
            np.full(len(c.history), len(c.sites), np.int16),
            {},
            {"all": c.accepted},
        )
        for c in opt.runs
    ) or (
        ChainResult(
            chosen,
            terms["total"],
            0,
            np.array([terms["total"]]),
            np.array([terms["total"]]),
            np.array([len(chosen)], np.int16),
        ),
    )
    ann = AnnealResult(min(runs, key=lambda c: c.cost), runs)
    cost = CostBreakdown(
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
    warnings = list(warnings)
    if terms["untracked"] > 0:
        warnings.append(
            f"{100 * terms['untracked']:.1f} % of the poses ({round(terms['untracked'] * len(poses))} of {len(poses)}) "
            "are not tracked (fewer than 3 markers seen, or in a line)"
        )
    if terms["close_pairs"]:
        warnings.append(
            f"{terms['close_pairs']} marker pair(s) closer than the spacing {prob.spacing * 1000:.1f} mm"
        )
    if terms["avoid_conflicts"]:
        warnings.append(
            f"{terms['avoid_conflicts']} marker triangle(s) within {ts.avoid_tolerance_mm:g} mm of another prop's"
        )
    _tick(timings, "score_s", t)
    res = PlacementResult(
        prop,
        spec,
        seed,
        rig,
        poses,
        sites,
        n_bad,
        table.site_visibility,
        chosen,
        cost,
        ann,
        pose_seen[list(chosen)],
        timings,
        table.rays,
        opt,
        tuple(warnings),
        prob.spacing,
    )
    # marker positions reported at the surface (where they are stuck); centres = + radius * normal
    return res


#: a scored marker may lie this far from the prop's surface (m), or 1 % of the prop's size if more
OFF_SURFACE_M = 0.002


def score_layout(prop, points: np.ndarray, normals: np.ndarray | None, spec: PlaceSpec, seed: int = 0):
    """Score a given layout (the paper's expert comparison): ``(CostBreakdown, per-marker
    visibility, extra)`` where ``extra`` holds the tracked objective's terms for that objective.

    Markers are surface points (as markers.csv writes them); one farther from the surface than
    :data:`OFF_SURFACE_M` (or 1 % of the prop's size) is refused.  Normals missing or zero are
    taken from the nearest surface point.
    """
    from starforge.props.rig import load_rig, make_poses
    from starforge.props.visibility import compute_table

    pts = np.asarray(points, dtype=float)
    require(len(pts) >= 1, "the layout has no markers")
    closest, dist, tri = prop.mesh.nearest.on_surface(pts)
    limit = max(OFF_SURFACE_M, 0.01 * float(np.linalg.norm(prop.mesh.extents)))
    far = np.flatnonzero(dist > limit)
    if len(far):
        k = int(far[np.argmax(dist[far])])
        raise StarforgeError(
            f"marker {k} lies {dist[k] * 1000:.1f} mm from the prop's surface (at most {limit * 1000:.1f} mm): "
            f"{len(far)} of {len(pts)} markers are off the prop (wrong --units, or another prop's file?)"
        )
    nrm = np.zeros_like(pts) if normals is None else np.asarray(normals, dtype=float)
    length = np.linalg.norm(nrm, axis=1)
    missing = length < 1e-12
    if missing.any():
        nrm[missing] = prop.mesh.face_normals[tri[missing]]
        length = np.linalg.norm(nrm, axis=1)
    nrm = nrm / length[:, None]
    rng = np.random.default_rng(seed)
    rig = load_rig(spec.rig)
    pivot = np.asarray(prop.mesh.bounds, dtype=float).mean(axis=0)
    poses = make_poses(rig.volume, spec.resolution, spec.orientations, pivot, rng)
    check_cost(prop, spec, rig, len(pts), len(poses))
    table = compute_table(
        prop.mesh,
        pts,
        nrm,
        rig,
        poses,
        spec.grazing_limit_deg,
        radius_m=spec.marker_diameter_m / 2,
        occlusion=spec.occlusion,
    )
    v = table.site_visibility
    if spec.objective == "tracked":
        from starforge.props.tracked import Problem, spacing_m

        ts = spec.track
        prob = Problem(
            pts + ts.marker_mm / 2000.0 * nrm,
            table.seen.any(axis=2),
            v,
            ts,
            spacing_m(ts.marker_mm, rig, ts.gap_px),
            max(ts.spread_fraction * float(np.sort(prop.mesh.extents)[1]), 1e-4),
        )
        t = prob.terms(list(range(len(pts))))
        cost = CostBreakdown(
            t["total"],
            1 - t["mean_visibility"],
            0.0,
            float(t["close_pairs"]),
            0.0,
            0.0,
            t["mean_visibility"],
            t["close_pairs"],
            False,
            t["near_symmetry_margin_m"],
            len(pts),
            t["untracked"],
        )
        extra = {"objective": "tracked", "tracked_fraction": 1 - t["untracked"], "spacing_m": prob.spacing}
        return cost, v, extra
    return evaluate(pts, v, spec.costs, marker_pose_seen=table.seen.any(axis=2)), v, {"objective": "paper"}


# ----------------------------------------------------------------------------- files


def _r(x, nd=9):
    """Round floats for stable, readable JSON."""
    if isinstance(x, np.ndarray):
        return (np.round(x.astype(float), nd) + 0.0).tolist()  # + 0.0 turns -0.0 into 0.0
    return round(float(x), nd) + 0.0


def _downsample(arr: np.ndarray, n: int = HISTORY_POINTS) -> tuple[list[int], np.ndarray]:
    if len(arr) <= n:
        idx = np.arange(len(arr))
    else:
        idx = np.unique(np.linspace(0, len(arr) - 1, n).round().astype(int))
    return idx.tolist(), arr[idx]


def placement_json(res: PlacementResult) -> dict:
    """The ``placement.json`` document (plain JSON data; keys fixed by format version 1)."""
    from starforge.spec import to_mapping

    prop = res.prop
    spec = res.spec
    runs = res.anneal.runs
    costs = res.anneal.costs
    history = {
        "restarts": len(runs),
        "best_run": int(np.argmin(costs)),
        "run_costs": _r(costs),
        "cost_mean": _r(costs.mean()),
        "cost_sd": _r(costs.std(ddof=1)) if len(costs) > 1 else 0.0,
        "runs": [],
    }
    for r in runs:
        it, c = _downsample(r.history_cost)
        history["runs"].append(
            {
                "iterations": r.iterations,
                "cost": _r(r.cost),
                "markers": len(r.sites),
                "proposed": r.proposed,
                "accepted": r.accepted,
                "trace": {
                    "iteration": it,
                    "cost": _r(c),
                    "best": _r(r.history_best[it]),
                    "markers": r.history_n[it].astype(int).tolist(),
                    "temperature": [_r(spec.chain.temperature(i)) for i in it],
                },
            }
        )
    seen3 = (res.marker_pose_seen.sum(axis=0) >= 3) if len(res.marker_sites) else np.zeros(0, bool)
    markers = []
    for i, s in enumerate(res.marker_sites):
        markers.append(
            {
                "id": i,
                "position": _r(res.sites.points[s]),
                "normal": _r(res.sites.normals[s]),
                "site": int(s),
                "visibility": _r(res.site_visibility[s]),
                "seen_fraction": _r(res.marker_pose_seen[i].mean()),
            }
        )
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "prop": {
            "name": prop.name,
            "units": prop.units,
            "source": prop.source,
            "faces": int(len(prop.mesh.faces)),
            "extents_m": _r(np.asarray(prop.mesh.extents)),
            "bounds_m": _r(np.asarray(prop.mesh.bounds)),
            "watertight": bool(prop.mesh.is_watertight),
            "repairs": list(prop.notes),
        },
        "settings": to_mapping(spec),
        "seed": res.seed,
        "rig": res.rig.to_json(),
        "poses": {
            "count": len(res.poses),
            "resolution": spec.resolution,
            "orientations": spec.orientations,
            **res.poses.to_json(),
        },
        "sites": {
            "sampled": len(res.sites) + res.forbidden,
            "forbidden": res.forbidden,
            "usable": len(res.sites),
            "poisson_radius_m": _r(res.sites.radius_m),
        },
        "markers": markers,
        "marker_diameter_m": spec.marker_diameter_m,
        "cost": {
            **{k: (_r(v) if isinstance(v, float) else v) for k, v in res.cost.to_json().items()},
            "weights": {
                "visibility": spec.costs.w_visibility,
                "count": spec.costs.w_count,
                "overlap": spec.costs.w_overlap,
                "symmetry": spec.costs.w_symmetry,
                "near_symmetry": spec.costs.w_near_symmetry,
            },
        },
        "coverage": {
            "poses_with_3_markers_seen": _r(seen3.mean()) if len(seen3) else 0.0,
            "min_markers_seen": int(res.marker_pose_seen.sum(axis=0).min()) if len(seen3) else 0,
        },
        "history": history,
        "timings": {
            **res.timings,
            "rays": res.rays,
            **(res.tracked.seconds if res.tracked is not None else {}),
        },
        "objective": spec.objective,
        "warnings": list(res.warnings),
    }
    if res.tracked is None:
        from starforge.props.costs import lower_bound

        lb, lb_n = lower_bound(res.site_visibility, spec.costs)
        doc["cost"]["lower_bound"] = _r(lb)
        doc["cost"]["lower_bound_markers"] = lb_n
        doc["cost"]["lower_bound_note"] = (
            "no layout of these sites can cost less: the visibility term is at least its distance from the "
            "range of means of n sites, the count term is exact, the others are >= 0"
        )
    if res.tracked is not None:
        t = res.tracked.terms
        doc["tracked"] = {
            "definition": (
                f"a pose is tracked when >= 3 markers are each seen by a camera pair and they are not in a line "
                f"(spread across their best-fit line at least that of a triangle {spec.track.min_height_mm:g} mm high)"
            ),
            "tracked_fraction": _r(1.0 - t["untracked"]),
            "mean_visibility": _r(t["mean_visibility"]),
            "spread_m": _r(t["spread_m"]),
            "near_symmetry_margin_m": None
            if math.isinf(t["near_symmetry_margin_m"])
            else _r(t["near_symmetry_margin_m"]),
            "close_pairs": t["close_pairs"],
            "spacing_m": _r(res.spacing_m),
            "avoid_conflicts": t["avoid_conflicts"],
            "cost": _r(t["total"]),
            "baselines": {
                "greedy_local_search": _r(res.tracked.baselines["greedy_local_search"]["cost"]),
                "best_of_random": None
                if res.tracked.baselines["best_of_random"]["cost"] is None
                else _r(res.tracked.baselines["best_of_random"]["cost"]),
                "random_layouts": res.tracked.baselines["best_of_random"]["layouts"],
                "median_random": None
                if res.tracked.baselines["best_of_random"]["median_cost"] is None
                else _r(res.tracked.baselines["best_of_random"]["median_cost"]),
                "chains": [
                    {k: (_r(v) if isinstance(v, float) else v) for k, v in c.items()}
                    for c in res.tracked.baselines["chains"]
                ],
            },
            "marker_centres_m": _r(res.marker_points + spec.track.marker_mm / 2000.0 * res.marker_normals),
        }
    return doc


def markers_csv(points: np.ndarray, normals: np.ndarray) -> str:
    """``id,x_m,y_m,z_m,nx,ny,nz``, one marker per row."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for i, (p, n) in enumerate(zip(points, normals, strict=True)):
        w.writerow(
            [i, *(f"{v + 0.0:.9f}" for v in np.round(p, 9)), *(f"{v + 0.0:.9f}" for v in np.round(n, 9))]
        )
    return buf.getvalue()


def read_markers_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Marker positions (m) and normals (None when the columns are absent) from a markers CSV."""
    from starforge.io import check_input_file

    path = check_input_file(Path(path), "markers file")
    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise StarforgeError(f"markers file {path} is not a readable CSV: {exc}") from None
    if not rows:
        raise StarforgeError(f"markers file {path} has no markers")
    fields = set(rows[0])
    if not {"x_m", "y_m", "z_m"} <= fields:
        raise StarforgeError(f"markers file {path} needs columns x_m,y_m,z_m (header {','.join(CSV_HEADER)})")
    try:
        pts = np.array([[float(r["x_m"]), float(r["y_m"]), float(r["z_m"])] for r in rows])
        nrm = None
        if {"nx", "ny", "nz"} <= fields:
            nrm = np.array([[float(r["nx"] or 0), float(r["ny"] or 0), float(r["nz"] or 0)] for r in rows])
    except (TypeError, ValueError) as exc:
        raise StarforgeError(f"markers file {path} has a non-numeric value: {exc}") from None
    if not np.all(np.isfinite(pts)):
        raise StarforgeError(f"markers file {path} has non-finite coordinates")
    return pts, nrm


def marker_mesh(prop_mesh, points, normals, diameter_m: float, fmt: str = "glb") -> bytes:
    """The prop with a sphere per marker (resting on the surface along its normal), as GLB or STL bytes."""
    import trimesh

    r = diameter_m / 2.0
    spheres = []
    for p, n in zip(points, normals, strict=True):
        s = trimesh.creation.icosphere(subdivisions=2, radius=r)
        s.apply_translation(np.asarray(p) + r * np.asarray(n))
        spheres.append(s)
    if fmt == "stl":
        return trimesh.util.concatenate([prop_mesh, *spheres]).export(file_type="stl")
    body = prop_mesh.copy()
    body.visual.face_colors = [200, 200, 200, 255]
    scene = trimesh.Scene()
    scene.add_geometry(body, geom_name="prop")
    if spheres:
        marks = trimesh.util.concatenate(spheres)
        marks.visual.face_colors = [230, 40, 40, 255]
        scene.add_geometry(marks, geom_name="markers")
    return scene.export(file_type="glb")


def write_outputs(res: PlacementResult, folder: Path, render: bool = True, renderer=None) -> list[str]:
    """Write every output of a placement into ``folder`` (a staging folder); return the file names.

    ``renderer``: a started :class:`starforge.render.props.BackgroundRenderer` to draw the
    pictures in (default: drawn here when ``render``).
    """
    from starforge.io import atomic_write_bytes, atomic_write_json, atomic_write_text

    t = time.perf_counter()
    folder = Path(folder)
    if render and renderer is None:
        from starforge.render.props import BackgroundRenderer

        renderer = BackgroundRenderer(enabled=False)
    if render:
        renderer.submit(res, folder)
    names = []
    atomic_write_text(folder / "markers.csv", markers_csv(res.marker_points, res.marker_normals))
    names.append("markers.csv")
    fmt = res.spec.mesh_format
    mesh_name = f"prop_markers.{fmt}"
    atomic_write_bytes(
        folder / mesh_name,
        marker_mesh(res.prop.mesh, res.marker_points, res.marker_normals, res.spec.marker_diameter_m, fmt),
    )
    names.append(mesh_name)
    if render:
        names += renderer.wait()
    res.timings["write_s"] = round(time.perf_counter() - t, 4)
    doc = placement_json(res)
    atomic_write_json(folder / "placement.json", doc)
    names.insert(0, "placement.json")
    return names


@dataclass(frozen=True)
class Placement:
    """A ``placement.json`` read back (:func:`load_placement`)."""

    path: Path
    data: dict = field(repr=False)
    positions_m: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)
    sites: tuple[int, ...] = ()
    visibility: np.ndarray = field(default=None, repr=False)
    marker_diameter_m: float = 0.004
    seed: int = 0

    @property
    def prop_name(self) -> str:
        return self.data["prop"]["name"]

    @property
    def total_cost(self) -> float:
        return float(self.data["cost"]["total"])


def load_placement(path: str | Path) -> Placement:
    """Read ``placement.json`` (or the folder holding it); StarforgeError when missing or not a placement."""
    from starforge.io import read_json

    path = Path(path)
    if path.is_dir():
        path = path / "placement.json"
    data = read_json(path, "placement file")
    if data.get("format") != FORMAT:
        raise StarforgeError(f"{path} is not a starforge placement (format {data.get('format')!r})")
    if data.get("version") != VERSION:
        raise StarforgeError(
            f"{path}: unsupported placement version {data.get('version')!r}, expected {VERSION}"
        )
    missing = [
        k
        for k in (
            "prop",
            "settings",
            "seed",
            "rig",
            "poses",
            "markers",
            "marker_diameter_m",
            "cost",
            "history",
            "timings",
        )
        if k not in data
    ]
    if missing:
        raise StarforgeError(f"{path} lacks {', '.join(missing)}")
    try:
        m = data["markers"]
        pos = np.array([x["position"] for x in m], dtype=float).reshape(-1, 3)
        nrm = np.array([x["normal"] for x in m], dtype=float).reshape(-1, 3)
        sites = tuple(int(x["site"]) for x in m)
        vis = np.array([x["visibility"] for x in m], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise StarforgeError(f"{path} has a malformed marker entry: {exc}") from None
    return Placement(path, data, pos, nrm, sites, vis, float(data["marker_diameter_m"]), int(data["seed"]))


def summary_lines(res: PlacementResult) -> list[str]:
    """A few lines for the terminal."""
    c = res.cost
    costs = res.anneal.costs
    sd = costs.std(ddof=1) if len(costs) > 1 else 0.0
    lines = [
        f"prop {res.prop.name}: {len(res.prop.mesh.faces)} faces, extents "
        f"{' x '.join(f'{e:.3f}' for e in res.prop.mesh.extents)} m",
    ]
    lines += [f"  repair: {n}" for n in res.prop.notes]
    lines.append(f"sites: {len(res.sites)} usable ({res.forbidden} in constrained areas removed)")
    lines.append(f"poses: {len(res.poses)}, camera pairs: {len(res.rig.pairs)}, rays cast: {res.rays}")
    if res.tracked is not None:
        t, b = res.tracked.terms, res.tracked.baselines
        lines.append(
            f"markers: {t['markers']} ({res.spec.track.marker_mm:g} mm, spacing {res.spacing_m * 1000:.1f} mm), "
            f"tracked at {100 * (1 - t['untracked']):.1f} % of the poses, mean visibility {t['mean_visibility']:.3f}"
        )
        rnd = b["best_of_random"]["cost"]
        lines.append(
            f"cost {t['total']:.4f}; greedy + local search {b['greedy_local_search']['cost']:.4f}"
            + (f", best of {b['best_of_random']['layouts']} random {rnd:.4f}" if rnd is not None else "")
        )
        if not math.isinf(t["near_symmetry_margin_m"]):
            lines.append(f"near-symmetry margin: {t['near_symmetry_margin_m'] * 1000:.1f} mm")
        return lines
    lines.append(
        f"markers: {c.markers}, cost {c.total:.4f} (visibility {c.visibility:.4f}, count {c.count:.4f}, "
        f"overlap {c.overlap:.4f}, symmetry {c.symmetry:.0f}), mean visibility {c.mean_visibility:.3f}"
    )
    from starforge.props.costs import lower_bound

    lb, lb_n = lower_bound(res.site_visibility, res.spec.costs)
    lines.append(f"no layout of these sites costs less than {lb:.4f} ({lb_n} most visible sites)")
    if len(costs) > 1:
        lines.append(f"restarts: {len(costs)}, cost mean {costs.mean():.4f} SD {sd:.4f}")
    if not math.isinf(c.margin_m):
        lines.append(f"near-symmetry margin: {c.margin_m * 1000:.1f} mm")
    return lines
