"""Identification the way optical trackers do it, vectorised over many frames.

Pipeline (no Python loop per frame or per body):

1. **Library**: every triangle of 3 markers of every body, with the side opposite each vertex
   (a triangle is the smallest identifying unit: what is left of a 4-marker star with one
   marker hidden).  Triangles are sorted by their longest side for range look-ups.
2. **Observed triangles**: every triple of observed points whose sides all lie in the
   library's length range.
3. **Distance match**: sorted sides within ``match_mm`` of a library triangle's sorted sides
   (the bottleneck test: some vertex correspondence matches iff the sorted sides do), then
   every one of the 6 vertex correspondences whose sides match gives a hypothesis
   (body, observed point -> model marker).
4. **Rigid fit**: Kabsch on the 3 points, predict the body's other markers, take the nearest
   observed point within ``match_mm`` for each, refit on all matched points; accept when the
   RMS residual is within ``residual_mm``.
5. **Conflicts**: hypotheses ranked by (more markers, then lower RMS, or at random for a
   tracker that treats every match inside its window as equal: :data:`CHOOSE`); greedy
   acceptance, each observed point used at most once (done in parallel rounds: a hypothesis
   that is the best user of all its resources is accepted; the result equals the sequential
   greedy).  Hypotheses
   with fewer than ``min_markers`` matched markers are not reported (a vendor that identifies
   from 4-marker subsets only, like ART, never reports a 3-marker match).
6. **Worlds**: in the *open world* (the default, and what a tracker must assume when bodies
   come and go) each point cluster is identified on its own: a label may be reported on two
   clusters of one frame.  The *closed world* uses each body label at most once per frame (as
   QTM documents: one solution per body); with every body in every frame (``presence`` 1) that
   hides the confusions a body's absence exposes.  The open world is the closed world's worst
   case over which bodies are absent, so ``presence`` changes only closed-world rates.

Simulation: in every frame each body is present with probability ``presence`` and sits at a
random pose (uniform rotation), far from the others (farther than the longest library
distance, so points of two bodies never form a library distance); every marker centre gets
Gaussian noise (``noise_mm`` per axis), up to ``drop`` of its markers are hidden (uniform
0..drop, or exactly ``drop``; never so many that fewer than 3 remain: a 3-marker body is always
seen whole, since a tracker cannot identify it with a marker hidden), and ``ghosts`` random extra points appear in a ball around it
(radius: the body's radius + ``match_mm``).

Outcome per body and frame: *correct* (own label, every real point on its own marker),
*flip* (own label, a wrong correspondence: the "body flips 180 degrees" report),
*mislabel* (another body's label), *missed* (no accepted hypothesis on its points).
Flips and mislabels are both confusions.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from starforge.geometry.rigid import kabsch
from starforge.spec import non_negative, positive, require
from starforge.tracking.library import (
    Library,
    build_library,
    triangle_sides,
)
from starforge.tracking.scenes import Tally, score, simulate

_PERMS = np.array(list(itertools.permutations(range(3))), dtype=np.intp)


@dataclass(frozen=True)
class Hypotheses:
    """Accepted rigid-fit hypotheses (one row each).

    scene : (H,) int           scene (frame x body slot) the points come from
    body : (H,) int            library body claimed
    assign : (H, nmax) int     observed slot matched to each model marker, -1 if none
    n : (H,) int               matched markers
    rms : (H,) float, mm       RMS residual of the final fit
    """

    scene: np.ndarray
    body: np.ndarray
    assign: np.ndarray
    n: np.ndarray
    rms: np.ndarray


def hypotheses(
    lib: Library,
    pts: np.ndarray,
    match_mm: float,
    residual_mm: float,
    reflect: bool = False,
) -> Hypotheses:
    """Every accepted, de-duplicated hypothesis in scenes ``pts`` (S, P, 3) mm, NaN = no point."""
    S, P, _ = pts.shape
    nmax = lib.n_max
    empty = Hypotheses(
        *(np.zeros(0, dtype=int) for _ in range(2)),
        np.zeros((0, nmax), dtype=int),
        np.zeros(0, dtype=int),
        np.zeros(0),
    )
    if P < 3 or S == 0:
        return empty
    triples = np.array(list(itertools.combinations(range(P), 3)), dtype=np.intp)
    sides = triangle_sides(pts[:, triples])  # (S, t, 3)
    lo_lib = lib.tri_sorted[:, 0].min() - match_mm
    hi_lib = lib.tri_sorted[:, 2].max() + match_mm
    with np.errstate(invalid="ignore"):
        keep = (sides.min(axis=2) >= lo_lib) & (sides.max(axis=2) <= hi_lib)
    s_idx, t_idx = np.nonzero(keep)
    if len(s_idx) == 0:
        return empty
    obs = sides[s_idx, t_idx]
    osrt = np.sort(obs, axis=1)
    lo = np.searchsorted(lib.tri_sorted[:, 2], osrt[:, 2] - match_mm, side="left")
    hi = np.searchsorted(lib.tri_sorted[:, 2], osrt[:, 2] + match_mm, side="right")
    cnt = hi - lo
    q = np.repeat(np.arange(len(obs)), cnt)
    start = np.repeat(np.cumsum(cnt) - cnt, cnt)
    li = lo[q] + (np.arange(len(q)) - start)
    ok = (np.abs(osrt[q, :2] - lib.tri_sorted[li, :2]) <= match_mm).all(axis=1)
    q, li = q[ok], li[ok]
    if len(q) == 0:
        return empty
    # every vertex correspondence whose opposite sides match
    d = np.abs(obs[q][:, None, :] - lib.tri_sides[li][:, _PERMS])  # (n, 6, 3)
    qi, pi = np.nonzero((d <= match_mm).all(axis=2))
    q, li, perm = q[qi], li[qi], _PERMS[pi]
    scene = s_idx[q]
    slots = triples[t_idx[q]]  # (H, 3) observed slots of vertices 0, 1, 2
    body = lib.tri_body[li]
    markers = np.take_along_axis(lib.tri_verts[li], perm, axis=1)  # model marker of each vertex
    obs3 = pts[scene[:, None], slots]
    model_all = lib.points[body]  # (H, nmax, 3)
    mod3 = model_all[np.arange(len(scene))[:, None], markers]
    R, t = kabsch(mod3, obs3)
    if reflect:
        # three points fit their mirror image as well as themselves (they span a plane): a
        # mirror-blind tracker tries both, so every hypothesis gets its mirrored twin, the proper
        # fit reflected through the plane of the three observed points
        c = obs3.mean(axis=1)
        nrm = np.cross(obs3[:, 1] - obs3[:, 0], obs3[:, 2] - obs3[:, 0])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        M = np.eye(3) - 2.0 * nrm[:, :, None] * nrm[:, None, :]
        Rm = M @ R
        tm = np.einsum("hij,hj->hi", M, t - c) + c
        scene, slots, body, markers = (np.concatenate([x, x]) for x in (scene, slots, body, markers))
        model_all = np.concatenate([model_all, model_all])
        R, t = np.concatenate([R, Rm]), np.concatenate([t, tm])
    H = len(scene)
    pred = np.einsum("hij,hkj->hki", R, model_all) + t[:, None, :]
    assign = np.full((H, nmax), -1, dtype=np.intp)
    np.put_along_axis(assign, markers, slots, axis=1)
    scene_pts = pts[scene]  # (H, P, 3)
    used = np.zeros((H, P), dtype=bool)
    np.put_along_axis(used, slots, True, axis=1)
    seed_assign = assign.copy()
    _extend(assign, used, scene_pts, pred, model_all, match_mm)
    R0, t0 = R.copy(), t.copy()
    more = (assign >= 0).sum(axis=1) > 3  # only these gained markers: refit them
    if more.any():
        w = (assign[more] >= 0).astype(float)
        obs_m = pts[scene[more][:, None], np.maximum(assign[more], 0)]
        R[more], t[more] = kabsch(model_all[more], obs_m, w, reflect=reflect)
    n, rms, worst = _fit_errors(pts, scene, assign, model_all, R, t)
    acc = (rms <= residual_mm) & (worst <= match_mm)
    # a gained marker that breaks the fit's limits is left out again: the seed's 3-marker match
    back = ~acc & more
    if back.any():
        assign[back], R[back], t[back] = seed_assign[back], R0[back], t0[back]
        n[back], rms[back], worst[back] = _fit_errors(
            pts, scene[back], assign[back], model_all[back], R[back], t[back]
        )
        acc[back] = (rms[back] <= residual_mm) & (worst[back] <= match_mm)
    acc &= n >= 3
    scene, body, assign, n, rms = scene[acc], body[acc], assign[acc], n[acc], rms[acc]
    if len(scene) == 0:
        return empty
    key = np.concatenate([scene[:, None], body[:, None], assign], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    return Hypotheses(scene[first], body[first], assign[first], n[first], rms[first])


def _fit_errors(pts, scene, assign, model_all, R, t):
    """Matched markers, RMS residual and largest residual (mm) of hypotheses' fits ``R``, ``t``."""
    w = assign >= 0
    obs = pts[scene[:, None], np.maximum(assign, 0)]
    fit = np.einsum("hij,hkj->hki", R, np.nan_to_num(model_all)) + t[:, None, :]
    err = np.where(w, np.linalg.norm(np.nan_to_num(obs) - fit, axis=2), 0.0)
    n = w.sum(axis=1).astype(int)
    return n, np.sqrt((err**2).sum(axis=1) / np.maximum(n, 1)), err.max(axis=1)


