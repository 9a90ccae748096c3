"""placement.json and the files beside it: written from a :class:`PlacementResult`, read back.

``placement.json`` is the source of truth (read back with :func:`load_placement`); the CSV,
the mesh and the pictures are derived from the same result.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.distinct import subset_margin

if TYPE_CHECKING:
    from starforge.props.result import PlacementResult

FORMAT = "starforge.placement"
VERSION = 1
CSV_HEADER = ("id", "x_m", "y_m", "z_m", "nx", "ny", "nz")
HISTORY_POINTS = 400



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
    from starforge.props.guide import caliper_pairs

    centres = res.centres()
    features, marks = res.rigging
    rep = res.seat_report
    rods = res.marker_rods_mm
    markers = []
    for i, s in enumerate(res.marker_sites):
        edge = float(rep.edge_m[s])
        clamp = {"clamp_rod_mm": _r(float(rods[i]), 3)} if rods[i] > 0 else {}
        markers.append(
            {
                "id": i,
                "number": i + 1,
                "position": _r(res.sites.points[s]),
                "normal": _r(res.sites.normals[s]),
                "centre": _r(centres[i]),
                "site": int(s),
                "visibility": _r(res.site_visibility[s]),
                "seen_fraction": _r(res.marker_pose_seen[i].mean()),
                "seen_all_cameras": _r((np.bitwise_count(res.marker_masks[i]) >= 2).mean()),
                "base_contact": _r(rep.contact[s], 4),
                "edge_distance_mm": None if not math.isfinite(edge) else _r(edge * 1000.0, 3),
                "seat_margin_mm": _r(float(rep.margin_m[s]) * 1000.0, 3),
                **clamp,
                "landmark": marks[i],
            }
        )
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "prop": {
            "name": prop.name,
            "units": prop.units,
            "source": prop.source,
            "faces": int(len(prop.faces)),
            "extents_m": _r(prop.extents_m),
            "bounds_m": _r(prop.bounds_m),
            "watertight": prop.watertight,
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
            "sampled": len(res.sites) + sum(res.removed.values()),
            "forbidden": res.forbidden,
            "under_hand": res.removed.get("under_hand", 0),
            "unseated": res.removed.get("unseated", 0),
            "usable": len(res.sites),
            "poisson_radius_m": _r(res.sites.radius_m),
        },
        "markers": markers,
        "marker_diameter_m": spec.marker_diameter_m,
        "seat": {
            **res.seat.to_json(),
            **{k: v for k, v in to_mapping(spec.seat).items()},
            "sites_removed": dict(res.removed),
        },
        "guide": {
            "landmarks": features,
            "caliper": caliper_pairs(centres, res.seat.ball_mm, spec.seat.placement_error_mm),
            "placement_error_mm": spec.seat.placement_error_mm,
        },
        "hand": [c.to_json() for c in res.capsules],
        "grips": {
            "held_part": None if res.part is None else res.part.to_json(),
            "grips": [g.to_json() for g in res.grips],
            "assignment": "every pose held in one grip, "
            + ("the poses shared in proportion to the grips' weights" if len({g.weight for g in res.grips}) > 1 else "the same number of poses each")
            + ", in a random order from the seed",
        },
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
            **distinct_report(res),
            "cost": _r(t["total"]),
            "scenarios": {
                "poses": len(res.poses),
                "cameras_lost": int(round(spec.track.cameras_lost * len(res.rig.cameras))),
                "cameras": len(res.rig.cameras),
                "count": int(res.marker_pose_seen.shape[1]),
            },
            "baselines": {
                "greedy_local_search": _r(res.tracked.baselines["greedy_local_search"]["cost"]),
                "greedy_local_search_sites": res.tracked.baselines["greedy_local_search"]["sites"],
                "best_of_random": None
                if res.tracked.baselines["best_of_random"]["cost"] is None
                else _r(res.tracked.baselines["best_of_random"]["cost"]),
                "best_of_random_sites": res.tracked.baselines["best_of_random"]["sites"],
                "selection": {
                    "validated": res.tracked.baselines["validated"],
                    "note": "the candidates (the baselines as they are, the best random layout after the swap "
                    "search, each chain's best after it) ranked by their tracked fraction on a held-out sample "
                    f"({spec.track.validation_poses} random poses x their own camera losses, a seed of their own, "
                    "not the evaluation's), then by their cost on the searched and held-out scenarios together; "
                    "the first listed wins a tie",
                    "winner": res.tracked.baselines["selection"]["winner"],
                    "polish": res.tracked.baselines["selection"].get("polish"),
                    "candidates": {
                        name: {k: (_r(v) if isinstance(v, float) else v) for k, v in c.items()}
                        for name, c in res.tracked.baselines["selection"]["candidates"].items()
                    },
                    "default": _r(res.tracked.baselines["selection_cost"]),
                    "greedy_local_search": _r(res.tracked.baselines["greedy_local_search"]["selection_cost"]),
                    "best_of_random": None
                    if res.tracked.baselines["best_of_random"]["selection_cost"] is None
                    else _r(res.tracked.baselines["best_of_random"]["selection_cost"]),
                },
                "random_layouts": res.tracked.baselines["best_of_random"]["layouts"],
                "median_random": None
                if res.tracked.baselines["best_of_random"]["median_cost"] is None
                else _r(res.tracked.baselines["best_of_random"]["median_cost"]),
                **_search_summary(res.tracked),
                "chains": [
                    {k: (_r(v) if isinstance(v, float) else v) for k, v in c.items()}
                    for c in res.tracked.baselines["chains"]
                ],
            },
            "marker_centres_m": _r(centres),
            "below_target": {k: (_r(v) if isinstance(v, float) else v) for k, v in res.shortfall.items()} or None,
            "layouts": {
                name: {"sites": list(sites), "positions": _r(res.sites.points[list(sites)]), "centres": _r(res.centres(sites))}
                for name, sites in (
                    ("greedy_local_search", res.tracked.baselines["greedy_local_search"]["sites"]),
                    ("best_of_random", res.tracked.baselines["best_of_random"]["sites"]),
                )
                if sites is not None
            },
        }
    if res.evaluation:
        ev = res.evaluation
        doc["evaluation"] = {
            "definition": (
                f"{ev['_poses']} fresh uniformly random rotations at random positions of the volume (not the "
                f"optimizer's poses), {ev['_cameras_lost']} of {len(res.rig.cameras)} cameras lost at random in each, "
                "the hand at the grip; tracked: >= 3 markers each seen by 2 surviving cameras, not in a line"
            ),
            **{
                k: {kk: vv if isinstance(vv, int) else _r(vv) for kk, vv in v.items()}  # pose counts stay integers
                for k, v in ev.items()
                if not k.startswith("_")
            },
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

    path = check_input_file(Path(path), "markers file", "csv")
    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise StarforgeError(
            f"markers file {path} is not a readable CSV ({exc}); save it as UTF-8 CSV with the header "
            f"{','.join(CSV_HEADER)}"
        ) from None
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
        raise StarforgeError(
            f"markers file {path} has non-finite coordinates (nan or inf); fix x_m,y_m,z_m (metres) of every marker"
        )
    return pts, nrm


#: segments round a marker's ball and its base in ``prop_markers``
MARKER_SEGMENTS = 24
#: the colours ``prop_markers.glb`` gives the prop and the markers (RGBA, 0-1)
PROP_RGBA = (0.78, 0.78, 0.78, 1.0)
MARKER_RGBA = (0.9, 0.16, 0.16, 1.0)


def marker_parts(points, normals, seat, rods_mm=None, rod_axes=None) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, faces)`` of every marker as it sits: a ball ``seat.centre_height_mm`` above
    its site along the normal, on a 1 mm disc of the base's diameter or its stand-off's post
    (manifold3d's sphere and cylinder, :data:`MARKER_SEGMENTS` round), and round a rod
    ``rods_mm[i]`` across (axis ``rod_axes[i]``), the clamp's ring, m."""
    from manifold3d import Manifold

    from starforge.geometry.frames import perpendicular_basis
    from starforge.props.clamp import ring_frame

    pts = np.asarray(points, float).reshape(-1, 3)
    rods = np.zeros(len(pts)) if rods_mm is None else np.asarray(rods_mm, float)
    axes = np.zeros((len(pts), 3)) if rod_axes is None else np.asarray(rod_axes, float)
    parts = []
    for p, n, d, t in zip(pts, np.asarray(normals, float).reshape(-1, 3), rods, axes, strict=True):
        n = n / np.linalg.norm(n)
        parts.append(Manifold.sphere(seat.ball_radius_m, MARKER_SEGMENTS).translate(p + seat.centre_height_m * n))
        if seat.base_mm > 0:  # the base pad, or the stand-off's post
            turn = np.column_stack([*perpendicular_basis(n), n, p])  # right-handed: a turn, then the site
            r = seat.base_radius_m
            parts.append(Manifold.cylinder(max(0.001, seat.standoff_m), r, r, MARKER_SEGMENTS).transform(turn))
        if d > 0:  # the clamp's ring round the rod, as wide as the post
            frame, bore, outside = ring_frame(p, n, d, t)
            w = seat.base_radius_m
            ring = Manifold.cylinder(2 * w, outside, outside, MARKER_SEGMENTS, True)
            ring -= Manifold.cylinder(3 * w, bore, bore, MARKER_SEGMENTS, True)
            parts.append(ring.transform(frame[:3]))
    vertices, faces, start = [], [], 0
    for part in parts:
        m = part.to_mesh()
        v = np.asarray(m.vert_properties, dtype=float)[:, :3]
        vertices.append(v)
        faces.append(np.asarray(m.tri_verts, dtype=np.int64) + start)
        start += len(v)
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(vertices), np.vstack(faces)


