"""The identification pipeline against an independent brute force: every subset of a cluster's
points put on every body under every relabelling, gated by QTM's bone rule (every distance
within the window), fitted by an SVD written here, and ranked as the headline rules rank
(more markers, then the lowest residual; or, for ``sides``, the smallest sorted-distance
difference, blind to the labels).  The pipeline's best hypothesis per cluster must be the
brute force's best."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from starforge.tracking import identify as ident

MATCH, RESIDUAL, NOISE = 2.0, 1.0, 0.25


def _bodies(rng) -> list[np.ndarray]:
    """Six random 4-marker bodies (about 30 mm), two of them nearly congruent (a pair a tracker
    confuses now and then), all with distances at least 6 mm."""
    out = []
    while len(out) < 5:
        P = rng.uniform(0, 30, size=(4, 3))
        d = [np.linalg.norm(P[a] - P[b]) for a, b in itertools.combinations(range(4), 2)]
        if min(d) > 6 and min(np.diff(sorted(d))) > 0.5:
            out.append(P)
    twin = out[0] + rng.normal(0, 0.3, size=(4, 3))
    return [*out, twin]


def _rotation(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def _scene(bodies, b, rng, hide: bool, ghosts: int):
    """Body ``b`` at a random pose with noise, maybe one marker hidden, ghosts in a ball around
    it; returns (points (k, 3), true marker of each point, -1 for a ghost)."""
    P = bodies[b] @ _rotation(rng).T + rng.uniform(-500, 500, 3)
    P = P + rng.normal(0, NOISE, P.shape)
    lab = np.arange(4)
    if hide:
        keep = np.sort(rng.permutation(4)[:3])
        P, lab = P[keep], lab[keep]
    c = P.mean(axis=0)
    u = rng.normal(size=(ghosts, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    G = c + u * (25 * rng.random((ghosts, 1)) ** (1 / 3))
    X = np.concatenate([P, G])
    lab = np.concatenate([lab, np.full(ghosts, -1)])
    order = rng.permutation(len(X))
    return X[order], lab[order]


def _fit_rms(model: np.ndarray, obs: np.ndarray) -> tuple[float, float]:
    """Least-squares rigid fit of ``model`` onto ``obs`` (both (k, 3)): (RMS, largest residual)."""
    mc, oc = model.mean(axis=0), obs.mean(axis=0)
    U, _, Vt = np.linalg.svd((model - mc).T @ (obs - oc))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    err = np.linalg.norm((model - mc) @ R.T + oc - obs, axis=1)
    return float(np.sqrt((err**2).mean())), float(err.max())


def _sorted_gap(model: np.ndarray, obs: np.ndarray) -> float:
    pairs = list(itertools.combinations(range(len(obs)), 2))
    a = sorted(np.linalg.norm(obs[i] - obs[j]) for i, j in pairs)
    b = sorted(np.linalg.norm(model[i] - model[j]) for i, j in pairs)
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def brute_force(bodies, X):
    """Every accepted hypothesis: (markers, rms, sides gap, body, {point: marker})."""
    out = []
    for k in range(3, len(X) + 1):
        for pts in itertools.combinations(range(len(X)), k):
            obs = X[list(pts)]
            d_obs = np.linalg.norm(obs[:, None] - obs[None], axis=2)
            for b, M in enumerate(bodies):
                for marks in itertools.permutations(range(len(M)), k):
                    Mk = M[list(marks)]
                    if (np.abs(d_obs - np.linalg.norm(Mk[:, None] - Mk[None], axis=2)) > MATCH).any():
                        continue  # the bone rule
                    rms, worst = _fit_rms(Mk, obs)
                    if rms <= RESIDUAL and worst <= MATCH:
                        out.append((k, rms, _sorted_gap(Mk, obs), b, dict(zip(pts, marks, strict=True))))
    return out


def _pipeline(lib, X):
    """The pipeline's hypotheses of one cluster, as (markers, rms, sides gap, body, {point: marker})."""
    pts = X[None]
    h = ident.hypotheses(lib, pts, MATCH, RESIDUAL)
    gap = ident.sides_key(lib, pts, h)
    return [
        (int(n), float(r), float(g), int(b), {int(p): j for j, p in enumerate(a) if p >= 0})
        for n, r, g, b, a in zip(h.n, h.rms, gap, h.body, h.assign, strict=True)
    ]


