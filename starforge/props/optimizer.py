"""Reversible-jump MCMC simulated annealing over marker sets (the paper's section 4, eq. 6-9).

State: a list of 4..Z candidate-site indices (Z = ``max_markers``, 20).  Moves: add a marker on
a uniformly random site (p_a = .3), remove a uniformly random marker (p_r = .3), move a
uniformly random marker to a uniformly random site (p_m = .4).  Acceptance (Metropolis-Hastings-
Green) with f(M) = exp(-C(M) / t):

* add:    min(1, p_r (Z - |M|) f(M') / (p_a |M'| f(M)))           (eq. 7)
* remove: min(1, p_a |M| f(M') / (p_r (Z - |M'|) f(M)))           (eq. 8)
* modify: min(1, f(M') / f(M))                                    (eq. 9)

These are exact MH ratios for a chain over Z labelled marker slots whose occupied slots carry a
uniformly distributed site: an add picks one of the Z - |M| free slots, a remove one of the |M'|
occupied ones, and the uniform site proposal cancels against the uniform site prior.  With a
constant cost the chain's stationary marker count is therefore proportional to C(Z, n) on
[min, max] (checked in the tests).  At t = 0 the limit is taken: strictly better proposals are
accepted, worse ones refused, equal ones accepted with the proposal ratio.

Schedule (paper): t = 1.0, lowered by 0.25 every 50 iterations, 0 from iteration 200; stop once
t = 0 and the cost changed by less than 3 % over the last 50 iterations.

Speed: every step is O(Z) table lookups.  Visibility is a running sum of per-site visibility,
overlap a running count of overlapping pairs kept with per-site neighbour counts, symmetry a
cheap exact early-out (:func:`starforge.props.symmetry.quick_reject`) before the full test.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from starforge.props.costs import NEAR_SYMMETRY_REFINE, CostSettings
from starforge.props.symmetry import is_symmetric, near_symmetry_margin, quick_reject_xyz
from starforge.spec import in_range, non_negative, positive, require

ADD, REMOVE, MODIFY = 0, 1, 2
MOVE_NAMES = ("add", "remove", "modify")


@dataclass(frozen=True)
class ChainSettings:
    """Optimizer settings (defaults: the paper's section 4).

    Attributes
    ----------
    p_add, p_remove, p_modify : float
        Move probabilities (.3, .3, .4); they must sum to 1.
    t0 : float
        Initial temperature (1.0).
    cool_step : float
        Temperature drop (0.25) every ``cool_every`` iterations (50).
    zero_from : int
        Iteration from which t = 0 (200).
    stop_window : int
        Iterations over which the relative cost change is measured (50).
    stop_rel : float
        Stop when |C(i - window) - C(i)| <= stop_rel * C(i - window) at t = 0 (0.03).
    max_iterations : int
        Hard cap per restart (20000).
    restarts : int
        Independent chains (the paper ran 10 per prop); the best is kept.
    fixed_temperature : float
        If >= 0, ignore the schedule and run at this temperature for ``max_iterations``
        (for sampling and tests); -1 = off.
    """

    p_add: float = 0.3
    p_remove: float = 0.3
    p_modify: float = 0.4
    t0: float = 1.0
    cool_step: float = 0.25
    cool_every: int = 50
    zero_from: int = 200
    stop_window: int = 50
    stop_rel: float = 0.03
    max_iterations: int = 20000
    restarts: int = 1
    fixed_temperature: float = -1.0

    def __post_init__(self):
        for name in ("p_add", "p_remove", "p_modify"):
            in_range(name, getattr(self, name), 0.0, 1.0)
        total = self.p_add + self.p_remove + self.p_modify
        require(abs(total - 1.0) < 1e-9, f"p_add + p_remove + p_modify must be 1, got {total}")
        require(
            self.p_add > 0 and self.p_remove > 0 or self.p_add == self.p_remove == 0,
            "p_add and p_remove must both be > 0 (or both 0)",
        )
        non_negative("t0", self.t0)
        non_negative("cool_step", self.cool_step)
        in_range("cool_every", self.cool_every, 1, 10**9)
        in_range("zero_from", self.zero_from, 0, 10**9)
        in_range("stop_window", self.stop_window, 1, 10**9)
        non_negative("stop_rel", self.stop_rel)
        in_range("max_iterations", self.max_iterations, 1, 10**9)
        in_range("restarts", self.restarts, 1, 10000)
        require(
            self.fixed_temperature == -1.0 or self.fixed_temperature >= 0,
            f"fixed_temperature must be >= 0 or -1 (off), got {self.fixed_temperature}",
        )

    def temperature(self, i: int) -> float:
        """Temperature at iteration ``i`` (0-based)."""
        if self.fixed_temperature >= 0:
            return self.fixed_temperature
        if i >= self.zero_from:
            return 0.0
        return max(0.0, self.t0 - self.cool_step * (i // self.cool_every))


def proposal_factor(move: int, n: int, s: ChainSettings, z: int) -> float:
    """Proposal-probability ratio q(M|M') / q(M'|M) of eq. 7-9 for a move from a set of size n."""
    if move == ADD:
        return s.p_remove * (z - n) / (s.p_add * (n + 1))
    if move == REMOVE:
        return s.p_add * n / (s.p_remove * (z - (n - 1)))
    return 1.0


def acceptance_probability(
    move: int, n: int, cost: float, new_cost: float, t: float, s: ChainSettings, z: int
) -> float:
    """Eq. 7-9: min(1, proposal factor * f(M') / f(M)), f = exp(-C / t); the t -> 0 limit at t = 0."""
    factor = proposal_factor(move, n, s, z)
    if factor <= 0:
        return 0.0
    delta = new_cost - cost
    if t <= 0:
        if delta < 0:
            return 1.0
        if delta > 0:
            return 0.0
        return min(1.0, factor)
    log_r = math.log(factor) - delta / t
    return 1.0 if log_r >= 0 else math.exp(log_r)


@dataclass(frozen=True)
class ChainResult:
    """One annealing run.

    Attributes
    ----------
    sites : tuple of int
        Best marker set found (site indices, in the order they were placed).
    cost : float
        Its total cost.
    iterations : int
    history_cost, history_best : (iterations,) float
        Current and best-so-far total cost after each iteration.
    history_n : (iterations,) int
        Current marker count.
    proposed, accepted : dict move name -> int
    seconds : float
    """

    sites: tuple[int, ...]
    cost: float
    iterations: int
    history_cost: np.ndarray = field(repr=False)
    history_best: np.ndarray = field(repr=False)
    history_n: np.ndarray = field(repr=False)
    proposed: dict = field(default_factory=dict)
    accepted: dict = field(default_factory=dict)
    seconds: float = 0.0


def overlap_neighbours(points: np.ndarray, diameter_m: float) -> list[tuple[int, ...]]:
    """For every site, the sites (itself included) whose marker spheres would intersect its own."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    pairs = tree.query_pairs(np.nextafter(diameter_m, 0.0), output_type="ndarray")
    nbr: list[list[int]] = [[i] for i in range(len(points))]
    for a, b in pairs:
        nbr[a].append(int(b))
        nbr[b].append(int(a))
    return [tuple(x) for x in nbr]


class _Layout:
    """Incremental cost of a marker set (running sums; O(Z) per move)."""

    def __init__(self, points, vis, cs: CostSettings, nbr, pose_seen=None):
        self.points = points
        # coverage term: per-site pose visibility (s, p) and the markers seen at each pose (p,)
        self.pose_seen = pose_seen if cs.w_coverage > 0 else None
        self.pc = None if self.pose_seen is None else np.zeros(pose_seen.shape[1], dtype=np.int32)
        self.vis = vis
        self.cs = cs
        self.nbr = nbr
        self.nbrset = [frozenset(x) for x in nbr] if any(len(x) > 1 for x in nbr) else None
        self.cnt = np.zeros(len(points), dtype=np.int64)  # markers overlapping a marker at each site
        self.sites: list[int] = []
        self.sum_v = 0.0
        self.pairs = 0
        self.sym = 0.0
        self.X, self.Y, self.Z = (points[:, a].tolist() for a in range(3))

    def place(self, site: int) -> None:
        self.pairs += int(self.cnt[site])
        for j in self.nbr[site]:
            self.cnt[j] += 1
        self.sites.append(site)
        self.sum_v += self.vis[site]

    def take(self, index: int) -> None:
        site = self.sites.pop(index)
        for j in self.nbr[site]:
            self.cnt[j] -= 1
        self.pairs -= int(self.cnt[site])
        self.sum_v -= self.vis[site]

    def cost_of(self, n: int, sum_v: float, pairs: int, sites, pc=None) -> tuple[float, float]:
        cs = self.cs
        c = cs.w_visibility * abs(sum_v / n - cs.target_visibility)
        c += cs.w_count * (1.0 - math.exp(-((n - cs.target_markers) ** 2) / (2 * cs.sigma_markers**2)))
        ovl = 2.0 * pairs / (n * (n - 1)) if n > 1 else 0.0
        c += cs.w_overlap * abs(ovl - cs.target_overlap)
        sym = 0.0
        if cs.w_symmetry > 0 or cs.w_near_symmetry > 0:
            if cs.w_symmetry > 0:
                X, Y, Z = self.X, self.Y, self.Z
                if n < 2 or quick_reject_xyz(
                    [X[i] for i in sites], [Y[i] for i in sites], [Z[i] for i in sites], cs.symmetry_tol_m
                ):
                    sym = 0.0
                else:
                    sym = 1.0 if is_symmetric(self.points[sites], cs.symmetry_k, cs.symmetry_tol_m) else 0.0
                c += cs.w_symmetry * abs(sym - cs.target_symmetry)
            if cs.w_near_symmetry > 0:
                m = near_symmetry_margin(
                    self.points[sites], refine=NEAR_SYMMETRY_REFINE, cap=cs.near_symmetry_target_m
                )
                c += cs.w_near_symmetry * max(0.0, 1.0 - m / cs.near_symmetry_target_m)
        else:
            c += cs.w_symmetry * abs(0.0 - cs.target_symmetry)
        if pc is not None:
            c += cs.w_coverage * float(np.count_nonzero(pc < cs.coverage_markers)) / len(pc)
        return c, sym

    def total(self) -> float:
        return self.cost_of(len(self.sites), self.sum_v, self.pairs, self.sites, self.pc)[0]


def random_valid_layout(n: int, n_sites: int, nbr, rng: np.random.Generator, tries: int = 1000) -> list[int]:
    """``n`` distinct sites, no two overlapping (falls back to distinct sites after ``tries``)."""
    for _ in range(tries):
        sites = rng.choice(n_sites, size=n, replace=False)
        taken: set[int] = set()
        ok = True
        for s in sites:
            if s in taken:
                ok = False
                break
            taken.update(nbr[s])
        if ok:
            return [int(s) for s in sites]
    return [int(s) for s in rng.choice(n_sites, size=n, replace=False)]


def run_chain(
    points: np.ndarray,
    site_visibility: np.ndarray,
    cs: CostSettings,
    ch: ChainSettings,
    rng: np.random.Generator,
    nbr=None,
    initial=None,
    on_iteration=None,
    site_pose_seen=None,
) -> ChainResult:
    """One simulated-annealing RJ-MCMC run.

    Parameters
    ----------
    points : (s, 3) float, m
        Candidate sites (prop frame).
    site_visibility : (s,) float in [0, 1]
        Fraction of (pose, pair) combinations that see each site (from the visibility table).
    cs, ch : CostSettings, ChainSettings
    rng : numpy.random.Generator
    nbr : list of tuples, optional
        :func:`overlap_neighbours` (computed when not given).
    initial : sequence of int, optional
        Starting set; default a random valid set of ``target_markers`` sites.
    on_iteration : callable, optional
        Called every 1000 iterations with the iteration number.
    site_pose_seen : (s, p) bool, optional
        Whether any camera pair sees each site at each pose; required when ``cs.w_coverage > 0``.
    """
    t_start = time.perf_counter()
    points = np.asarray(points, dtype=float)
    vis = np.asarray(site_visibility, dtype=float)
    S = len(points)
    require(S >= 1, "no candidate sites left")
    if nbr is None:
        nbr = overlap_neighbours(points, cs.marker_diameter_m)
    Z, lo = cs.max_markers, cs.min_markers
    pose_seen = None
    if cs.w_coverage > 0:
        require(site_pose_seen is not None, "the coverage term needs the per-pose visibility of the sites")
        pose_seen = np.asarray(site_pose_seen, dtype=np.int32)
    lay = _Layout(points, vis.tolist(), cs, nbr, pose_seen)
    start = (
        list(initial)
        if initial is not None
        else random_valid_layout(min(max(cs.target_markers, lo), Z), S, nbr, rng)
    )
    for s_ in start:
        lay.place(int(s_))
        if pose_seen is not None:
            lay.pc += pose_seen[int(s_)]
    cur_cost = lay.total()
    best_cost, best_sites = cur_cost, tuple(lay.sites)
    N = ch.max_iterations
    h_cost = np.empty(N)
    h_best = np.empty(N)
    h_n = np.empty(N, dtype=np.int16)
    proposed = [0, 0, 0]
    accepted = [0, 0, 0]
    pa, pr = ch.p_add, ch.p_add + ch.p_remove
    block = 4096
    i = 0
    sites = lay.sites
    cnt = lay.cnt
    vlist = lay.vis
    nbrset = lay.nbrset
    window, rel = ch.stop_window, ch.stop_rel
    sched = ch.fixed_temperature < 0
    while i < N:
        u_move = rng.random(block).tolist()
        u_pick = rng.random(block).tolist()
        u_site = rng.integers(0, S, size=block).tolist()
        u_acc = rng.random(block).tolist()
        for b in range(block):
            if i >= N:
                break
            t = ch.temperature(i)
            n = len(sites)
            um = u_move[b]
            move = ADD if um < pa else (REMOVE if um < pr else MODIFY)
            proposed[move] += 1
            ok = False
            new_pc = None
            if move == ADD:
                s_new = u_site[b]
                if n < Z and s_new not in sites:  # one marker per site
                    if pose_seen is not None:
                        new_pc = lay.pc + pose_seen[s_new]
                    new_sites = sites + [s_new]
                    new_n, new_v, new_pairs = n + 1, lay.sum_v + vlist[s_new], lay.pairs + int(cnt[s_new])
                    ok = True
            elif move == REMOVE:
                if n > lo:
                    k = int(u_pick[b] * n)
                    s_old = sites[k]
                    new_sites = sites[:k] + sites[k + 1 :]
                    if pose_seen is not None:
                        new_pc = lay.pc - pose_seen[s_old]
                    new_n, new_v, new_pairs = n - 1, lay.sum_v - vlist[s_old], lay.pairs - int(cnt[s_old]) + 1
                    ok = True
            else:
                k = int(u_pick[b] * n)
                s_old, s_new = sites[k], u_site[b]
                if s_new != s_old and s_new in sites:  # one marker per site
                    i += 1
                    h_cost[i - 1], h_best[i - 1], h_n[i - 1] = cur_cost, best_cost, n
                    continue
                new_sites = sites[:k] + [s_new] + sites[k + 1 :]
                if pose_seen is not None:
                    new_pc = lay.pc - pose_seen[s_old] + pose_seen[s_new]
                lost = int(cnt[s_old]) - 1
                gained = int(cnt[s_new]) - (
                    1 if (s_old == s_new or (nbrset is not None and s_old in nbrset[s_new])) else 0
                )
                new_n, new_v, new_pairs = (
                    n,
                    lay.sum_v - vlist[s_old] + vlist[s_new],
                    lay.pairs - lost + gained,
                )
                ok = True
            if ok:
                new_cost, _ = lay.cost_of(new_n, new_v, new_pairs, new_sites, new_pc)
                if t > 0 or new_cost <= cur_cost:
                    p_acc = acceptance_probability(move, n, cur_cost, new_cost, t, ch, Z)
                    if u_acc[b] < p_acc:
                        accepted[move] += 1
                        if move == ADD:
                            lay.place(s_new)
                        elif move == REMOVE:
                            lay.take(k)
                        else:
                            lay.take(k)
                            lay.place(s_new)
                            # keep marker order stable: move the new marker back to slot k
                            sites.insert(k, sites.pop())
                        lay.pc = new_pc
                        cur_cost = new_cost
                        if cur_cost < best_cost:
                            best_cost, best_sites = cur_cost, tuple(sites)
            h_cost[i] = cur_cost
            h_best[i] = best_cost
            h_n[i] = len(sites)
            i += 1
            if on_iteration is not None and i % 1000 == 0:
                on_iteration(i)
            if sched and i > ch.zero_from + window:
                old = h_cost[i - 1 - window]
                if abs(old - cur_cost) <= rel * abs(old):
                    N = i
                    break
    return ChainResult(
        sites=best_sites,
        cost=float(best_cost),
        iterations=i,
        history_cost=h_cost[:i].copy(),
        history_best=h_best[:i].copy(),
        history_n=h_n[:i].copy(),
        proposed=dict(zip(MOVE_NAMES, proposed, strict=True)),
        accepted=dict(zip(MOVE_NAMES, accepted, strict=True)),
        seconds=time.perf_counter() - t_start,
    )


@dataclass(frozen=True)
class AnnealResult:
    """Best of several restarts, with the spread of their costs."""

    best: ChainResult
    runs: tuple[ChainResult, ...]

    @property
    def costs(self) -> np.ndarray:
        return np.array([r.cost for r in self.runs])


def anneal(
    points,
    site_visibility,
    cs: CostSettings,
    ch: ChainSettings,
    rng: np.random.Generator,
    on_iteration=None,
    on_run=None,
    site_pose_seen=None,
) -> AnnealResult:
    """``ch.restarts`` independent chains (sequential, one rng); the lowest-cost run is ``best``.

    ``on_run(done, total)`` is called after each run (for a progress bar).
    """
    positive("marker_diameter_m", cs.marker_diameter_m)
    nbr = overlap_neighbours(np.asarray(points, dtype=float), cs.marker_diameter_m)
    runs = []
    for k in range(ch.restarts):
        runs.append(
            run_chain(
                points,
                site_visibility,
                cs,
                ch,
                rng,
                nbr=nbr,
                on_iteration=on_iteration,
                site_pose_seen=site_pose_seen,
            )
        )
        if on_run is not None:
            on_run(k + 1, ch.restarts)
    best = min(runs, key=lambda r: r.cost)
    return AnnealResult(best, tuple(runs))