def marker_mesh(prop, points, normals, seat, fmt: str = "glb", rods_mm=None, rod_axes=None) -> bytes:
    """The prop (a :class:`~starforge.props.mesh.PropMesh`) with every marker as it sits
    (:func:`marker_parts`), as GLB (the prop grey, the markers red) or STL bytes, m."""
    from starforge.meshfiles import glb_bytes, stl_bytes

    mv, mf = marker_parts(points, normals, seat, rods_mm, rod_axes)
    if fmt == "stl":
        return stl_bytes(np.vstack([prop.vertices, mv]), np.vstack([prop.faces, mf + len(prop.vertices)]))
    return glb_bytes([("prop", prop.vertices, prop.faces, PROP_RGBA), ("markers", mv, mf, MARKER_RGBA)])


def write_outputs(res: PlacementResult, folder: Path, render: bool = True, renderer=None, bases_stl: bool = False) -> list[str]:
    """Write every output of a placement into ``folder`` (a staging folder); return the file names.

    ``renderer``: a started :class:`starforge.render.props.BackgroundRenderer` to draw the
    pictures in (required when ``render``; ``BackgroundRenderer(enabled=False)`` draws in this process).  ``bases_stl``: also the prop with a pad
    under every marker (:func:`starforge.props.guide.bases_mesh`) as ``prop_bases.stl``.
    """
    from starforge.io import atomic_write_bytes, atomic_write_json, atomic_write_text

    t = time.perf_counter()
    folder = Path(folder)
    if render and renderer is None:
        raise ValueError("write_outputs(render=True) needs a renderer (starforge.render.props.BackgroundRenderer)")
    if render and not renderer.submitted:  # the CLI submits as soon as the layout is chosen
        renderer.submit(res, folder)
    names = []
    atomic_write_text(folder / "markers.csv", markers_csv(res.marker_points, res.marker_normals))
    names.append("markers.csv")
    fmt = res.spec.mesh_format
    mesh_name = f"prop_markers.{fmt}"
    atomic_write_bytes(
        folder / mesh_name,
        marker_mesh(res.prop, res.marker_points, res.marker_normals, res.seat, fmt, res.marker_rods_mm, res.marker_rod_axes),
    )
    names.append(mesh_name)
    if res.seat.standoff_mm > 0:
        from starforge.props.standoff import standoff_stl

        atomic_write_bytes(folder / "standoff.stl", standoff_stl(res.seat))
        names.append("standoff.stl")
        rods = res.marker_rods_mm
        if (rods > 0).any():
            from starforge.props.standoff import clamps_solid, solid_stl

            atomic_write_bytes(folder / "clamps.stl", solid_stl(clamps_solid(res.seat, rods[rods > 0])))
            names.append("clamps.stl")
    if bases_stl:
        from starforge.props.guide import bases_mesh

        base = res.seat.base_mm or res.seat.ball_mm
        atomic_write_bytes(
            folder / "prop_bases.stl",
            bases_mesh(res.prop.mesh, res.marker_points, res.marker_normals, base).export(file_type="stl"),
        )
        names.append("prop_bases.stl")
    # the document is made while the pictures are drawn; only its write time waits for them
    res.timings["write_s"] = 0.0
    doc = placement_json(res)
    if render:
        names += renderer.wait()
    res.timings["write_s"] = doc["timings"]["write_s"] = round(time.perf_counter() - t, 4)
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
        f"prop {res.prop.name}: {len(res.prop.faces)} faces, extents "
        f"{' x '.join(f'{e:.3f}' for e in res.prop.extents_m)} m",
    ]
    lines += [f"  repair: {n}" for n in res.prop.notes]
    rm = res.removed
    lines.append(
        f"sites: {len(res.sites)} usable of {len(res.sites) + sum(rm.values())} ({rm.get('constrained', 0)} constrained, "
        f"{rm.get('under_hand', 0)} under the hand, {rm.get('unseated', 0)} where a {res.seat.name} base does not seat)"
    )
    lines.append(f"poses: {len(res.poses)}, cameras: {len(res.rig.cameras)}, rays cast: {res.rays}")
    lines += grip_lines(res.part, res.grips)
    if res.tracked is not None:
        t, b = res.tracked.terms, res.tracked.baselines
        lines.append(
            f"markers: {t['markers']} ({res.seat.name}, spacing {res.spacing_m * 1000:.1f} mm), tracked in "
            f"{100 * (1 - t['untracked']):.1f} % of {res.marker_pose_seen.shape[1]} scenarios with "
            f"{round(res.spec.track.cameras_lost * len(res.rig.cameras))} cameras lost, mean visibility {t['mean_visibility']:.3f}"
        )
        rnd = b["best_of_random"]["cost"]
        lines.append(
            f"cost {t['total']:.4f}; greedy + local search {b['greedy_local_search']['cost']:.4f}"
            + (f", best of {b['best_of_random']['layouts']} random {rnd:.4f}" if rnd is not None else "")
        )
        why = ranking_note(b)
        if why:
            lines.append(why)
        ev = res.evaluation
        if ev:
            parts = [f"{k.replace('_', ' ')} {100 * v['tracked']:.1f} %" for k, v in ev.items() if not k.startswith("_")]
            lines.append(
                f"fresh poses ({ev['_poses']}, {ev['_cameras_lost']} cameras lost, the hand): tracked " + ", ".join(parts)
            )
        idx = list(res.marker_sites)
        foot = res.marker_rods_mm <= 0  # a clamp's post stands on its ring, not on the surface
        contact = np.asarray(res.seat_report.contact)[idx][foot]
        edge = np.asarray(res.seat_report.edge_m)[idx][foot]
        margin = np.asarray(res.seat_report.margin_m)[idx] * 1000.0
        rules = res.spec.seat
        clamped = ", ".join(str(i + 1) for i in np.flatnonzero(~foot))
        lines.append(
            "seats: "
            + (
                f"base contact >= {100 * contact.min():.0f} %, sharp edges >= "
                + (f"{1000 * edge.min():.1f} mm" if np.isfinite(edge.min()) else "none")
                + f" away (base radius {res.seat.base_mm / 2:g} mm); "
                if foot.any()
                else ""
            )
            + f"margin for a {rules.placement_error_mm:g} mm placement "
            f"error: {', '.join(f'{m:.1f}' for m in margin)} mm (measured up to {rules.margin_cap_mm:g}"
            + (f"; along the rod for {clamped}, on clamps)" if clamped else ")")
        )
        if res.seat.standoff_mm > 0:
            from starforge.props.standoff import standoff_words

            lines.append(f"stand-offs: {standoff_words(res.seat, res.marker_rods_mm)}")
        if not math.isinf(t["near_symmetry_margin_m"]):
            lines.append(symmetry_line(t["near_symmetry_margin_m"], res.spec.track.near_symmetry_target_mm))
        d = distinct_report(res)
        if d["self_margin_mm"] is not None:
            lines.append(
                f"self-margin: {d['self_margin_mm']:.2f} mm from any 3 markers, "
                + (f"{d['self_margin_4_mm']:.2f} mm from any 4" if d["self_margin_4_mm"] is not None else "no 4-marker subset")
                + f" (kept: {d['distinct_mm']:g} mm; {d['own_conflicts']} own triangle conflicts)"
            )
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


