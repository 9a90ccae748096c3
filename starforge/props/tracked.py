"""The tracked objective: marker layouts that keep a prop tracked while it is handled.

A scenario (a pose, with a random set of the cameras lost:
:func:`starforge.props.scenarios.loss_scenarios`) is
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

Per pose :class:`Problem` keeps the count, sum and second moments of the seen markers, so a move
updates every pose in O(poses) and the collinearity test is a closed-form 3 x 3 eigenvalue.

The layouts are searched in :mod:`starforge.props.layout_search` and chosen in
:mod:`starforge.props.tracked_optimizer`.
"""

from __future__ import annotations

import math
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
from starforge.props.symmetry import near_symmetry_margin
from starforge.runtime.kernels import compiled_here, numba
from starforge.runtime.threads import threads_for_work
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
    grow_markers: bool = True  # short of target_tracked held out: add markers, one at a time, up to max_markers

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
        return 1.0 - float(self.tracked_scenarios(sites).mean())

    def tracked_scenarios(self, sites) -> np.ndarray:
        """(scenarios,) bool: ``sites`` tracked in each scenario (>= 3 seen, not in a line)."""
        return self._seen_counts(np.asarray(sites, dtype=np.int64))[1]

    def crowding(self, sites) -> int:
        """The ``close_pairs``, ``avoid_conflicts`` and ``own_conflicts`` terms of :meth:`terms` alone."""
        P = self.points[np.asarray(sites, dtype=np.int64)]
        return self._close_pairs(P) + self._avoid_count(P) + self._own(P)["own_conflicts"]

    def _margin(self, idx: np.ndarray) -> float:
        """The near-symmetry margin of a site set (cached: chains revisit layouts)."""
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
        with threads_for_work(len(cand) * self.poses):
            return _screen_tracked(
                cnt0, s10, s20, self.pose_seen[cand], self.points[cand], self.moments[cand], self.min_spread2
            )

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