def _extend(assign, used, scene_pts, pred, model_all, match_mm: float) -> None:
    """Add to each hypothesis the body's other markers (in place): for marker ``j``, the unused
    observed point nearest its predicted place ``pred`` (within twice the window) among those
    whose distances to every marker matched so far differ from the body's by at most
    ``match_mm``.  The final fit's limits then decide (:func:`hypotheses`).

    The distance test is QTM's bone rule: "for a marker to be included in the 6DOF body none of
    the distances to the other markers in the body may exceed the Bone tolerance" (Qualisys QTM
    manual, Calculating 6DOF data:
    https://docs.qualisys.com/qtm/content/processing_measurement/calculating_6dof_data.htm).
    """
    H, nmax = assign.shape
    rows = np.arange(H)
    d_mod = np.linalg.norm(model_all[:, :, None] - model_all[:, None, :], axis=3)  # (H, nmax, nmax)
    for j in range(nmax):
        todo = (assign[:, j] < 0) & ~np.isnan(model_all[:, j, 0])
        if not todo.any():
            continue
        kept = assign >= 0
        obs_kept = scene_pts[rows[:, None], np.maximum(assign, 0)]  # (H, nmax, 3)
        d_obs = np.linalg.norm(scene_pts[:, :, None] - obs_kept[:, None, :], axis=3)  # (H, P, nmax)
        with np.errstate(invalid="ignore"):
            off = (np.abs(d_obs - d_mod[:, j][:, None, :]) > match_mm) & kept[:, None, :]
        dist = np.linalg.norm(scene_pts - pred[:, j][:, None, :], axis=2)  # (H, P)
        dist = np.where(np.isnan(dist) | used | off.any(axis=2), np.inf, dist)
        k = dist.argmin(axis=1)
        hit = todo & (dist[rows, k] <= 2.0 * match_mm)
        assign[hit, j] = k[hit]
        used[hit, k[hit]] = True