def distinct_report(res: PlacementResult) -> dict:
    """How far the layout lies from mistaking itself (:mod:`starforge.props.distinct`), mm: the
    tolerance its triangles keep (``distinct_mm``), the conflicts below it, and its self-margins
    from any 3 and any 4 of its markers (ball centres; None when it has too few markers)."""
    P = res.centres() * 1000.0
    m3, m4 = subset_margin(P, 3), subset_margin(P, 4)
    return {
        "distinct_mm": res.spec.track.avoid_tolerance_mm,
        "own_conflicts": int(res.tracked.terms.get("own_conflicts", 0)),
        "self_margin_mm": None if math.isinf(m3) else _r(m3, 6),
        "self_margin_4_mm": None if math.isinf(m4) else _r(m4, 6),
    }


def symmetry_line(margin_m: float, target_mm: float) -> str:
    """The near-symmetry margin; the search stops at its target, so a margin there is a floor."""
    if margin_m * 1000.0 >= target_mm - 1e-9:
        return f"near-symmetry margin: >= {target_mm:g} mm (the target; the search stops there)"
    return f"near-symmetry margin: {margin_m * 1000:.1f} mm (below the {target_mm:g} mm target)"


def ranking_note(baselines: dict) -> str:
    """Why the chosen layout costs more than a baseline printed beside it, or "" when it does not:
    the candidates are ranked by their tracked fraction on held-out poses first."""
    sel = baselines.get("selection", {})
    cands = sel.get("candidates", {})
    won = cands.get(sel.get("winner"))
    greedy = cands.get("greedy_local_search")
    if not won or not greedy or won["cost"] <= greedy["cost"] + 1e-12 or won["validation_tracked"] is None:
        return ""
    return (
        f"  the chosen layout costs more than greedy + local search on the searched scenarios but tracks "
        f"{100 * won['validation_tracked']:.2f} % of the held-out ones against {100 * greedy['validation_tracked']:.2f} % "
        "(layouts are ranked by held-out tracking first, then by cost)"
    )


