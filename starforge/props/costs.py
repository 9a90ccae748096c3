"""Cost terms of a marker layout (the paper's eq. 1-5) as pure functions on arrays.

Marker size: the paper's Table 1 gives "2 mm" and its text (section 3.2.2) says a marker is a
sphere of 2 mm *radius*; we follow the text, so the default ``marker_diameter_m`` is 0.004 m.
Two markers overlap when their spheres intersect: centre distance < diameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from starforge.spec import in_range, non_negative, positive, require

# candidate self-matches refined when the near-symmetry margin is a cost term (chain and evaluate alike)
NEAR_SYMMETRY_REFINE = 4


@dataclass(frozen=True)
class CostSettings:
    """Targets and weights (defaults: the paper's Table 1 and section 4).

    Attributes
    ----------
    target_visibility : float
        rho_v, target mean pair visibility in [0, 1] (1).
    target_markers : int
        rho_n, target number of markers (7).
    target_overlap, target_symmetry : float
        rho_o and rho_s in [0, 1] (0, 0).
    sigma_markers : float
        Spread of the Gaussian count penalty (1).
    w_visibility, w_count, w_overlap, w_symmetry : float
        Weights (1, 0.8, 1, 1), >= 0.
    w_near_symmetry : float
        Weight of the optional continuous near-symmetry term (0 = off).
    near_symmetry_target_m : float
        Near-symmetry cost is max(0, 1 - margin / target): 1 for an exactly symmetric set,
        0 once no rigid self-match fits better than this RMS residual, m (0.005).
    marker_diameter_m : float
        Marker sphere diameter, m (0.004: the paper's 2 mm radius).
    symmetry_k : int
        Largest rotation order tried about x, y and z (8).
    symmetry_tol_m : float
        Distance tolerance for a symmetric match, m (0.002).
    min_markers, max_markers : int
        Allowed marker count; the paper's interval [4, 20] (max is Z in eq. 7-8).
    w_coverage : float
        Weight of an optional coverage term (not in the paper; 0 = off): the fraction of poses at
        which fewer than ``coverage_markers`` markers are seen by any camera pair.  A tracker
        needs at least 3 markers to follow a rigid body, which the average visibility of eq. 2
        does not ensure.
    coverage_markers : int
        Markers that must be seen at a pose for it to count as covered (3).
    """

    target_visibility: float = 1.0
    target_markers: int = 7
    target_overlap: float = 0.0
    target_symmetry: float = 0.0
    sigma_markers: float = 1.0
    w_visibility: float = 1.0
    w_count: float = 0.8
    w_overlap: float = 1.0
    w_symmetry: float = 1.0
    w_near_symmetry: float = 0.0
    near_symmetry_target_m: float = 0.005
    marker_diameter_m: float = 0.004
    symmetry_k: int = 8
    symmetry_tol_m: float = 0.002
    min_markers: int = 4
    max_markers: int = 20
    w_coverage: float = 0.0
    coverage_markers: int = 3

    def __post_init__(self):
        in_range("target_visibility", self.target_visibility, 0.0, 1.0)
        in_range("target_overlap", self.target_overlap, 0.0, 1.0)
        in_range("target_symmetry", self.target_symmetry, 0.0, 1.0)
        positive("sigma_markers", self.sigma_markers)
        in_range("coverage_markers", self.coverage_markers, 1, 1000)
        for name in ("w_visibility", "w_count", "w_overlap", "w_symmetry", "w_near_symmetry", "w_coverage"):
            non_negative(name, getattr(self, name))
        positive("near_symmetry_target_m", self.near_symmetry_target_m)
        positive("marker_diameter_m", self.marker_diameter_m)
        in_range("symmetry_k", self.symmetry_k, 2, 360)
        non_negative("symmetry_tol_m", self.symmetry_tol_m)
        in_range("min_markers", self.min_markers, 1, 1000)
        in_range("max_markers", self.max_markers, 1, 1000)
        require(
            self.min_markers <= self.max_markers,
            f"min_markers must be <= max_markers, got {self.min_markers} > {self.max_markers}",
        )
        in_range("markers (target_markers)", self.target_markers, self.min_markers, self.max_markers)


@dataclass(frozen=True)
class CostBreakdown:
    """Every term of eq. 1 for one layout (weighted sum in ``total``)."""

    total: float
    visibility: float
    count: float
    overlap: float
    symmetry: float
    near_symmetry: float
    mean_visibility: float
    overlapping_pairs: int
    symmetric: bool
    margin_m: float
    markers: int
    coverage: float = 0.0

    def to_json(self) -> dict:
        return {
            "total": self.total,
            "visibility": self.visibility,
            "count": self.count,
            "overlap": self.overlap,
            "symmetry": self.symmetry,
            "near_symmetry": self.near_symmetry,
            "mean_visibility": self.mean_visibility,
            "overlapping_pairs": self.overlapping_pairs,
            "symmetric": self.symmetric,
            "near_symmetry_margin_m": None if math.isinf(self.margin_m) else self.margin_m,
            "markers": self.markers,
            "coverage": self.coverage,
        }


def visibility_cost(marker_visibility: np.ndarray, target: float) -> float:
    """Eq. 2: |mean over markers (of mean over poses and pairs) - rho_v|."""
    v = np.asarray(marker_visibility, dtype=float)
    return abs(float(v.mean()) - target) if len(v) else abs(target)


def count_cost(n: int, target: float, sigma: float = 1.0) -> float:
    """Eq. 3: 1 - exp(-(n - rho_n)^2 / (2 sigma^2))."""
    return 1.0 - math.exp(-((n - target) ** 2) / (2.0 * sigma * sigma))


def lower_bound(site_visibility: np.ndarray, s: CostSettings) -> tuple[float, int]:
    """A lower bound on eq. 1 over every layout of the candidate sites, and the count that attains it.

    For ``n`` markers the mean visibility lies between the mean of the ``n`` least and the ``n``
    most visible sites, so the visibility term is at least its distance from that interval; the
    count term is exact, and the overlap, symmetry and optional terms are >= 0.  The bound is
    reached when the ``n`` most visible sites (with ``target_visibility`` = 1) neither overlap nor
    form a symmetric set, which makes it the optimum of the paper's cost in the usual case.
    """
    v = np.sort(np.asarray(site_visibility, dtype=float))
    best, best_n = math.inf, 0
    csum_hi = np.concatenate([[0.0], np.cumsum(v[::-1])])
    csum_lo = np.concatenate([[0.0], np.cumsum(v)])
    for n in range(s.min_markers, min(s.max_markers, len(v)) + 1):
        hi, lo = csum_hi[n] / n, csum_lo[n] / n
        gap = max(0.0, s.target_visibility - hi, lo - s.target_visibility)
        c = s.w_visibility * gap + s.w_count * count_cost(n, s.target_markers, s.sigma_markers)
        if c < best - 1e-15:
            best, best_n = c, n
    return float(best), best_n


def overlapping_pairs(points: np.ndarray, diameter_m: float) -> int:
    """Unordered marker pairs whose spheres intersect (centre distance < diameter)."""
    p = np.asarray(points, dtype=float)
    if len(p) < 2:
        return 0
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    iu = np.triu_indices(len(p), 1)
    return int((d[iu] < diameter_m).sum())


def overlap_cost(points: np.ndarray, diameter_m: float, target: float = 0.0) -> float:
    """Eq. 4: |(1/N) sum over ordered pairs i != j of OVL - rho_o|, N = n (n - 1)."""
    n = len(points)
    if n < 2:
        return abs(target)
    return abs(2.0 * overlapping_pairs(points, diameter_m) / (n * (n - 1)) - target)


def near_symmetry_cost(margin_m: float, target_m: float) -> float:
    """max(0, 1 - margin / target): 1 for an exactly symmetric set, 0 from a margin of ``target_m`` on."""
    return max(0.0, 1.0 - margin_m / target_m)


def coverage_cost(marker_pose_seen: np.ndarray, k: int = 3) -> float:
    """Fraction of poses at which fewer than ``k`` markers are seen (``marker_pose_seen``: (n, p) bool)."""
    seen = np.asarray(marker_pose_seen)
    if seen.size == 0:
        return 1.0
    return float((seen.sum(axis=0) < k).mean())


def evaluate(
    points: np.ndarray,
    marker_visibility: np.ndarray,
    s: CostSettings,
    with_margin: bool = True,
    marker_pose_seen: np.ndarray | None = None,
) -> CostBreakdown:
    """All cost terms of a layout (eq. 1), from scratch.

    Parameters
    ----------
    points : (n, 3) float, m
        Marker positions, prop frame.
    marker_visibility : (n,) float in [0, 1]
        Fraction of (pose, pair) combinations that see each marker.
    s : CostSettings
    with_margin : bool
        Compute the near-symmetry margin even when its weight is 0 (for reports).
    marker_pose_seen : (n, p) bool, optional
        Whether any camera pair sees each marker at each pose; needed for the coverage term.
    """
    from starforge.props.symmetry import is_symmetric, near_symmetry_margin

    p = np.asarray(points, dtype=float)
    n = len(p)
    cv = visibility_cost(marker_visibility, s.target_visibility)
    cn = count_cost(n, s.target_markers, s.sigma_markers)
    pairs = overlapping_pairs(p, s.marker_diameter_m)
    co = overlap_cost(p, s.marker_diameter_m, s.target_overlap)
    sym = is_symmetric(p, s.symmetry_k, s.symmetry_tol_m)
    cs = abs(float(sym) - s.target_symmetry)
    # the cost only needs the margin below the target (a capped, much faster search)
    capped = (
        near_symmetry_margin(p, refine=NEAR_SYMMETRY_REFINE, cap=s.near_symmetry_target_m)
        if s.w_near_symmetry > 0
        else math.inf
    )
    cns = near_symmetry_cost(capped, s.near_symmetry_target_m)
    margin = near_symmetry_margin(p) if with_margin else capped
    total = s.w_visibility * cv + s.w_count * cn + s.w_overlap * co + s.w_symmetry * cs
    total += s.w_near_symmetry * cns
    if marker_pose_seen is not None:
        cc = coverage_cost(marker_pose_seen, s.coverage_markers)
    else:
        require(s.w_coverage == 0, "the coverage term needs the markers' per-pose visibility")
        cc = 0.0
    total += s.w_coverage * cc
    mv = float(np.mean(marker_visibility)) if n else 0.0
    return CostBreakdown(total, cv, cn, co, cs, cns, mv, pairs, sym, margin, n, cc)