def resolve(
    h: Hypotheses, frame_of_scene: np.ndarray, n_points: int, n_bodies: int, key: np.ndarray | None = None
) -> np.ndarray:
    """Indices of the hypotheses a tracker reports: greedy by (more markers, then ``key``,
    lowest first; default the RMS residual), each observed point (``scene * n_points + slot``)
    and each (group, body label) used once.

    ``frame_of_scene`` groups the scenes whose labels exclude each other: the frame in the
    closed world, the scene itself in the open world (each cluster on its own).  A tracker that
    cannot rank matches inside its window passes a random ``key`` (see :data:`CHOOSE`)."""
    H = len(h.scene)
    if H == 0:
        return np.zeros(0, dtype=np.intp)
    order = np.lexsort((h.rms if key is None else key, -h.n))
    rank = np.empty(H, dtype=np.int64)
    rank[order] = np.arange(H)
    pt = np.where(h.assign >= 0, h.scene[:, None] * n_points + h.assign, -1)
    n_pt = int(frame_of_scene.size) * n_points
    lab = n_pt + frame_of_scene[h.scene] * n_bodies + h.body
    res = np.concatenate([pt, lab[:, None]], axis=1)  # (H, nmax + 1), -1 = none
    valid = res >= 0
    res_c = np.where(valid, res, 0)
    n_res = n_pt + (int(frame_of_scene.max()) + 1) * n_bodies
    alive = np.ones(H, dtype=bool)
    accepted = np.zeros(H, dtype=bool)
    big = np.iinfo(np.int64).max
    while alive.any():
        best = np.full(n_res, big, dtype=np.int64)
        m = valid & alive[:, None]
        np.minimum.at(best, res_c[m], np.broadcast_to(rank[:, None], res.shape)[m])
        win = alive & np.where(valid, best[res_c] == rank[:, None], True).all(axis=1)
        accepted |= win
        taken = np.zeros(n_res, dtype=bool)
        taken[res_c[valid & win[:, None]]] = True
        alive &= ~win & ~np.where(valid, taken[res_c], False).any(axis=1)
    return np.flatnonzero(accepted)