def _search_summary(opt) -> dict:
    """:meth:`~starforge.props.tracked_optimizer.Optimized.search_summary` with its trace rounded for the JSON."""
    s = opt.search_summary()
    return {**s, "greedy_trace": _r(np.asarray(s["greedy_trace"], float))}


def grip_lines(part, grips) -> list[str]:
    """The grips the layout is scored under, grouped by hand and place (numbers as ``--grip N``
    takes them); wrist turns that every group shares are said once, in the first line."""
    from starforge.props.grips import grips_summary

    if not grips:
        return ["hand: none (--no-hand)"]
    groups = []  # (first, last, what, wrist turns)
    k = 0
    while k < len(grips):
        j = k
        base = grips[k].label.split(", wrist at")[0]
        while j < len(grips) and grips[j].label.split(", wrist at")[0] == base:
            j += 1
        wraps = ", ".join(f"{g.wrap_deg:g}" for g in grips[k:j]) if "wrist at" in grips[k].label else ""
        groups.append((k + 1, j, base, wraps))
        k = j
    shared = {w for *_, w in groups}
    common = shared.pop() if len(shared) == 1 and len(groups) > 1 else None
    head = f"hand: {grips_summary(part, grips)}; each pose is held in one of them"
    if common:
        head += f", the wrist at {common} deg around the part in turn"
    out = [head + " (--grip N pins grip N):"]

    def nums(a, b):
        return f"{a}" if a == b else f"{a}-{b}"

    i = 0
    while i < len(groups):
        a, b, base, wraps = groups[i]
        turns = f", wrist at {wraps} deg around the part" if wraps and not common else ""
        if i + 1 < len(groups) and base.startswith("right hand ") and groups[i + 1][2] == "left" + base[5:]:
            c, d, _, wraps2 = groups[i + 1]
            if wraps2 == wraps:  # the same place in either hand: one line
                out.append(f"  grip {nums(a, b)} right hand, {nums(c, d)} left hand: {base[11:]}{turns}")
                i += 2
                continue
        out.append(f"  grip {nums(a, b)}: {base}{turns}")
        i += 1
    return out