@pytest.mark.parametrize(
    "hide,ghosts",
    [(False, 0), (True, 0), pytest.param(True, 2, marks=pytest.mark.slow), pytest.param(False, 2, marks=pytest.mark.slow)],
)
def test_the_best_hypothesis_is_the_brute_forces_under_both_headline_rules(hide, ghosts):
    rng = np.random.default_rng(11 + 3 * ghosts + hide)
    bodies = _bodies(rng)
    lib = ident.build_library(bodies)
    outcomes = {"right": 0, "wrong": 0}
    for trial in range(40):
        b = trial % len(bodies)
        X, lab = _scene(bodies, b, rng, hide, ghosts)
        brute = brute_force(bodies, X)
        mine = _pipeline(lib, X)
        if not brute:
            assert not mine
            continue
        # fit: more markers, then the lowest residual (a near-tie is left alone: floating point)
        best = sorted(brute, key=lambda h: (-h[0], h[1]))
        got = min(mine, key=lambda h: (-h[0], h[1]))
        if len(best) == 1 or best[1][0] < best[0][0] or best[1][1] - best[0][1] > 1e-9:
            assert (got[3], got[4]) == (best[0][3], best[0][4])
            assert got[1] == pytest.approx(best[0][1], abs=1e-9)
        # sides: the same body on the same points (a relabelling ties: sorted distances are blind)
        bs = min(brute, key=lambda h: (-h[0], h[2]))
        gs = min(mine, key=lambda h: (-h[0], h[2]))
        close = [h for h in brute if h[0] == bs[0] and h[2] - bs[2] <= 1e-9]
        if all((h[3], set(h[4])) == (bs[3], set(bs[4])) for h in close):
            assert (gs[3], set(gs[4])) == (bs[3], set(bs[4]))
        ok = best[0][3] == b and all(lab[p] == m for p, m in best[0][4].items() if lab[p] >= 0)
        outcomes["right" if ok else "wrong"] += 1
    assert outcomes["right"] > 0


def test_ambiguous_matches_are_withheld_exactly_when_a_rival_fits_alike():
    """unambiguous() against the definition, pair by pair: a chosen match is dropped iff another
    hypothesis with as many markers shares an observed point and its misfit (negative
    log-likelihood) is within the margin of the chosen one's."""
    rng = np.random.default_rng(3)
    bodies = _bodies(rng)
    lib = ident.build_library(bodies)
    scenes = [_scene(bodies, i % len(bodies), rng, True, 2)[0] for i in range(30)]
    pts = np.stack(scenes)
    h = ident.hypotheses(lib, pts, MATCH, RESIDUAL)
    chosen = ident.resolve(h, np.arange(len(pts)), pts.shape[1], len(bodies))
    nll = ident.misfit(h, h.rms, "fit", 0.1)
    # the fit misfit is the sum of squared residuals over twice the variance
    assert np.allclose(nll, h.n * h.rms**2 / (2 * 0.1**2))
    for margin in (0.0, 0.5, 3.0):
        kept = set(ident.unambiguous(h, chosen, pts.shape[1], nll, margin).tolist())
        for i in chosen.tolist():
            mine = {(h.scene[i], p) for p in h.assign[i] if p >= 0}
            rivals = [
                j
                for j in range(len(h.scene))
                if j != i and h.n[j] == h.n[i] and mine & {(h.scene[j], p) for p in h.assign[j] if p >= 0}
            ]
            alike = margin > 0 and any(nll[j] <= nll[i] + margin for j in rivals)
            assert (i in kept) == (not alike)
    assert len(ident.unambiguous(h, chosen, pts.shape[1], nll, 3.0)) < len(chosen)  # some are withheld