def unambiguous(
    h: Hypotheses, chosen: np.ndarray, n_points: int, nll: np.ndarray, margin: float
) -> np.ndarray:
    """The hypotheses of ``chosen`` that no rival makes ambiguous: a rival is another hypothesis
    with as many markers that shares an observed point with it; a chosen match is kept only
    when every rival's ``nll`` (its misfit as a negative log-likelihood, :func:`misfit`)
    exceeds its own by more than ``margin`` (the log of the likelihood ratio the tracker
    demands).  A tracker that cannot tell two explanations of the same points apart reports
    neither: a missed frame instead of a wrong body or a wrong pose (the ghost that completes a
    wrong triangle from two real markers fits about as well as the right one).  ``margin`` <= 0
    keeps every chosen one."""
    if margin <= 0.0 or len(chosen) == 0:
        return chosen
    H = len(h.scene)
    pt = np.where(h.assign >= 0, h.scene[:, None] * n_points + h.assign, -1)
    ok = np.ones(H, dtype=bool)
    n_res = int(pt.max()) + 1
    for k in np.unique(h.n[chosen]):
        members = np.flatnonzero(h.n == k)
        rows = pt[members]
        valid = rows >= 0
        ids = np.broadcast_to(members[:, None], rows.shape)[valid]
        res = rows[valid]
        vals = nll[ids]
        # the two smallest values per observed point, and who holds the smallest
        order = np.lexsort((vals, res))
        res_s, vals_s, ids_s = res[order], vals[order], ids[order]
        first = np.ones(len(res_s), dtype=bool)
        first[1:] = res_s[1:] != res_s[:-1]
        best1 = np.full(n_res, np.inf)
        who1 = np.full(n_res, -1)
        best1[res_s[first]] = vals_s[first]
        who1[res_s[first]] = ids_s[first]
        second = np.zeros(len(res_s), dtype=bool)
        second[1:] = ~first[1:] & first[:-1]
        best2 = np.full(n_res, np.inf)
        best2[res_s[second]] = vals_s[second]
        mine = chosen[h.n[chosen] == k]
        r = pt[mine]
        v = r >= 0
        rc = np.where(v, r, 0)
        rival = np.where(v, np.where(who1[rc] == mine[:, None], best2[rc], best1[rc]), np.inf).min(axis=1)
        ok[mine] = rival > nll[mine] + margin
    return chosen[ok[chosen]]


