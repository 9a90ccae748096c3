"""Rigid bodies measured from a recording: the clusters of labelled markers that keep their
distances, and each cluster's geometry and per-marker scatter.

Finding clusters: the distance of every pair of markers is taken over (a sample of) the frames
in which both are seen; a pair is rigid when that distance's standard deviation is at most
``rigid_mm``.  Complete-linkage clustering on those deviations gives groups in which every
pair is rigid (scipy's ``linkage(..., "complete")``, cut at ``rigid_mm``); groups of 3 or more
markers are bodies.  A user may instead name the bodies (``NAME=M1,M2,M3``).

Geometry: iterated median alignment.  Start from a frame that shows every marker of the body;
align every frame that shows at least 3 of them onto the current shape (weighted Kabsch,
:func:`starforge.geometry.rigid.kabsch`, unseen markers weigh 0) and take, per marker and axis,
the median of the aligned positions over frames; repeat.  Each round aligns at most
:data:`ALIGN_SAMPLE` frames, spread evenly over the recording.  The median ignores the frames where
a marker was mislabelled or swapped as long as they are fewer than half of them.  The shape is
returned centred on its centroid.  A marker's scatter is the RMS distance of its aligned
positions from the shape.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.rigid import kabsch
from starforge.tracking.bodies import MAX_MARKERS, MIN_SEPARATION_MM, SPREAD_MM, safe_name
from starforge.tracking.recording import Trajectories

#: a pair of markers is rigid when its distance varies by at most this (standard deviation), mm
RIGID_MM = 0.5
#: frames sampled to find clusters (distances of every pair in each)
CLUSTER_FRAMES = 1000
#: frames each alignment round aligns at most (evenly spread over the recording): the median of
#: 5000 frames of 0.2 mm noise is within about 0.005 mm of the median of all
ALIGN_SAMPLE = 5000
#: alignment rounds
ROUNDS = 3
#: a pair must be seen together in this share of the sampled frames to be judged at all
MIN_TOGETHER = 0.2


@dataclass(frozen=True)
class MeasuredBody:
    """One body measured from a recording.

    name : str
    labels : tuple of str               its markers' labels, in order
    points_mm : (k, 3) float, mm        the shape, centred on its centroid
    scatter_mm : (k,) float, mm         RMS distance of each marker's aligned positions from its place
    frames : int                        frames that showed at least 3 of its markers
    seen : (k,) float                   share of the recording's frames that show each marker
    """

    name: str
    labels: tuple[str, ...]
    points_mm: np.ndarray
    scatter_mm: np.ndarray
    frames: int
    seen: np.ndarray


def parse_body_option(text: str) -> tuple[str, list[str]]:
    """``NAME=M1,M2,M3`` -> (NAME, [M1, M2, M3]); StarforgeError naming ``--body``."""
    name, sep, rest = str(text).partition("=")
    labels = [x.strip() for x in rest.split(",") if x.strip()]
    if not sep or not name.strip() or len(labels) < 3:
        raise StarforgeError(f"--body needs NAME=M1,M2,M3 (3 or more marker labels), got {text!r}")
    if len(set(labels)) != len(labels):
        raise StarforgeError(f"--body {name.strip()} names a marker twice")
    return name.strip(), labels


def pair_deviation(P: np.ndarray, max_frames: int = CLUSTER_FRAMES):
    """For markers ``P`` (F, M, 3) mm (NaN unseen): each pair's distance standard deviation
    (M, M) mm and mean distance (M, M) mm over the sampled frames in which both are seen
    (NaN when they are seen together in fewer than :data:`MIN_TOGETHER` of them)."""
    F, M, _ = P.shape
    budget = max(50, int(4e7 // max(1, M * M)))  # about 320 MB of distances at most
    S = min(F, max_frames, budget)
    X = P[np.unique(np.linspace(0, F - 1, S).round().astype(int))]
    D = np.linalg.norm(X[:, :, None] - X[:, None], axis=3)
    together = np.isfinite(D).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pairs: judged below
        sd = np.nanstd(D, axis=0)
        med = np.nanmean(D, axis=0)
    low = together < max(2, MIN_TOGETHER * len(X))
    sd[low] = np.nan
    med[low] = np.nan
    return sd, med


def find_clusters(traj: Trajectories, rigid_mm: float = RIGID_MM) -> list[list[int]]:
    """Marker index groups (3 or more, every pair rigid) of ``traj``, in label order."""
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import squareform

    M = len(traj.labels)
    if M < 3:
        return []
    sd, med = pair_deviation(traj.points_mm)
    bad = ~np.isfinite(sd) | ~(med >= MIN_SEPARATION_MM) | ~(med <= SPREAD_MM[1])
    cost = np.where(bad, 1e6, sd)
    np.fill_diagonal(cost, 0.0)
    Z = linkage(squareform(cost, checks=False), method="complete")
    group = fcluster(Z, t=rigid_mm, criterion="distance")
    out = []
    for g in np.unique(group):
        idx = np.flatnonzero(group == g)
        if 3 <= len(idx):
            out.append(idx[:MAX_MARKERS].tolist())
    return sorted(out, key=lambda g: g[0])


def _cluster_name(labels: list[str], others: list[str], k: int) -> str:
    """The labels' common prefix before ``:`` or ``_`` (``Wand:M1`` -> ``Wand``) when no other
    marker of the recording shares it, else ``body<k>``."""
    for sep in (":", "_"):
        heads = {x.split(sep, 1)[0] for x in labels if sep in x}
        if len(heads) == 1 and all(sep in x for x in labels):
            head = heads.pop()
            if not any(x.split(sep, 1)[0] == head for x in others if sep in x):
                return safe_name(head)
    return f"body{k}"


def measure_shape(P: np.ndarray, rounds: int = ROUNDS):
    """Shape (k, 3) mm, scatter (k,) mm and frames used, of one body's markers ``P`` (F, k, 3)
    mm (NaN unseen); see the module docstring.  StarforgeError when no frame shows them all."""
    seen = np.isfinite(P).all(axis=2)
    use = np.flatnonzero(seen.sum(axis=1) >= 3)
    full = np.flatnonzero(seen.all(axis=1))
    if not len(full):
        raise StarforgeError("no frame shows all its markers")
    T = P[full[len(full) // 2]]
    T = T - T.mean(axis=0)
    idx = use if len(use) <= ALIGN_SAMPLE else use[np.linspace(0, len(use) - 1, ALIGN_SAMPLE).astype(int)]
    X, w = P[idx], seen[idx].astype(float)
    for _ in range(rounds):
        R, t = kabsch(np.broadcast_to(T, X.shape), X, w)  # template -> frame
        A = np.einsum("fki,fij->fkj", np.where(w[..., None] > 0, X, 0.0) - t[:, None], R)  # frame -> template
        A[w == 0] = np.nan
        T = np.nanmedian(A, axis=0)
        T = T - T.mean(axis=0)
    d2 = np.sum((A - T) ** 2, axis=2)
    scatter = np.sqrt(np.nanmean(d2, axis=0))
    return T, scatter, len(use)


def measure_bodies(traj: Trajectories, named=None, rigid_mm: float = RIGID_MM) -> list[MeasuredBody]:
    """The bodies of ``traj``: those ``named`` ([(name, [labels])]) or, when None, every
    cluster :func:`find_clusters` finds.  StarforgeError (one line) for an unknown label, no
    cluster, or a body no frame shows whole."""
    if not (np.isfinite(rigid_mm) and rigid_mm > 0):
        raise StarforgeError(f"rigid must be > 0 mm, got {rigid_mm}")
    index = {x: i for i, x in enumerate(traj.labels)}
    if named:
        groups = []
        for name, labels in named:
            missing = [x for x in labels if x not in index]
            if missing:
                known = ", ".join(traj.labels[:8]) + (" ..." if len(traj.labels) > 8 else "")
                raise StarforgeError(
                    f"--body {name}: no marker {missing[0]!r} in {traj.source} (labels: {known})"
                )
            groups.append((safe_name(name), [index[x] for x in labels]))
    else:
        found = find_clusters(traj, rigid_mm)
        if not found:
            raise StarforgeError(
                f"{traj.source}: no group of 3 or more markers keeps its distances within {rigid_mm:g} mm; "
                "name the bodies with --body NAME=M1,M2,M3 or raise --rigid"
            )
        groups = []
        for k, g in enumerate(found):
            others = [x for i, x in enumerate(traj.labels) if i not in set(g)]
            groups.append((_cluster_name([traj.labels[i] for i in g], others, k + 1), g))
    out, taken = [], set()
    for name, g in groups:
        n = name
        k = 2
        while n in taken:
            n, k = f"{name}_{k}", k + 1
        taken.add(n)
        P = traj.points_mm[:, g]
        try:
            T, scatter, frames = measure_shape(P)
        except StarforgeError as exc:
            raise StarforgeError(f"body {n} of {traj.source}: {exc}") from None
        seen = np.isfinite(P).all(axis=2).mean(axis=0)
        out.append(MeasuredBody(n, tuple(traj.labels[i] for i in g), T, scatter, frames, seen))
    return out


#: matching window and fit limit, mm, with which :func:`identify_recording` identifies frames
#: (a tracker's usual window; ``starforge check --match`` defaults to 2 mm as well)
MATCH_MM, RESIDUAL_MM = 2.0, 1.0
#: frames :func:`identify_recording` identifies at most (evenly spread)
IDENTIFY_FRAMES = 600


def identify_recording(
    bodies: list[MeasuredBody],
    traj: Trajectories,
    match_mm: float = MATCH_MM,
    residual_mm: float = RESIDUAL_MM,
) -> dict[str, float]:
    """Share of frames (of those showing >= 3 of its markers) in which each body's markers, as
    an unlabelled cluster, are identified as that body with every marker right, by the same
    triangle matching and rigid fit ``starforge check`` simulates
    (:mod:`starforge.tracking.identify`, each cluster on its own)."""
    from starforge.tracking.identify import hypotheses, resolve
    from starforge.tracking.library import build_library

    lib = build_library([b.points_mm for b in bodies], [b.name for b in bodies])
    index = {x: i for i, x in enumerate(traj.labels)}
    F = traj.points_mm.shape[0]
    frames = np.unique(np.linspace(0, F - 1, min(F, IDENTIFY_FRAMES)).round().astype(int))
    nmax = lib.n_max
    rates = {}
    for bi, b in enumerate(bodies):
        cols = [index[x] for x in b.labels]
        pts = np.full((len(frames), nmax, 3), np.nan)
        pts[:, : len(cols)] = traj.points_mm[frames][:, cols]
        shown = np.isfinite(pts).all(axis=2).sum(axis=1) >= 3
        h = hypotheses(lib, pts, match_mm, residual_mm)
        chosen = resolve(h, np.arange(len(frames)), nmax, lib.n_bodies)
        seen = np.isfinite(pts).all(axis=2)
        right = np.zeros(len(frames), dtype=bool)
        for i in chosen.tolist():
            s = h.scene[i]
            want = np.where(seen[s], np.arange(nmax), -1)
            right[s] = h.body[i] == bi and np.array_equal(h.assign[i], want)
        rates[b.name] = float(right[shown].mean()) if shown.any() else 0.0
    return rates


@dataclass(frozen=True)
class MeasureResult:
    """Files of a measurement and what they hold.

    files : dict of str -> bytes     ``bodies.csv`` (every body), ``family.json`` (the 4-marker
        bodies, when they can form a family), ``measure.json`` (the report)
    family_note : str or None        why some or all bodies are not in family.json
    identified : dict of str -> float   :func:`identify_recording` per body
    """

    files: dict[str, bytes]
    family_note: str | None
    identified: dict[str, float]


def measure_outputs(
    traj: Trajectories, bodies: list[MeasuredBody], noise_mm: float = 0.2, mount=None, reserve_for=None
) -> MeasureResult:
    """The files of :class:`MeasureResult` for ``bodies`` measured from ``traj`` (``mount``,
    ``reserve_for``: see :func:`starforge.tracking.asfamily.family_from_bodies`)."""
    import json

    from starforge.tracking.asfamily import family_from_bodies
    from starforge.tracking.formats.bodycsv import plain_csv

    files = {"bodies.csv": plain_csv([(b.name, b.points_mm) for b in bodies]).encode("utf-8")}
    four = [b for b in bodies if len(b.labels) == 4]
    note = None
    if len(four) < len(bodies):
        left = [b.name for b in bodies if len(b.labels) != 4]
        note = f"family.json holds 4-marker bodies; {', '.join(left)} are in bodies.csv only"
    if four:
        try:
            fam = family_from_bodies(
                [(b.name, b.points_mm, b.labels) for b in four],
                name=safe_name(traj.source.rsplit("/", 1)[-1].rsplit(".", 1)[0]),
                noise_mm=noise_mm,
                description=f"measured from {traj.source}",
                extra=[{"scatter_mm": np.round(b.scatter_mm, 6).tolist(), "frames": b.frames} for b in four],
                mount=mount,
                reserve_for=reserve_for,
            )
            files["family.json"] = (json.dumps(fam, indent=1) + "\n").encode("utf-8")
        except StarforgeError as exc:
            note = f"no family.json: {exc}"
    identified = identify_recording(bodies, traj)
    report = {
        "format": "starforge.measure",
        "version": 1,
        "units": "mm",
        "source": traj.source,
        "frames": int(traj.points_mm.shape[0]),
        "rate_hz": traj.rate_hz,
        "family_note": note,
        "identification": {"match_mm": MATCH_MM, "residual_mm": RESIDUAL_MM, "rate": identified},
        "bodies": [
            {
                "name": b.name,
                "labels": list(b.labels),
                "points_mm": np.round(b.points_mm, 6).tolist(),
                "scatter_mm": np.round(b.scatter_mm, 6).tolist(),
                "frames": b.frames,
                "seen": np.round(b.seen, 6).tolist(),
            }
            for b in bodies
        ],
    }
    files["measure.json"] = (json.dumps(report, indent=1) + "\n").encode("utf-8")
    return MeasureResult(files, note, identified)
