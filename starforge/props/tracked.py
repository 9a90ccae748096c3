"""Marker layouts that keep a prop tracked while it is handled: objective, baselines, optimizer.

A scenario (a pose, with a random set of the cameras lost: :func:`loss_scenarios`) is
**tracked** when at least three markers are each seen by two surviving cameras and the seen
markers are not nearly collinear: their spread across their best-fit line (RMS
distance from it) is at least that of a triangle ``min_height_mm`` high (``sqrt(2) / 3`` of the
height).  The cost of a layout, lowest best, is led by the fraction of poses not tracked::

    C = w_untracked * untracked + w_spare * spare_shortfall + w_visibility * (1 - mean visibility)
      + w_spread * max(0, 1 - spread / spread_target) + w_near_symmetry * max(0, 1 - margin / target)
      + w_spacing * pairs closer than the spacing + w_count * (1 - exp(-(n - n0)^2 / 2))
      + w_avoid * (triangles within the tolerance of another prop's + own conflicts)
      + w_margin * mean seat-margin shortfall

with *spare_shortfall* the mean shortfall of the markers seen
below ``spare_markers`` (5), as a fraction of it (markers to spare when more are lost: the
term keeps separating layouts once every scenario is tracked), *visibility* the fraction of scenarios
in which a marker is seen (the paper's eq. 2 quantity, under camera loss), *spread* the markers' RMS distance from their best-fit line (a layout on one
line cannot give an orientation), *margin* the near-symmetry margin
(:func:`starforge.props.symmetry.near_symmetry_margin`), and the *seat-margin shortfall* each
marker's room to spare beyond its base (:attr:`starforge.props.seat.SeatReport.margin_m`) short
of ``margin_target``, as a fraction of it (a marker stuck a little off its mark still seats).
The *own conflicts* are the pairs of the layout's own triangles a tracker seeing three markers
may mistake for each other, and its triangles it may match to themselves relabelled (two sides
within the tolerance): :func:`starforge.props.distinct.own_triangles` at ``avoid_tolerance_mm``,
the same tolerance other props' triangles keep.  A layout without them is flip-proof from any
three or four of its markers (:mod:`starforge.props.distinct`).

Per pose the optimizer keeps the count, sum and second moments of the seen markers, so a move
updates every pose in O(poses) and the collinearity test is a closed-form 3 x 3 eigenvalue.

Optimizer (:func:`optimize`): greedy additions refined by a swap local search; the best of
``random_layouts`` random layouts; optionally ``restarts`` chains of the paper's reversible-jump
annealing (add / remove / modify, the eq. 7-9 acceptance with Z = ``max_markers``) started from
the best random layout, half of the modify moves going to one of the 8 nearest sites (a local
move; its proposal ratio is taken as 1, exact for a symmetric neighbourhood and an annealing
heuristic otherwise), cooled geometrically with a convergence stop, annealing the cost without
its near-symmetry term.  The greedy layout, the best random layout as it is, and every chain's
best and the best random layout after the swap search are the candidates; with a held-out
sample (``validate``: random poses with their own camera losses and seed, never the
evaluation's) they are ranked by their conflicts first (close pairs and triangles a tracker may
mistake, after :func:`untangle` swapped markers out of them: a wrong pose is worse than a missed
frame; when every candidate keeps a conflict and no chain ran, :data:`RESCUE_CHAINS` chains run
and compete too), then by their tracked fraction there, then by their cost on both samples together, so the result is never behind either baseline on that ranking, and
placement.json reports what each gave.  With ``polish`` the leader and the cheapest candidate
also compete after :func:`held_out_polish` on a tuning sample of their own (not the ranking
sample, so the ranking is not biased towards them), unless the leader tracks every ranking
scenario and is the cheapest candidate (a polished layout could then win only by a lower cost
at the same 100 %; measured, it never did).  The searched scenarios cannot rank the tracked fraction
(the candidates were fitted to them and are tracked in nearly all); a sample of 3000 poses x 2
camera losses resolves gaps of a few in a thousand.
Measured in the previous session (unseated sites), chains from a random start, polished, beat
greedy + swap search on 3 of the 7 built-ins; on seated sites, with the hand and camera loss,
they beat it on none (ties or losses on all 7), so the default runs no chain.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from starforge.geometry.sym3 import (
    line_spread2,
    line_spread2_at_least,
    line_spread2_at_least_many,
    line_spread2_many,
    moments,
)
from starforge.props.distinct import added_conflicts, clashes, face_tree, own_triangles
from starforge.runtime.kernels import compiled_here, numba
from starforge.spec import in_range, non_negative, positive

TRIANGLE_SPREAD = math.sqrt(2.0) / 3.0  # RMS distance from the base line of a triangle of height 1


@dataclass(frozen=True)
class TrackSettings:
    """The tracked objective and its optimizer (lengths in mm unless named ``_m``)."""

    marker_mm: float = 9.5
    marker: str = ""  # a catalogue name (its base seats the marker); "" for the entry of marker_mm
    cameras_lost: float = 0.5  # fraction of the cameras lost at random in each scenario
    loss_patterns: int = 2  # random camera losses per pose (scenarios = poses x patterns)
    gap_px: float = 2.0
    min_height_mm: float = 15.0
    target_markers: int = 7
    min_markers: int = 4
    max_markers: int = 12
    w_untracked: float = 10.0
    w_spare: float = 2.0
    spare_markers: int = 5
    w_visibility: float = 1.0
    w_spread: float = 0.5
    w_near_symmetry: float = 1.0
    w_spacing: float = 2.0
    w_count: float = 0.2
    w_avoid: float = 5.0
    w_margin: float = 0.5
    near_symmetry_target_mm: float = 5.0
    spread_fraction: float = 0.2
    avoid_tolerance_mm: float = 2.6  # every triangle keeps this from other bodies' and the layout's own (sorted sides)
    iterations: int = 3000
    stall: int = 2000
    restarts: int = 2
    t0: float = 0.1
    random_layouts: int = 1000
    validation_poses: int = 3000  # held-out random poses that rank the final candidates (0: none)
    target_tracked: float = 0.99  # below this tracked fraction on the held-out poses: a warning saying why

    def __post_init__(self):
        in_range("marker_mm", self.marker_mm, 1.0, 50.0)
        in_range("gap_px", self.gap_px, 0.0, 50.0)
        in_range("spare_markers", self.spare_markers, 0, 100)
        in_range("cameras_lost", self.cameras_lost, 0.0, 1.0)
        in_range("loss_patterns", self.loss_patterns, 1, 64)
        in_range("min_height_mm", self.min_height_mm, 0.0, 1000.0)
        in_range("min_markers", self.min_markers, 3, 100)
        in_range("max_markers", self.max_markers, self.min_markers, 100)
        in_range("markers (target_markers)", self.target_markers, self.min_markers, self.max_markers)
        for n in ("w_untracked", "w_spare", "w_visibility", "w_spread", "w_near_symmetry", "w_spacing", "w_count", "w_avoid", "w_margin"):
            non_negative(n, getattr(self, n))
        positive("near_symmetry_target_mm", self.near_symmetry_target_mm)
        in_range("spread_fraction", self.spread_fraction, 0.0, 1.0)
        positive("avoid_tolerance_mm", self.avoid_tolerance_mm)
        in_range("iterations", self.iterations, 0, 10**7)
        in_range("stall", self.stall, 1, 10**7)
        in_range("restarts", self.restarts, 0, 1000)
        non_negative("t0", self.t0)
        in_range("random_layouts", self.random_layouts, 0, 10**6)
        in_range("validation_poses", self.validation_poses, 0, 100_000)
        in_range("target_tracked", self.target_tracked, 0.0, 1.0)


def spacing_m(marker_mm: float, rig, gap_px: float) -> float:
    """Least centre distance of two markers, m: one diameter plus ``gap_px`` pixels at the farthest
    camera-to-volume distance of the rig (so two markers stay apart in every camera image)."""
    corners = np.array(
        [[c + s * (i - 0.5) for c, s, i in zip(rig.volume.center, rig.volume.size, idx, strict=True)]
         for idx in np.ndindex(2, 2, 2)]
    )
    worst = 0.0
    for cam in rig.cameras:
        d = float(np.linalg.norm(corners - np.asarray(cam.position), axis=1).max())
        pixel = math.radians(cam.fov_deg) / cam.resolution[0]
        worst = max(worst, d * pixel)
    return marker_mm / 1000.0 + gap_px * worst


def spaced_capacity(points: np.ndarray, spacing: float, enough: int) -> int:
    """How many of ``points`` (m) can be taken at least ``spacing`` apart, up to ``enough``: a
    farthest-point traversal from the first point (each step takes the point farthest from those
    taken) until the farthest is closer than ``spacing``; when that stops short of ``enough``, also
    a greedy that takes the point with the fewest untaken neighbours closer than ``spacing`` (it
    packs a narrow strip the traversal leaves gaps in), and the larger count.  A lower bound on
    the largest such set (finding that is NP-hard), exact in the common case where it reaches
    ``enough``."""
    pts = np.asarray(points, float)
    if not len(pts):
        return 0
    d = np.linalg.norm(pts - pts[0], axis=1)
    taken = 1
    while taken < enough:
        k = int(np.argmax(d))
        if d[k] < spacing:
            break
        taken += 1
        d = np.minimum(d, np.linalg.norm(pts - pts[k], axis=1))
    if taken >= enough or len(pts) > 5000:
        return taken
    near = np.linalg.norm(pts[:, None] - pts[None], axis=2) < spacing  # the diagonal included
    free = np.ones(len(pts), dtype=bool)
    packed = 0
    while free.any() and packed < enough:
        deg = near[:, free].sum(axis=1)
        k = int(np.flatnonzero(free)[np.argmin(deg[free])])
        free &= ~near[k]
        packed += 1
    return max(taken, packed)


def line_reach(points: np.ndarray, refine_below: float = math.inf) -> float:
    """An upper bound (m) on how far ``points`` lie from some line: the largest distance of a
    point from a line, for the best of a few lines (along the principal axis through the centroid
    and through the middle of the extent across it, then that line's direction and offset refined
    by a Nelder-Mead search for the least largest distance).  Any subset's RMS distance from its
    own best-fit line is at most its RMS distance from any line, so at most this: when it is below
    the tracked test's spread, no subset of the points can be tracked.  Every line tried gives a
    valid bound; the search only makes it tighter (a search, not the exact minimax line), and
    runs only when the first bound is below ``refine_below`` (a caller that needs the bound only
    against a threshold skips it where the threshold is far)."""
    pts = np.asarray(points, float)
    if len(pts) < 2:
        return 0.0
    centroid = pts.mean(axis=0)
    c = pts - centroid
    axes = np.linalg.svd(c, full_matrices=False)[2]
    if len(axes) < 3:  # two points: a line through both
        return 0.0
    across = c @ axes[1:].T  # (n, 2) across the principal axis
    mid = (across.max(axis=0) + across.min(axis=0)) / 2
    starts = [np.zeros(2), mid]
    best = min(float(np.linalg.norm(across - o, axis=1).max()) for o in starts)
    if best >= refine_below:
        return best

    def reach(x):  # the line through centroid + o (across) along the axis tilted by (a, b)
        d = axes[0] + x[0] * axes[1] + x[1] * axes[2]
        d = d / np.linalg.norm(d)
        q = c - (x[2] * axes[1] + x[3] * axes[2])
        return float(np.linalg.norm(q - np.outer(q @ d, d), axis=1).max())

    from scipy.optimize import minimize

    scale = float(np.abs(across).max()) or 1.0
    for o in starts:
        r = minimize(reach, np.array([0.0, 0.0, o[0], o[1]]), method="Nelder-Mead",
                     options={"initial_simplex": np.array([[0, 0, o[0], o[1]], [0.05, 0, o[0], o[1]], [0, 0.05, o[0], o[1]],
                                                           [0, 0, o[0] + 0.2 * scale, o[1]], [0, 0, o[0], o[1] + 0.2 * scale]]),
                              "xatol": 1e-7, "fatol": 1e-7, "maxiter": 800})  # fmt: skip
        best = min(best, reach(r.x))  # re-evaluated: the bound is the distance from that very line
    return best


def spaced_triple(points: np.ndarray, spacing: float) -> bool:
    """Whether three of ``points`` lie pairwise at least ``spacing`` apart (exact: a pair far
    apart and a point far from both, counted by a boolean matrix product)."""
    pts = np.asarray(points, float)
    if len(pts) < 3:
        return False
    far = (np.linalg.norm(pts[:, None] - pts[None], axis=2) >= spacing).astype(np.float32)
    return bool(((far @ far) * far).max() > 0.5)


#: relative margin of the skip in :func:`_screen_tracked` (far above the closed form's rounding)
_SAFE_MARGIN = 1e-3


def kernels_compiled() -> bool:
    """Whether this machine's cache holds the placement's screening kernel (false on a first run,
    which compiles it: :func:`starforge.runtime.kernels.compiled_here`)."""
    return compiled_here(_screen_tracked)


@numba.njit(cache=True, nogil=True, parallel=True)
def _screen_tracked(cnt0, s10, s20, seen_c, pts_c, mom_c, min_spread2):
    """(k,) fraction of poses tracked when candidate c joins a layout whose seen markers per pose
    have counts ``cnt0`` (P,), coordinate sums ``s10`` (P, 3) and product sums ``s20`` (P, 6);
    ``seen_c`` (k, P) bool, ``pts_c`` (k, 3), ``mom_c`` (k, 6) describe the candidates.  Only the
    poses that see a candidate change, so the others keep the layout's own verdict; and a pose
    whose n seen markers spread enough that n / (n + 1) of their spread still passes (with a
    margin) stays tracked whatever point joins: the mean squared distance of n + 1 points from
    their best-fit line is at least n / (n + 1) of that of the n from theirs."""
    k, P = seen_c.shape
    base = np.zeros(P, dtype=np.bool_)
    safe = np.zeros(P, dtype=np.bool_)
    for p in range(P):
        if cnt0[p] >= 3:
            d2 = line_spread2(cnt0[p], s10[p, 0], s10[p, 1], s10[p, 2], s20[p, 0], s20[p, 1], s20[p, 2], s20[p, 3], s20[p, 4], s20[p, 5])
            base[p] = d2 >= min_spread2
            safe[p] = d2 * cnt0[p] / (cnt0[p] + 1.0) >= min_spread2 * (1.0 + _SAFE_MARGIN)
    base_good = base.sum()
    out = np.empty(k)
    for i in numba.prange(k):
        good = base_good
        x, y, z = pts_c[i, 0], pts_c[i, 1], pts_c[i, 2]
        for p in range(P):
            if not seen_c[i, p] or safe[p]:
                continue
            n = cnt0[p] + 1.0
            ok = False
            if n >= 3:
                ok = line_spread2_at_least(
                    n, s10[p, 0] + x, s10[p, 1] + y, s10[p, 2] + z,
                    s20[p, 0] + mom_c[i, 0], s20[p, 1] + mom_c[i, 1], s20[p, 2] + mom_c[i, 2],
                    s20[p, 3] + mom_c[i, 3], s20[p, 4] + mom_c[i, 4], s20[p, 5] + mom_c[i, 5], min_spread2,
                )  # fmt: skip
            good += int(ok) - int(base[p])
        out[i] = good / P
    return out


@dataclass
class Problem:
    """Everything the objective needs (metres inside): sites, per-pose visibility, settings."""

    points: np.ndarray  # (s, 3) marker centres (the site one radius off the surface), m
    pose_seen: np.ndarray  # (s, P) bool: some pair sees the marker at the pose
    visibility: np.ndarray  # (s,) fraction of (pose, pair) combinations that see it
    settings: TrackSettings
    spacing: float  # m
    spread_target: float  # m
    avoid_faces: np.ndarray | None = None  # (k, 3) sorted triangle sides of other props, m
    margin: np.ndarray | None = None  # (s,) each site's seat margin, m (starforge.props.seat.SeatReport.margin_m)
    margin_target: float = 0.0  # m: a margin this large costs nothing
    moments: np.ndarray = field(init=False, repr=False)
    neighbours: list = field(init=False, repr=False)
    knn: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        from scipy.spatial import cKDTree

        self.moments = moments(self.points)
        tree = cKDTree(self.points)
        pairs = tree.query_pairs(np.nextafter(self.spacing, 0.0), output_type="ndarray")
        nb = [[] for _ in range(len(self.points))]
        for a, b in pairs:
            nb[a].append(int(b))
            nb[b].append(int(a))
        self.neighbours = [np.array(x, dtype=np.int64) for x in nb]
        k = min(9, len(self.points))
        self.knn = tree.query(self.points, k=k)[1][:, 1:] if k > 1 else np.zeros((len(self.points), 0), int)
        self.seen_f = self.pose_seen.astype(np.float64)
        self.min_spread2 = (TRIANGLE_SPREAD * self.settings.min_height_mm / 1000.0) ** 2
        self._margins: dict = {}
        self._avoid_tree = face_tree(self.avoid_faces)

    @property
    def poses(self) -> int:
        return self.pose_seen.shape[1]

    # --- the exact cost of a layout -----------------------------------------------------------
    def terms(self, sites, symmetry: bool = True) -> dict:
        """Every term of the cost of ``sites`` (list of site indices), and the total.  Without
        ``symmetry`` the near-symmetry term is left out: a lower bound on the total (the term is
        >= 0), which spares its search for proposals that lose anyway."""
        s = self.settings
        idx = np.asarray(sites, dtype=np.int64)
        n = len(idx)
        cnt, tracked = self._seen_counts(idx)
        untracked = 1.0 - float(tracked.mean())
        spare_shortfall = float(np.maximum(0.0, s.spare_markers - cnt).mean()) / max(1, s.spare_markers)
        vis = float(self.visibility[idx].mean()) if n else 0.0
        P = self.points[idx]
        spread = math.sqrt(line_spread2(n, *P.sum(0), *self.moments[idx].sum(0))) if n >= 2 else 0.0
        close = self._close_pairs(P)
        cap = s.near_symmetry_target_mm / 1000.0
        out = {
            "untracked": untracked,
            "spare_shortfall": spare_shortfall,
            "mean_visibility": vis,
            "spread_m": spread,
            "near_symmetry_margin_m": cap if not symmetry else math.inf,
            "close_pairs": close,
            "markers": n,
            "avoid_conflicts": self._avoid_count(P),
            **self._own(P),
            "margin_shortfall": float(self._margin_short(idx).mean()) if n else 0.0,
        }
        if symmetry:
            out["near_symmetry_margin_m"] = self._margin(idx)
        out["total"] = self._total(out)
        return out

    def _seen_counts(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per scenario: how many of the sites ``idx`` are seen, and whether the layout is tracked."""
        seen = self.seen_f[idx]
        cnt = seen.sum(axis=0)
        s1 = seen.T @ self.points[idx]
        s2 = seen.T @ self.moments[idx]
        return cnt, (cnt >= 3) & line_spread2_at_least_many(cnt, s1, s2, self.min_spread2)

    def _margin_short(self, idx: np.ndarray) -> np.ndarray:
        """Per site of ``idx``: how far its seat margin falls short of the target, as a fraction of it."""
        if self.margin is None or self.margin_target <= 0:
            return np.zeros(len(idx))
        return np.maximum(0.0, 1.0 - self.margin[idx] / self.margin_target)

    def _close_pairs(self, P: np.ndarray) -> int:
        n = len(P)
        if n < 2:
            return 0
        d = np.linalg.norm(P[:, None] - P[None], axis=2)
        return int((d < self.spacing).sum() - n) // 2  # the diagonal's n zeros left out

    def untracked(self, sites) -> float:
        """The ``untracked`` term of :meth:`terms` alone."""
        return 1.0 - float(self._seen_counts(np.asarray(sites, dtype=np.int64))[1].mean())

    def crowding(self, sites) -> int:
        """The ``close_pairs``, ``avoid_conflicts`` and ``own_conflicts`` terms of :meth:`terms` alone."""
        P = self.points[np.asarray(sites, dtype=np.int64)]
        return self._close_pairs(P) + self._avoid_count(P) + self._own(P)["own_conflicts"]

    def _margin(self, idx: np.ndarray) -> float:
        """The near-symmetry margin of a site set (cached: chains revisit layouts)."""
        from starforge.props.symmetry import near_symmetry_margin

        s = self.settings
        if len(idx) < 3 or s.w_near_symmetry <= 0:
            return math.inf
        key = tuple(sorted(int(i) for i in idx))
        m = self._margins.get(key)
        if m is None:
            m = near_symmetry_margin(self.points[list(key)], refine=4, cap=s.near_symmetry_target_mm / 1000.0)
            if len(self._margins) < 200_000:
                self._margins[key] = m
        return m

    def _total(self, t: dict) -> float:
        s = self.settings
        n = t["markers"]
        return (
            s.w_untracked * t["untracked"]
            + s.w_spare * t.get("spare_shortfall", 0.0)
            + s.w_visibility * (1.0 - t["mean_visibility"])
            + s.w_spread * max(0.0, 1.0 - t["spread_m"] / self.spread_target)
            + s.w_near_symmetry * max(0.0, 1.0 - t["near_symmetry_margin_m"] * 1000.0 / s.near_symmetry_target_mm)
            + s.w_spacing * t["close_pairs"]
            + s.w_count * (1.0 - math.exp(-((n - s.target_markers) ** 2) / 2.0))
            + s.w_avoid * (t["avoid_conflicts"] + t.get("own_conflicts", 0))
            + s.w_margin * t.get("margin_shortfall", 0.0)
        )

    def cost(self, sites, bound: float = math.inf) -> float:
        """The total cost; when even its lower bound exceeds ``bound`` that bound is returned
        (the caller only needs to know the layout loses)."""
        t = self.terms(sites, symmetry=False)
        if t["total"] > bound:
            return t["total"]
        t["near_symmetry_margin_m"] = self._margin(np.asarray(sites, dtype=np.int64))
        return self._total(t)

    def _own(self, P: np.ndarray) -> dict:
        """The layout's own triangles a tracker may mistake for each other or for themselves
        relabelled (:func:`starforge.props.distinct.own_triangles` at ``avoid_tolerance_mm``), and
        its self-margin, m."""
        conflicts, margin = own_triangles(P, self.settings.avoid_tolerance_mm / 1000.0)
        return {"own_conflicts": conflicts, "self_margin_m": margin}

    def _avoid_count(self, P: np.ndarray) -> int:
        return clashes(P, self._avoid_tree, self.settings.avoid_tolerance_mm / 1000.0)

    # --- cheap screening of many candidate additions at once ------------------------------------
    def tracked_additions(self, sites, candidates) -> np.ndarray:
        """(k,) the exact tracked fraction of ``sites + [c]`` for each candidate c (compiled)."""
        idx = np.asarray(sites, dtype=np.int64)
        base_seen = self.seen_f[idx]
        cnt0 = base_seen.sum(axis=0)
        s10 = base_seen.T @ self.points[idx] if len(idx) else np.zeros((self.poses, 3))
        s20 = base_seen.T @ self.moments[idx] if len(idx) else np.zeros((self.poses, 6))
        cand = np.asarray(candidates, dtype=np.int64)
        return _screen_tracked(cnt0, s10, s20, self.pose_seen[cand], self.points[cand], self.moments[cand], self.min_spread2)

    def _added(self, idx: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each candidate c: the close pairs c makes with ``idx``, and the triangle conflicts
        (other props' and own) of ``idx + [c]``."""
        P, C = self.points[idx], self.points[cand]
        close = (np.linalg.norm(C[:, None] - P[None], axis=2) < self.spacing).sum(axis=1) if len(idx) else np.zeros(len(C), np.int64)
        tol = self.settings.avoid_tolerance_mm / 1000.0
        base = self._avoid_count(P) + self._own(P)["own_conflicts"]
        return close, base + added_conflicts(P, C, self._avoid_tree, tol)

    def crowding_additions(self, sites, candidates) -> np.ndarray:
        """(k,) :meth:`crowding` of ``sites + [c]`` for each candidate c, all at once."""
        idx = np.asarray(sites, dtype=np.int64)
        close, conflicts = self._added(idx, np.asarray(candidates, dtype=np.int64))
        return self._close_pairs(self.points[idx]) + close + conflicts

    def screen_additions(self, sites, candidates: np.ndarray) -> np.ndarray:
        """An approximate cost (no near-symmetry) of ``sites + [c]`` for each candidate c; its
        new close pairs and its triangle conflicts are exact (:meth:`crowding_additions`)."""
        s = self.settings
        idx = np.asarray(sites, dtype=np.int64)
        tracked = self.tracked_additions(idx, candidates)
        cand = np.asarray(candidates, dtype=np.int64)
        n = len(idx) + 1
        vis = (self.visibility[idx].sum() + self.visibility[candidates]) / n
        P = self.points[idx]
        close, conflicts = self._added(idx, cand)
        allm = self.moments[idx].sum(0)[None] + self.moments[candidates]
        alls = P.sum(0)[None] + self.points[candidates]
        spread = np.sqrt(line_spread2_many(np.full(len(candidates), float(n)), alls, allm)) if n >= 2 else np.zeros(len(candidates))
        return (
            s.w_untracked * (1.0 - tracked)
            + s.w_visibility * (1.0 - vis)
            + s.w_spread * np.maximum(0.0, 1.0 - spread / self.spread_target)
            + s.w_spacing * close
            + s.w_avoid * conflicts
            + s.w_margin * (self._margin_short(idx).sum() + self._margin_short(cand)) / n
        )


#: candidate sites screened per greedy or swap step: a fixed spread subset plus the neighbours of
#: the current markers (screening all of a dense site set costs more than it finds)
SCREEN = 400


def _screen_pool(prob: Problem, sites) -> np.ndarray:
    S = len(prob.points)
    if S <= SCREEN:
        return np.arange(S)
    spread = np.arange(0, S, max(1, S // SCREEN))
    near = prob.knn[np.asarray(sites, dtype=np.int64)].ravel() if len(sites) else np.zeros(0, np.int64)
    return np.unique(np.concatenate([spread, near]))


def greedy_local_search(prob: Problem, candidates_top: int = 12) -> list[int]:
    """Greedy: add the best site until ``target_markers``; then swaps (one marker for another
    site) while they lower the exact cost."""
    sites: list[int] = []
    while len(sites) < prob.settings.target_markers:
        free = np.setdiff1d(_screen_pool(prob, sites), sites)
        approx = prob.screen_additions(sites, free)
        top = free[np.argsort(approx, kind="stable")[:candidates_top]]
        best = min(top.tolist(), key=lambda c: (prob.cost([*sites, c]), c))
        sites.append(int(best))
    return local_search(prob, sites)


def untangle(prob: Problem, sites: list[int], rounds: int = 20) -> list[int]:
    """Swap one marker for another site while it lowers the layout's conflicts (:meth:`Problem.
    crowding`: close pairs, triangles a tracker may mistake for another prop's or the layout's
    own): each round takes the swap with the fewest conflicts, then the lowest screened cost,
    over every marker and every free site (:meth:`Problem.crowding_additions` counts them all at
    once).  A layout without conflicts is returned as it is."""
    sites = list(sites)
    cur = prob.crowding(sites)
    every = np.arange(len(prob.points))
    for _ in range(rounds):
        if cur == 0:
            break
        best = None
        for k in range(len(sites)):
            rest = sites[:k] + sites[k + 1 :]
            free = np.setdiff1d(every, sites)
            crowd = prob.crowding_additions(rest, free)
            fewest = crowd.min() if len(free) else cur
            if fewest >= cur or (best is not None and fewest > best[0][0]):
                continue
            few = free[crowd == fewest]
            approx = prob.screen_additions(rest, few)
            i = int(np.argmin(approx))
            key = (int(fewest), float(approx[i]))
            if best is None or key < best[0]:
                best = (key, rest[:k] + [int(few[i])] + rest[k:])
        if best is None:
            break
        sites, cur = best[1], best[0][0]
    return sites


def local_search(prob: Problem, sites: list[int], rounds: int = 20, candidates_top: int = 12) -> list[int]:
    """Swap one marker for another site (screened, then exact) while it lowers the cost."""
    sites = list(sites)
    cur = prob.cost(sites)
    for _ in range(rounds):
        improved = False
        for k in range(len(sites)):
            rest = sites[:k] + sites[k + 1 :]
            free = np.setdiff1d(_screen_pool(prob, sites), rest)
            approx = prob.screen_additions(rest, free)
            for c in free[np.argsort(approx, kind="stable")[:candidates_top]].tolist():
                if c == sites[k]:
                    continue
                trial = rest[:k] + [c] + rest[k:]
                tc = prob.cost(trial, bound=cur)
                if tc < cur - 1e-12:
                    sites, cur, improved = trial, tc, True
                    break
        if not improved:
            break
    return sites


def held_out_polish(tuning: Problem, searched: Problem, start: list[int], pool: np.ndarray, rounds: int = 10, top: int = 8) -> list[int]:
    """Swap one marker for another site while it tracks more of ``tuning``'s scenarios (a
    held-out sample, ``pool``'s sites: ``pool[i]`` is site i of ``tuning`` in ``searched``)
    without adding close pairs or conflicts with other props; a tie goes to the lower cost on the
    searched scenarios.  Returns ``tuning`` indices.  The tracked counts of every swap are
    screened at once (compiled), then the ``top`` best checked exactly."""

    eps = 0.5 / max(1, tuning.poses)

    def cheap(lay):  # close pairs + conflicts on the searched sites, untracked on the tuning ones
        return searched.crowding([int(pool[i]) for i in lay]), tuning.untracked(lay)

    cur = list(start)
    best = (*cheap(cur), searched.cost([int(pool[i]) for i in cur]))
    for _ in range(rounds):
        improved = False
        for k in range(len(cur)):
            rest = cur[:k] + cur[k + 1 :]
            free = np.setdiff1d(np.arange(len(pool)), cur)
            if not len(free):
                return cur
            frac = tuning.tracked_additions(rest, free)
            # only swaps that track at least as many scenarios as now can win
            ok = frac >= 1.0 - best[1] - eps
            for c in free[ok][np.argsort(-frac[ok], kind="stable")[:top]].tolist():
                trial = rest[:k] + [c] + rest[k:]
                close, untracked = cheap(trial)
                if close > best[0] or untracked > best[1] + eps:
                    continue
                g = [int(pool[i]) for i in trial]
                if untracked < best[1] - eps:  # tracks more: the cost only for the record
                    cur, best, improved = trial, (close, untracked, searched.cost(g)), True
                    break
                total = searched.cost(g, bound=best[2])  # a tie: only a lower cost wins
                if total < best[2] - 1e-12:
                    cur, best, improved = trial, (close, untracked, total), True
                    break
        if not improved:
            break
    return cur


def random_layouts(prob: Problem, count: int, rng: np.random.Generator) -> tuple[list[int] | None, float, list[float]]:
    """The best of ``count`` random layouts of ``target_markers`` sites (spacing respected when
    possible): (sites, exact cost of the best, the lower bounds of all).

    Every layout gets the cost without its near-symmetry term, a lower bound; the exact cost is
    computed in that order until the next lower bound exceeds the best exact cost, so the best
    is exact without a symmetry search for every layout."""
    S = len(prob.points)
    n = min(prob.settings.target_markers, S)
    layouts, lower = [], []
    for _ in range(count):
        order = rng.permutation(S)
        taken: list[int] = []
        blocked = np.zeros(S, dtype=bool)
        for s in order.tolist():
            if not blocked[s]:
                taken.append(s)
                blocked[prob.neighbours[s]] = True
                if len(taken) == n:
                    break
        if len(taken) < n:
            taken = order[:n].tolist()
        layouts.append(taken)
        lower.append(prob.terms(taken, symmetry=False)["total"])
    best, best_c = None, math.inf
    for k in np.argsort(lower, kind="stable").tolist():
        if lower[k] > best_c:
            break
        c = prob.terms(layouts[k])["total"]
        if c < best_c:
            best, best_c = layouts[k], c
    return best, best_c, lower


@dataclass(frozen=True)
class ChainRun:
    sites: tuple[int, ...]
    cost: float
    iterations: int
    history: np.ndarray = field(repr=False)  # best cost after each iteration
    accepted: int = 0


def chain(prob: Problem, start: list[int], rng: np.random.Generator) -> ChainRun:
    """One annealed reversible-jump chain from ``start`` (see the module docstring).

    The chain anneals the cost without its near-symmetry term (a lower bound of the total; the
    symmetry search took three quarters of a chain's time), and its ``cost`` is that bound; the
    swap search that polishes the chain's best uses the full cost."""
    s = prob.settings
    S = len(prob.points)
    Z, lo = s.max_markers, s.min_markers
    sites = list(start)
    cur = prob.terms(sites, symmetry=False)["total"]
    best, best_sites = cur, tuple(sites)
    hist = np.empty(max(1, s.iterations))
    last_gain = 0
    accepted = 0
    decay = (1e-4 / s.t0) ** (1.0 / max(1, s.iterations)) if s.t0 > 0 else 0.0
    t = s.t0
    i = 0
    for i in range(s.iterations):
        u = rng.random()
        n = len(sites)
        if u < 0.3 and n < Z:
            c = int(rng.integers(S))
            if c in sites:
                hist[i] = best
                continue
            new, factor = sites + [c], 0.3 * (Z - n) / (0.3 * (n + 1))
        elif u < 0.6 and n > lo:
            k = int(rng.integers(n))
            new, factor = sites[:k] + sites[k + 1 :], 0.3 * n / (0.3 * (Z - (n - 1)))
        else:
            k = int(rng.integers(n))
            if rng.random() < 0.5 and prob.knn.shape[1]:
                c = int(prob.knn[sites[k], rng.integers(prob.knn.shape[1])])
            else:
                c = int(rng.integers(S))
            if c in sites:
                hist[i] = best
                continue
            new, factor = sites[:k] + [c] + sites[k + 1 :], 1.0
        # accept iff new cost <= cur + t (log factor - log u): the bound that decides it
        lu = math.log(max(rng.random(), 1e-300))
        limit = cur + t * (math.log(factor) - lu) if t > 0 else cur
        nc = prob.terms(new, symmetry=False)["total"]
        ok = nc <= limit if t > 0 else nc < cur
        if ok:
            sites, cur = new, nc
            accepted += 1
            if cur < best - 1e-12:
                best, best_sites, last_gain = cur, tuple(sites), i
        hist[i] = best
        t *= decay
        if i - last_gain > s.stall:
            break
    n_it = i + 1 if s.iterations else 0
    return ChainRun(best_sites, float(best), n_it, hist[:n_it].copy(), accepted)


#: annealing chains run when no candidate is free of conflicts and the spec runs none
RESCUE_CHAINS = 2


@dataclass(frozen=True)
class Optimized:
    """The chosen layout and everything that competed with it."""

    sites: tuple[int, ...]
    terms: dict
    baselines: dict
    runs: tuple[ChainRun, ...]
    seconds: dict


def optimize(prob: Problem, rng: np.random.Generator, progress=None, validate=None, polish=None) -> Optimized:
    """Baselines, chains from the best random layout, the best polished (see the module docstring).

    ``validate``: optional ``validate(list of site tuples) -> list of {"untracked", "cost"}`` on
    scenarios the optimizer did not search (a held-out sample, its own seed).  The candidates are
    then ranked by their tracked fraction on that sample first (what the independent evaluation
    measures; the searched scenarios cannot rank it: every candidate is tracked in nearly all of
    them, having been fitted to them), then by their cost on both samples together.  Without it,
    by their cost on the searched scenarios.  ``baselines["selection"]`` names the winner and
    gives every candidate's scores."""
    s = prob.settings
    sec = {}
    t = time.perf_counter()
    greedy = greedy_local_search(prob)
    g_cost = prob.cost(greedy)
    sec["greedy_local_search_s"] = round(time.perf_counter() - t, 3)
    t = time.perf_counter()
    r_sites, r_cost, r_costs = random_layouts(prob, s.random_layouts, rng)
    sec["random_s"] = round(time.perf_counter() - t, 3)
    t = time.perf_counter()
    runs = []
    for k in range(s.restarts):
        runs.append(chain(prob, greedy if r_sites is None else r_sites, rng))
        if progress is not None:
            progress(k + 1, s.restarts)
    sec["chains_s"] = round(time.perf_counter() - t, 3)
    t = time.perf_counter()
    # the baselines themselves compete; every chain's best and the best random layout are
    # polished by the same swap search (the greedy layout already is)
    cands: dict[str, tuple[int, ...]] = {"greedy_local_search": tuple(greedy)}
    if r_sites is not None:
        cands["best_of_random"] = tuple(r_sites)
        cands["best_of_random_polished"] = tuple(local_search(prob, list(r_sites)))
    for k, r in enumerate(runs):
        cands[f"chain_{k}_polished"] = tuple(local_search(prob, list(r.sites)))
    for name, sites in cands.items():  # conflicts first: a tracker must never mistake the layout
        if prob.crowding(sites):
            cands[name] = tuple(untangle(prob, list(sites)))
    costs = {name: prob.cost(list(sites)) for name, sites in cands.items()}
    crowd = {name: prob.crowding(sites) for name, sites in cands.items()}
    sec["polish_s"] = round(time.perf_counter() - t, 3)
    held = {name: None for name in cands}
    if validate is not None:
        t = time.perf_counter()
        held = dict(zip(cands, validate(list(cands.values())), strict=True))
        sec["validate_s"] = round(time.perf_counter() - t, 3)

    def key(name):  # first listed wins a tie: the greedy layout, then the random baseline
        h = held[name]
        if h is None:
            return (crowd[name], costs[name])
        return (crowd[name], h["untracked"], costs[name] + h["cost"])

    order = sorted(cands, key=key)  # stable
    if crowd[order[0]] and s.restarts == 0:
        # conflicts left that single swaps cannot clear: the reversible-jump chains search too
        # (their add and remove moves also try fewer markers, which span fewer triangles)
        t = time.perf_counter()
        for k in range(RESCUE_CHAINS):
            runs.append(chain(prob, greedy if r_sites is None else r_sites, rng))
            name = f"chain_{k}_polished"
            cands[name] = tuple(untangle(prob, local_search(prob, list(runs[-1].sites))))
            costs[name], crowd[name] = prob.cost(list(cands[name])), prob.crowding(cands[name])
            held[name] = validate([cands[name]])[0] if validate is not None else None
        order = sorted(cands, key=key)
        sec["chains_s"] = round(time.perf_counter() - t, 3)
    polished = "none"
    if polish is not None and validate is not None:
        # the leader on the held-out sample and the cheapest candidate, each polished on a tuning
        # sample of its own, compete too, ranked on the same held-out sample as the others
        # (which they were not fitted to)
        t = time.perf_counter()
        cheapest = min(order, key=lambda n: costs[n] + held[n]["cost"])
        if held[order[0]]["untracked"] == 0.0 and cheapest == order[0]:
            # the leader tracks every held-out scenario, so no polished layout can rank above it
            # by tracking: only by a lower cost at 100 %, and it is already the cheapest.
            # Skipped: on the 7 built-ins and 4 real meshes the polish
            # from such a leader never added a candidate (box, shield, sword, umbrella)
            polished = "skipped: the leader tracks every held-out scenario and costs least"
        else:
            polished = "ran"
            for name, start in (("held_out_polished", order[0]), ("held_out_polished_cheapest", cheapest)):
                if name != "held_out_polished" and start == order[0]:
                    continue
                tuned = tuple(int(x) for x in polish(cands[start], [cands[n] for n in order if n != start]))
                if sorted(tuned) not in [sorted(c) for c in cands.values()]:
                    cands[name] = tuned
                    costs[name] = prob.cost(list(tuned))
                    crowd[name] = prob.crowding(tuned)
                    held[name] = validate([tuned])[0]
            order = sorted(cands, key=key)
        sec["held_out_polish_s"] = round(time.perf_counter() - t, 3)
    winner = order[0]
    best = list(cands[winner])
    sel_cost = {n: costs[n] + (held[n]["cost"] if held[n] is not None else 0.0) for n in cands}
    selection = {
        "winner": winner,
        "validated": validate is not None,
        "polish": polished,
        "candidates": {
            n: {
                "sites": [int(x) for x in cands[n]],
                "cost": costs[n],
                "validation_tracked": None if held[n] is None else 1.0 - held[n]["untracked"],
                "validation_cost": None if held[n] is None else held[n]["cost"],
                "selection_cost": sel_cost[n],
            }
            for n in order
        },
    }
    baselines = {
        "greedy_local_search": {"cost": g_cost, "sites": [int(x) for x in greedy], "selection_cost": sel_cost["greedy_local_search"]},
        "best_of_random": {
            "layouts": s.random_layouts,
            "cost": None if r_sites is None else r_cost,
            "sites": None if r_sites is None else [int(x) for x in r_sites],
            "median_cost": float(np.median(r_costs)) if r_costs else None,
            "selection_cost": sel_cost.get("best_of_random"),
        },
        "selection_cost": sel_cost[winner],
        "validated": validate is not None,
        "selection": selection,
        "chains": [{"cost": r.cost, "iterations": r.iterations, "accepted": r.accepted} for r in runs],
    }
    return Optimized(tuple(int(x) for x in best), prob.terms(best), baselines, tuple(runs), sec)


def alive_masks(n_cams: int, lost_fraction: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count,) uint64: random sets of surviving cameras, ``round(lost_fraction * n_cams)`` lost
    in each (a uniformly random subset per entry)."""
    lost = int(round(lost_fraction * n_cams))
    keep = n_cams - lost
    order = np.argsort(rng.random((count, n_cams)), axis=1)[:, :keep]
    bits = np.uint64(1) << order.astype(np.uint64)
    return np.bitwise_or.reduce(bits, axis=1) if keep else np.zeros(count, np.uint64)


def loss_scenarios(masks: np.ndarray, n_cams: int, lost_fraction: float, patterns: int, rng: np.random.Generator):
    """Scenarios of camera loss: every pose ``patterns`` times, each with its own random set of
    lost cameras (one when none are lost).  A marker is seen in a scenario when at least two of
    the surviving cameras see it (any two can triangulate it).

    Returns
    -------
    seen : (s, P * patterns) bool
    alive : (P * patterns,) uint64, the surviving cameras of each scenario
    """
    P = masks.shape[1]
    L = patterns if int(round(lost_fraction * n_cams)) > 0 else 1
    alive = alive_masks(n_cams, lost_fraction, P * L, rng)
    seen = np.bitwise_count(masks[:, np.repeat(np.arange(P), L)] & alive[None]) >= 2
    return seen, alive