def check_settings(
    lib: Library, noise_mm: float, drop: int, ghosts: int, frames: int, match_mm: float, residual_mm: float
) -> None:
    """Validate simulation settings with one-line errors naming the parameter and range."""
    non_negative("noise", noise_mm)
    require(isinstance(drop, int | np.integer) and drop >= 0, f"drop must be an integer >= 0, got {drop}")
    most = int(lib.counts.max()) - 3
    require(
        drop <= most,
        f"drop must be <= markers - 3 = {most} (the largest body has {int(lib.counts.max())} markers and "
        f"a tracker needs 3 to identify it), got {drop}",
    )
    require(
        isinstance(ghosts, int | np.integer) and ghosts >= 0, f"ghosts must be an integer >= 0, got {ghosts}"
    )
    require(
        ghosts <= MAX_GHOSTS,
        f"ghosts must be at most {MAX_GHOSTS} per body and frame (a cluster with more stray points is not a "
        f"rigid body a tracker could identify), got {ghosts}",
    )
    require(
        isinstance(frames, int | np.integer) and frames >= 1, f"frames must be an integer >= 1, got {frames}"
    )
    require(frames <= MAX_FRAMES, f"frames must be at most {MAX_FRAMES:,}, got {frames:,}")
    positive("match_mm", match_mm)
    positive("residual_mm", residual_mm)
    from starforge.runtime.budget import format_seconds, require_memory, require_time

    per_scene, seconds = cost(lib, ghosts, match_mm)
    require_memory(
        per_scene * 64, f"one cluster of {int(lib.n_max)} markers and {ghosts} ghosts", "lower --ghosts"
    )
    require_time(
        seconds * frames * lib.n_bodies,
        f"{frames:,} frames of {lib.n_bodies} bodies (about {format_seconds(seconds * lib.n_bodies)} per frame)",
        "lower --frames or --ghosts",
    )


#: how a tracker picks among a cluster's accepted matches with equally many markers (every one
#: of them passed the distance gate and the residual limit first)
CHOOSE = {
    "fit": "gate every distance by the window, then the best rigid fit",
    "sides": "gate by the window, then the smallest sorted-distance difference (blind to which marker is which)",
    "window": "stress model: every match inside the window counts the same, one is taken at random",
}
#: the rules a vendor's documentation or public code shows; ``check``'s headline is the worst
#: of these (:data:`RULE_SOURCES`)
HEADLINE_RULES = ("fit", "sides")
#: stress models no tracker documents: reported apart, never the headline
STRESS_RULES = ("window",)
#: every rule ``check`` simulates on the same frames
RULES = HEADLINE_RULES + STRESS_RULES
#: where each headline rule comes from
RULE_SOURCES = {
    "fit": (
        "Qualisys QTM: a marker joins a body only if none of its distances to the body's other markers is "
        "outside the Bone tolerance, and 6DOF data is reported only under the Max residual "
        "(https://docs.qualisys.com/qtm/content/processing_measurement/calculating_6dof_data.htm); OptiTrack "
        "Motive: Deflection, the distance a marker may deviate from its expected position "
        "(https://v110.wiki.optitrack.com/index.php?title=Rigid_Body_Properties); NDI Polaris: marker solutions "
        "are matched to the tools' known geometry, a bad transformation fit is rejected "
        "(https://www.manualslib.com/manual/3087896/Northern-Digital-Polaris-Vicra.html?page=50); Atracsys "
        "fusionTrack: matching tolerance on every fiducial distance, then a least-squares registration error "
        "(https://manualshive.com/ru/manual/atracsys/fusiontrack-500/3005017?page=43)"
    ),
    "sides": (
        "lab code that identifies a body by comparing its measured inter-marker distances (scipy pdist) with "
        "the known ones within an epsilon, without a rigid fit, as public motion-capture scripts do"
    ),
}


