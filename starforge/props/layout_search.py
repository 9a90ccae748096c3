"""The searches over marker layouts of the tracked objective: greedy additions, swap local
searches (on the cost, on the conflicts, on a held-out sample), random layouts and one
annealed reversible-jump chain.  Each takes a :class:`starforge.props.tracked.Problem` and
returns site indices; :func:`starforge.props.tracked_optimizer.optimize` runs them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from starforge.props.tracked import Problem

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


def greedy_local_search(prob: Problem, candidates_top: int = 12, start=(), trace: list[float] | None = None) -> list[int]:
    """Greedy: add the best site to ``start`` (default none) until ``target_markers``; then swaps
    (one marker for another site) while they lower the exact cost.  ``trace``: a list that gets
    the cost after each addition, then after each swap (what ``convergence.png`` draws)."""
    sites = [int(x) for x in start]
    while len(sites) < prob.settings.target_markers:
        free = np.setdiff1d(_screen_pool(prob, sites), sites)
        approx = prob.screen_additions(sites, free)
        top = free[np.argsort(approx, kind="stable")[:candidates_top]]
        cost, best = min((prob.cost([*sites, c]), c) for c in top.tolist())
        sites.append(int(best))
        if trace is not None:
            trace.append(float(cost))
    return local_search(prob, sites, trace=trace)


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


def local_search(
    prob: Problem, sites: list[int], rounds: int = 20, candidates_top: int = 12, trace: list[float] | None = None
) -> list[int]:
    """Swap one marker for another site (screened, then exact) while it lowers the cost;
    ``trace`` gets the cost after each swap."""
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
                    if trace is not None:
                        trace.append(float(tc))
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
    """One annealed reversible-jump chain from ``start`` (the moves and their acceptance:
    :mod:`starforge.props.tracked_optimizer`).

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