def sides_key(lib: Library, pts: np.ndarray, h: Hypotheses, chunk: int = 20000) -> np.ndarray:
    """For each hypothesis, the largest difference between the sorted distances among its
    matched observed points and the sorted distances among the model markers they are matched
    to, mm: how a tracker that compares sorted side lengths scores a match (blind to which
    marker is which, so a flip scores like the right correspondence)."""
    H = len(h.scene)
    out = np.zeros(H)
    nmax = lib.n_max
    iu = np.triu_indices(nmax, 1)
    for a in range(0, H, chunk):
        sl = slice(a, min(a + chunk, H))
        asg = h.assign[sl]
        ok = asg >= 0
        obs = pts[h.scene[sl][:, None], np.maximum(asg, 0)]  # (h, nmax, 3)
        mod = lib.points[h.body[sl]]
        both = ok[:, :, None] & ok[:, None, :]
        do = np.linalg.norm(obs[:, :, None] - obs[:, None, :], axis=3)[:, iu[0], iu[1]]
        dm = np.linalg.norm(mod[:, :, None] - mod[:, None, :], axis=3)[:, iu[0], iu[1]]
        m = both[:, iu[0], iu[1]]
        # unmatched pairs sort last in both (the same count per row) and compare as equal
        big = np.finfo(float).max
        do = np.sort(np.where(m, do, big), axis=1)
        dm = np.sort(np.where(m, np.nan_to_num(dm, nan=big), big), axis=1)
        out[sl] = np.abs(do - dm).max(axis=1)
    return out


#: ``check``'s ambiguity for the headline rules (:func:`unambiguous`): a chosen match is reported
#: only when it is at least this many times as likely as every rival explanation of its points with
#: as many markers, under Gaussian noise of the tracker's assumed size (:func:`misfit`;
#: :func:`run_rules` withholds nothing unless asked).  A likelihood ratio rather than a ratio of
#: residuals: two fits that both lie well inside the noise are not told apart by which is smaller.
AMBIGUITY = 20.0

#: the smallest noise (mm) the ambiguity test assumes: a noise-free simulation still ranks fits
NOISE_FLOOR_MM = 1e-3


def misfit(h: Hypotheses, value: np.ndarray, rule: str, noise_mm: float) -> np.ndarray:
    """Each hypothesis' misfit as a negative log-likelihood under Gaussian noise of ``noise_mm``
    per axis, up to a constant shared by rivals with as many markers: for ``fit`` the squared
    residuals of the rigid fit, ``n rms^2 / (2 sigma^2)``; for ``sides`` the largest sorted-
    distance difference ``value`` (a distance carries the noise of two points, variance
    ``2 sigma^2``), ``value^2 / (4 sigma^2)``."""
    var = max(float(noise_mm), NOISE_FLOOR_MM) ** 2
    if rule == "sides":
        return value**2 / (4.0 * var)
    return h.n * h.rms**2 / (2.0 * var)

#: caps on what ``check`` simulates, whatever the machine
MAX_GHOSTS = 20
MAX_FRAMES = 10_000_000


def cost(lib: Library, ghosts: int, match_mm: float) -> tuple[float, float]:
    """Candidate (observed triangle, library triangle) pairs one cluster creates, and the
    estimated seconds to identify one cluster (measured: about 2 us per pair plus 20 us)."""
    span = float(np.ptp(lib.tri_sorted[:, 2])) + 1e-9
    density = min(len(lib.tri_body), len(lib.tri_body) * 2 * match_mm / span + 1)
    pairs = math.comb(lib.n_max + ghosts, 3) * density
    return pairs, 20e-6 + 2e-6 * pairs


def run(
    lib: Library,
    n_frames: int,
    noise_mm: float,
    drop: int,
    ghosts: int,
    rng: np.random.Generator,
    match_mm: float,
    residual_mm: float,
    drop_exact: bool = False,
    reflect: bool = False,
    chunk_scenes: int = 20000,
    progress=None,
    world: str = "open",
    presence: float = 1.0,
    min_markers: int = 3,
    choose: str = "fit",
    ambiguity: float | None = None,
) -> Tally:
    """Simulate ``n_frames`` frames and identify them; returns the :class:`Tally`.

    ``world``: "open" (each cluster on its own) or "closed" (each label once per frame);
    ``presence``: probability that a body is in a frame; ``min_markers``: matched markers a
    reported identification needs; ``choose``: how a cluster's accepted matches with equally
    many markers are ranked (:data:`CHOOSE`).  ``progress(done_frames, total_frames)`` after
    each batch.
    """
    return run_rules(
        lib,
        n_frames,
        noise_mm,
        drop,
        ghosts,
        rng,
        match_mm,
        residual_mm,
        drop_exact,
        reflect,
        chunk_scenes,
        progress,
        world,
        presence,
        min_markers,
        (choose,),
        ambiguity,
    )[choose]


def run_rules(
    lib: Library,
    n_frames: int,
    noise_mm: float,
    drop: int,
    ghosts: int,
    rng: np.random.Generator,
    match_mm: float,
    residual_mm: float,
    drop_exact: bool = False,
    reflect: bool = False,
    chunk_scenes: int = 20000,
    progress=None,
    world: str = "open",
    presence: float = 1.0,
    min_markers: int = 3,
    rules=RULES,
    ambiguity: float | None = None,
    assumed_noise_mm: float | None = None,
) -> dict[str, Tally]:
    """As :func:`run`, identifying the same simulated frames under each ranking rule of
    ``rules`` (:data:`CHOOSE`): {rule: Tally}.  The frames and hypotheses are shared, only the
    choice among a cluster's accepted matches differs.  ``assumed_noise_mm``: the noise the
    tracker's ambiguity test assumes (:func:`misfit`; None: ``noise_mm``)."""
    check_settings(lib, noise_mm, drop, ghosts, n_frames, match_mm, residual_mm)
    require(world in ("open", "closed"), f"world must be open or closed, got {world!r}")
    require(0.0 < presence <= 1.0, f"presence must be in (0, 1], got {presence}")
    require(3 <= min_markers, f"min_markers must be >= 3, got {min_markers}")
    rules = tuple(rules)
    margin = 0.0 if ambiguity is None else math.log(float(ambiguity))
    assumed = noise_mm if assumed_noise_mm is None else assumed_noise_mm
    for choose in rules:
        require(choose in CHOOSE, f"choose must be one of {', '.join(CHOOSE)}, got {choose!r}")
    B = lib.n_bodies
    # bound the candidate (observed triangle, library triangle) pairs per batch to ~4 million
    pairs, _ = cost(lib, ghosts, match_mm)
    scenes = int(np.clip(4e6 / max(pairs, 1.0), 1, chunk_scenes))
    per = max(1, scenes // B)
    tallies = {r: Tally(B) for r in rules}
    done = 0
    while done < n_frames:
        f = min(per, n_frames - done)
        sc = simulate(lib, f, noise_mm, drop, ghosts, rng, match_mm, drop_exact, presence=presence)
        h = hypotheses(lib, sc.pts, match_mm, residual_mm, reflect)
        if min_markers > 3:
            keep = h.n >= min_markers
            h = Hypotheses(h.scene[keep], h.body[keep], h.assign[keep], h.n[keep], h.rms[keep])
        group = sc.frame if world == "closed" else np.arange(len(sc.body))
        random_key = rng.random(len(h.scene))
        for choose in rules:
            value = h.rms
            if choose == "window":
                key = random_key
            elif choose == "sides":
                # sorted-side difference first, ties (a flip scores like the right match) at random
                value = sides_key(lib, sc.pts, h)
                key = np.argsort(np.lexsort((random_key, value))).astype(float)
            else:
                key = None
            chosen = resolve(h, group, sc.pts.shape[1], B, key)
            if choose != "window":
                kept = unambiguous(h, chosen, sc.pts.shape[1], misfit(h, value, choose, assumed), margin)
                tallies[choose].withheld += len(chosen) - len(kept)
                chosen = kept
            score(sc, h, chosen, tallies[choose])
            tallies[choose].frames += f
        done += f
        if progress is not None:
            progress(done, n_frames)
    return tallies


def self_matches(points_mm: np.ndarray, match_mm: float, residual_mm: float, reflect: bool = False):
    """Wrong correspondences of a body onto itself that a tracker would accept (noise-free).

    Returns a list of ``(rms_mm, assign)`` for every accepted non-identity correspondence that
    uses all markers, best first; empty for a body that cannot flip.
    """
    lib = build_library([points_mm])
    pts = np.asarray(points_mm, dtype=float)[None]
    h = hypotheses(lib, pts, match_mm, residual_mm, reflect)
    n = len(points_mm)
    out = []
    for a, k, r in zip(h.assign, h.n, h.rms, strict=True):
        if k == n and not np.array_equal(a, np.arange(n)):
            out.append((float(r), a.copy()))
    return sorted(out, key=lambda x: x[0])
