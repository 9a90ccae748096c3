"""From a spec to a verified family: enumerate, select, place, measure margins and accuracy."""

from __future__ import annotations

import time

import numpy as np

from starforge.errors import NoStarError, StarforgeError
from starforge.geometry.rigid import (
    default_tip_mm,
    fle_from_sigma,
    rotation_error_deg,
    rotation_error_hidden_deg,
    tre_hidden,
    tre_rms,
)
from starforge.geometry.tetra import face_sides, tetra_width, vertices_from_lengths
from starforge.runtime.threads import beside
from starforge.stars.avoid import avoid_mask
from starforge.stars.bounds import block_bound
from starforge.stars.boxes import place_stars
from starforge.stars.classify import edge_pool
from starforge.stars.enumerate import Candidates, enumerate_candidates
from starforge.stars.model import Family, Star
from starforge.stars.rules import internal_ok, window_bytes, window_rows
from starforge.stars.select import (
    Selection,
    compactness_order,
    csr_rows,
    greedy,
    milp,
    node_budget,
    select_family,
)
from starforge.stars.spec import StarSpec


def margins(lengths: np.ndarray, pair: bool = True) -> list[dict]:
    """Per-star margins, mm, for a family of length vectors (n, 6).

    internal_mm: the smallest difference between two of the star's own six lengths.
    family_face_mm: the smallest face difference to any other face in the family (another
    star's, or another of its own), where two faces differ by the largest difference of their
    sorted sides (the face rule needs this >= tolerance).
    family_pair_mm: for the paper's rule, the smallest over other stars and relabellings of the
    largest "both lengths of one opposite pair differ" amount; with ``pair=False`` it is left
    out (it costs n^2 x 36 differences, which a face-rule check does not need).
    """
    L = np.asarray(lengths, dtype=float)
    n = len(L)
    srt = np.sort(L, axis=1)
    internal = np.diff(srt, axis=1).min(axis=1)
    F = face_sides(L).reshape(-1, 3)  # (4n, 3)
    owner = np.repeat(np.arange(n), 4)
    face_m = np.full(n, np.inf)
    if len(F) > 1:
        # the nearest other face in the Chebyshev metric (largest sorted-side difference)
        np.minimum.at(face_m, owner, _nearest_other_chebyshev(F))
    pair_m = _pair_margins(L) if pair and n > 1 else np.full(n, np.inf)
    out = [{"internal_mm": float(internal[i]), "family_face_mm": float(face_m[i])} for i in range(n)]
    if pair:
        for i in range(n):
            out[i]["family_pair_mm"] = float(pair_m[i])
    return out


def _pair_margins(L: np.ndarray) -> np.ndarray:
    """For each star of ``L`` (n, 6), n > 1, the paper's pair margin against the others: the
    smallest, over other stars and relabellings, of the largest "both lengths of one opposite
    pair differ" amount, mm (n,).

    A relabelling of the other star sends each opposite pair p = (2p, 2p + 1) of this star to
    one of its pairs, in one of two orientations; the 24 relabellings use only a few of these
    (pair, image, orientation) combinations, so each combination's "both differ" amount
    min(|a - b|, |A - B|) is computed once per pair of stars and the relabellings take the
    max / min of those.  Only differences, minima and maxima: the same floats as comparing
    the 24 relabelled forms one by one."""
    from starforge.geometry.tetra import RELABELLINGS

    n = len(L)
    A = L[:, RELABELLINGS[0]]  # this star as written
    combos: dict = {}  # (p, edge of the other star facing 2p, edge facing 2p + 1) -> index
    use = [
        tuple(combos.setdefault((q, int(r[2 * q]), int(r[2 * q + 1])), len(combos)) for q in range(3))
        for r in RELABELLINGS
    ]
    rows = max(1, int(2e6 // (n * 8 * (len(combos) + 2))))  # stars per block (about 2 MB: in cache)
    out = np.empty(n)
    for i0 in range(0, n, rows):
        i1 = min(n, i0 + rows)
        both = [
            np.minimum(np.abs(A[i0:i1, None, 2 * q] - L[None, :, e0]), np.abs(A[i0:i1, None, 2 * q + 1] - L[None, :, e1]))
            for q, e0, e1 in combos
        ]
        worst = None
        for c0, c1, c2 in use:
            told = np.maximum(np.maximum(both[c0], both[c1]), both[c2])  # told apart by the best pair
            worst = told if worst is None else np.minimum(worst, told)  # the worst relabelling decides
        worst[np.arange(i1 - i0), np.arange(i0, i1)] = np.inf
        out[i0:i1] = worst.min(axis=1)
    return out


#: faces up to which :func:`_nearest_other_chebyshev` compares every pair (numpy, in blocks)
#: instead of building a k-d tree (importing scipy.spatial alone costs about 0.1 s)
BRUTE_FACES = 8192


def _nearest_other_chebyshev(F: np.ndarray) -> np.ndarray:
    """For each row of F (m, 3), the Chebyshev distance to the nearest other row (the same
    numbers a k-d tree query gives: a maximum of absolute differences is exact)."""
    m = len(F)
    if m > BRUTE_FACES:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(F).query(F, k=2, p=np.inf)
        return d[:, 1]
    out = np.empty(m)
    rows = max(1, int(8e6 // (m * 8)))  # two blocks of about 8 MB of differences live at once
    for i0 in range(0, m, rows):
        i1 = min(m, i0 + rows)
        # one side at a time into one (rows, m) block: no (rows, m, 3) temporary
        d = np.abs(F[i0:i1, None, 0] - F[None, :, 0])
        for k in (1, 2):
            np.maximum(d, np.abs(F[i0:i1, None, k] - F[None, :, k]), out=d)
        d[np.arange(i1 - i0), np.arange(i0, i1)] = np.inf
        out[i0:i1] = d.min(axis=1)
    return out


def accuracy(vertices: np.ndarray, tip_mm: np.ndarray, sigma_mm: float) -> list[dict]:
    """Predicted accuracy of stars (n, 4, 3) in their placement frames, under isotropic marker
    noise ``sigma_mm`` per axis: rotation error (deg) and TRE at the tip (mm), with all four
    markers and in the worst case with one hidden."""
    fle = fle_from_sigma(sigma_mm)
    rot = np.atleast_1d(rotation_error_deg(vertices, sigma_mm))
    rot_h = rotation_error_hidden_deg(vertices, sigma_mm).max(axis=1)
    tre = np.atleast_1d(tre_rms(vertices, tip_mm, fle))
    tre_h = tre_hidden(vertices, tip_mm, fle)
    return [
        {
            "rotation_deg": float(rot[i]),
            "rotation_hidden_deg": float(rot_h[i]),
            "tip_tre_mm": float(tre[i]),
            "tip_tre_hidden_mm": float(tre_h[i].max()),
            "worst_hidden_marker": "ABCD"[int(tre_h[i].argmax())],
        }
        for i in range(len(vertices))
    ]


#: candidates per block of the ``--count`` order's accuracy scores: each block's temporaries
#: (points, inertia matrices and their inverses with each marker hidden, about 1 kB a star)
#: are freed before the next, so the order needs its scores and indices (16 bytes a candidate)
#: and one block, however many candidates there are
COUNT_BLOCK = 1 << 15


def _count_order(index: np.ndarray, pool: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Candidates from most to least accurate: worst-case rotation error with one marker hidden
    (frame-free; it drives the error at any tip away from the centroid), then pool indices.
    Scored in blocks of :data:`COUNT_BLOCK` (each star's score is its own: the same floats in
    any block)."""
    score = np.empty(len(index))
    for i0 in range(0, len(index), COUNT_BLOCK):
        P = vertices_from_lengths(pool[index[i0 : i0 + COUNT_BLOCK]])
        score[i0 : i0 + len(P)] = rotation_error_hidden_deg(P, sigma_mm).max(axis=1)
    keys = [index[:, k] for k in range(5, -1, -1)]
    return np.lexsort((*keys, np.round(score, 9)))


#: candidates the --count pick looks at: the most accurate ones
COUNT_POOL = 100_000


def _spread_count(index: np.ndarray, order: np.ndarray, spec: StarSpec, pool_size: int):
    """The ``spec.count`` most accurate stars, as far apart as the count allows.

    A few stars out of hundreds can keep their faces much further apart than the tolerance,
    which is what keeps a tracker from confusing them under noise.  Among the
    :data:`COUNT_POOL` most accurate candidates, the face separation is raised one pool step at
    a time (up to twice the tolerance) while a greedy pick in accuracy order still reaches the
    count; the largest separation that does is used.  A separation whose key windows would take
    more memory than the whole family's selection is skipped, and one set of windows is held at
    a time (when the pool is every candidate, they are the candidates' own, walked in accuracy
    order: no copy).  Returns (chosen, steps used).
    """
    m = spec.grid_steps
    every = len(order) <= COUNT_POOL
    top = order[:COUNT_POOL]
    sub, walk = (index, order) if every else (index[top], np.arange(len(top)))
    # never more memory than selecting among every candidate at the tolerance itself
    whole = window_bytes(len(index), spec.rule, m)
    for m2 in range(2 * m, m - 1, -1):
        if m2 > m and window_bytes(len(sub), spec.rule, m2) > whole:
            continue
        ptr, rows, n2 = _window_csr(sub, spec.rule, m2, pool_size)
        got = greedy(walk, ptr, rows, n2)
        del ptr, rows
        got = got if every else top[got]
        if len(got) >= spec.count or m2 == m:
            break
    if len(got) < spec.count and not every:  # even the tolerance itself is too tight among the top: use all
        ptr, rows, n2 = _window_csr(index, spec.rule, m, pool_size)
        got = greedy(order, ptr, rows, n2)
    return got, m2


def _window_csr(index: np.ndarray, rule: str, m: int, pool_size: int):
    """The key windows of ``index`` (:func:`window_rows`) as each star's rows: (ptr, rows, n_rows)."""
    s2, r2, n2 = window_rows(index, rule, m, pool_size)
    ptr, rows = csr_rows(s2, r2, len(index))
    return ptr, rows, n2


def _choose_count(index, volume, und, bound, spec: StarSpec, pool, work: int) -> Selection:
    """The ``spec.count`` selection (see :func:`_spread_count`); when the most accurate greedy
    family is too small, the largest family's stars, most accurate first.  Its memory stays
    within the whole family's: the order is scored in blocks, the separations tried take no
    more than the whole family's key windows, and the whole family's selection runs after the
    order is dropped (its stars are put in order again by the same key)."""
    order = _count_order(index, pool, spec.noise_mm)
    chosen, m_used = _spread_count(index, order, spec, len(pool))
    del order
    info = {"greedy_by_accuracy": int(len(chosen)), "face_separation_mm": round(m_used * spec.delta_mm, 9)}
    if len(chosen) >= spec.count:
        return Selection(chosen[: spec.count], bound, info)
    star_of, row, n_rows = window_rows(index, spec.rule, spec.grid_steps, len(pool))
    sel = select_family(
        index, pool, volume, star_of, row, n_rows, spec, bound=bound, n_undecided=len(und), milp_work=work
    )
    del star_of, row
    info.update(sel.info)
    if len(sel.chosen) < spec.count:
        raise StarforgeError(
            f"count {spec.count} is not achievable: the largest family found has {len(sel.chosen)} stars "
            f"(certified upper bound {sel.upper_bound}); ask for --count {len(sel.chosen)} or fewer, or raise --work"
        )
    best = np.asarray(sel.chosen)
    chosen = best[_count_order(index[best], pool, spec.noise_mm)][: spec.count]
    return Selection(chosen, sel.upper_bound, info)


def _choose(index, volume, und, bound, spec: StarSpec, pool, work: int):
    """Select the family among ``index`` (see :func:`make_family`); returns (Selection, bound)."""
    m = spec.grid_steps
    if spec.count is not None:
        sel = _choose_count(index, volume, und, bound, spec, pool, work)
    else:
        # the selection's order (numpy sorts) on a thread beside the key windows (compiled)
        order_of = beside(compactness_order, index, pool, volume)
        star_of, row, n_rows = window_rows(index, spec.rule, m, len(pool))
        sel = select_family(
            index, pool, volume, star_of, row, n_rows, spec, bound=bound, n_undecided=len(und), milp_work=work,
            order=order_of(),
        )
    ub = sel.upper_bound
    if len(und) and sel.info.get("milp_status") == "optimal" and ub > len(sel.chosen):
        # the solver proved its optimum over the stars that fit; the undecided ones may fit too,
        # so solve once more with them for a bound that covers every star that really fits
        both = np.concatenate([index, und])
        s2, r2, n2 = window_rows(both, spec.rule, m, len(pool))
        p2, rows2 = csr_rows(s2, r2, len(both))
        opt, dual, status, reproducible = milp(
            p2, rows2, n2, np.arange(len(both)), None, node_budget(len(rows2), work),
        )
        if reproducible:
            b2 = len(opt) if status == "optimal" else dual
            if b2 is not None and b2 < ub:
                ub = int(b2)
                sel.info["bound_from"] = "solver"
        sel.info["bound_solve_with_undecided"] = status
    return sel, ub


def make_family(
    spec: StarSpec,
    progress=None,
    candidates: Candidates | None = None,
    avoid_faces_mm: np.ndarray | None = None,
    avoid_sources: list[dict] | None = None,
    milp_work: int | None = None,
    star_filter=None,
    on_stage=None,
) -> Family:
    """Enumerate, select and place a family for ``spec``.

    ``avoid_faces_mm`` (k, 3): triangles of bodies the lab already owns; no face of a new star
    comes within the tolerance of one (``avoid_sources`` describes them for family.json).
    ``milp_work``: the exact solver's deterministic work budget (nonzeros x nodes; default the
    spec's ``work``).  ``star_filter(vertices (n, 4, 3)) -> (n,) bool``
    keeps only stars it accepts (e.g. whose printed body with its mount fits the limit): the
    ones it rejects are replaced by selecting again without them.  The exact solver is stopped by its
    node budget alone, never by the wall clock: the same family on any machine and at any load.  ``on_stage(name)`` is
    called as the selection (``"select"``) starts (the CLI waits there for its compile helper).

    Raises StarforgeError when no star fits, or when ``spec.count`` exceeds what is achievable
    (naming the largest family found and the certified bound).
    """
    work = spec.work if milp_work is None else int(milp_work)
    t0 = time.perf_counter()
    if candidates is None:
        from starforge.stars.estimate import check_size

        if check_size(spec, allow_stream=True) == "stream":
            return _streamed_family(spec, progress, avoid_faces_mm, avoid_sources, star_filter, t0)
    cands = candidates if candidates is not None else enumerate_candidates(spec, progress=progress)
    t_enum = time.perf_counter() - t0
    m = spec.grid_steps
    pool = cands.pool_mm
    ok = internal_ok(cands.index, spec.rule, m) & avoid_mask(cands.index, pool, avoid_faces_mm, spec.tol_mm)
    index, volume = (cands.index, cands.box_volume) if ok.all() else (cands.index[ok], cands.box_volume[ok])
    und = cands.undecided
    und = (
        und[internal_ok(und, spec.rule, m) & avoid_mask(und, pool, avoid_faces_mm, spec.tol_mm)]
        if len(und)
        else und
    )
    if len(index) == 0:
        raise _no_star(spec)
    # certified: every star that really fits is proven to fit here or undecided
    bound_set = np.concatenate([index, und]) if len(und) else index
    bound = block_bound(bound_set, m)
    if spec.count is not None and spec.count > bound:
        raise StarforgeError(
            f"count {spec.count} is not achievable: no family of this spec can hold more than {bound} stars "
            f"(certified upper bound); ask for --count {bound} or fewer, or a larger --box"
        )
    t1 = time.perf_counter()
    from starforge.runtime import progress as runtime_progress

    runtime_progress.stage("select")
    if on_stage is not None:
        on_stage("select")
    excluded = np.zeros(len(index), dtype=bool)
    rounds = 0
    while True:
        keep = np.flatnonzero(~excluded)
        kept = (index, volume) if len(keep) == len(index) else (np.take(index, keep, axis=0), volume[keep])
        sel, ub = _choose(*kept, und, bound, spec, pool, work)
        chosen = keep[np.sort(sel.chosen)]
        L = pool[index[chosen]]
        # the family's margins depend on its lengths alone: computed beside the placement
        marg_of_L = beside(margins, L) if star_filter is None else None
        placed = place_stars(vertices_from_lengths(L), spec.centre_limit_mm, spec.box_method)
        if star_filter is None:
            break
        ok = np.asarray(star_filter(np.array([item[0] for item in placed])), dtype=bool)
        rounds += 1
        if ok.all() or rounds >= 6:
            if not ok.all():  # still misfits after the rounds: leave them out
                chosen, placed = chosen[ok], [x for x, k in zip(placed, ok, strict=True) if k]
                L = pool[index[chosen]]
            break
        excluded[chosen[~ok]] = True
    sel.info["filtered_out"] = int(excluded.sum())
    if excluded.any():  # the solver's bound was over a reduced set: keep the block bound only
        ub = bound
    t_sel = time.perf_counter() - t1
    info = dict(sel.info)
    info["proven_optimal"] = bool(spec.count is None and len(chosen) >= ub)
    return _assemble(
        spec, pool, index[chosen], L, placed, info, ub, cands.stats, len(index), len(und), avoid_sources,
        {"enumerate": t_enum, "select": t_sel}, t0, marg_of_L,
    )


def _streamed_family(spec: StarSpec, progress, avoid_faces_mm, avoid_sources, star_filter, t0) -> Family:
    """:func:`make_family` for a spec whose candidates do not fit in memory: the streamed greedy
    (:mod:`starforge.stars.stream`)."""
    from starforge.stars.stream import stream_family

    if spec.count is not None or star_filter is not None:
        raise StarforgeError(
            f"{'--count' if spec.count is not None else '--mount'} needs every candidate in memory, and this "
            f"spec's do not fit (its family is selected by the streamed greedy); raise delta_mm or tolerance_mm"
        )
    res = stream_family(spec, progress=progress, avoid_faces_mm=avoid_faces_mm)
    pool = edge_pool(spec)
    index = res["index"]
    if not len(index):
        raise _no_star(spec)
    t1 = time.perf_counter()
    L = pool[index]
    placed = place_stars(vertices_from_lengths(L), spec.centre_limit_mm, spec.box_method)
    info = dict(res["info"])
    info["filtered_out"] = 0
    info["proven_optimal"] = bool(len(index) >= res["bound"])
    secs = res["seconds"]
    return _assemble(
        spec, pool, index, L, placed, info, res["bound"], res["stats"], res["candidates"], res["undecided"],
        avoid_sources, {"enumerate": secs["enumerate"], "select": secs["select"] + time.perf_counter() - t1}, t0,
    )


def _no_star(spec: StarSpec) -> NoStarError:
    return NoStarError(
        f"no star fits: box_mm {list(spec.box_mm)} with {spec.marker_mm:g} mm markers, delta_mm "
        f"{spec.delta_mm:g}, tolerance {spec.tol_mm:g} mm and min_depth_mm {spec.depth_mm:g} admits no "
        f"tetrahedron (try a smaller delta_mm, tolerance or min_depth_mm, or a larger box)"
    )


def _assemble(
    spec, pool, chosen_index, L, placed, info, ub, enum_stats, n_candidates, n_undecided, avoid_sources, secs, t0,
    margins_of_L=None,
) -> Family:
    """The family from its chosen stars (pool indices (k, 6), lengths, placements): accuracy,
    margins, ids (most accurate first) and the summary.  ``margins_of_L``: a function giving
    :func:`margins` of ``L`` in its own order (started earlier, :func:`starforge.runtime.threads.beside`);
    by default they are computed here.  (A margin is a minimum of exact differences over the
    other stars: the same floats in any order of the stars.)"""
    for i, item in enumerate(placed):
        if not item[4]:  # cannot happen for enumerated candidates; guard the invariant loudly
            raise RuntimeError(f"internal error: selected star {L[i].tolist()} does not fit")
    V = np.array([item[0] for item in placed])
    tip = np.asarray(spec.tip_mm if spec.tip_mm is not None else default_tip_mm(spec.box_mm), dtype=float)
    acc = accuracy(V, tip, spec.noise_mm)
    # most accurate first (worst-case tip error with one marker hidden), then pool indices
    keys = [chosen_index[:, k] for k in range(5, -1, -1)]
    order = np.lexsort((*keys, np.round([a["tip_tre_hidden_mm"] for a in acc], 9)))
    if margins_of_L is not None:
        of_L = margins_of_L()
        marg = [of_L[i] for i in order.tolist()]
    else:
        marg = margins(L[order])
    depth = tetra_width(L[order])
    stars = []
    for new_id, i in enumerate(order.tolist(), start=1):
        Vi, T, ext, how, _, min_ext = placed[i]
        stars.append(
            Star(
                id=new_id,
                lengths=L[i],
                vertices=Vi,
                obb_extents=ext,
                obb_transform=T,
                obb_method=how,
                margins=marg[new_id - 1],
                min_box_extents=min_ext,
                depth_mm=float(depth[new_id - 1]),
                accuracy=acc[i],
            )
        )
    timings = {k: info.pop(k) for k in list(info) if k.endswith("_s")}
    enum_stats = {k: v for k, v in enum_stats.items() if k != "seconds"}
    timings.update(
        enumerate=round(secs["enumerate"], 3), select=round(secs["select"], 3), total=round(time.perf_counter() - t0, 3)
    )
    n_chosen = len(chosen_index)
    summary = {
        "size": len(stars),
        "rule": spec.rule,
        "select": spec.select if spec.count is None else f"count {spec.count} (most accurate)",
        "tolerance_mm": spec.tol_mm,
        "min_depth_mm": spec.depth_mm,
        "pool_mm": [round(float(x), 9) for x in pool],
        "candidates": int(n_candidates),
        "undecided": int(n_undecided),
        "enumeration": enum_stats,
        "best_found": int(n_chosen) if spec.count is None else None,
        "upper_bound": ub,
        "upper_bound_basis": (
            "face-block count over every star that fits or is undecided (a superset of all fitting stars)"
            + (", tightened by the exact solver's dual bound" if info.get("bound_from") == "solver" else "")
        ),
        "gap": (ub - len(stars)) if ub is not None and spec.count is None else None,
        "optimal": bool(spec.count is None and ub is not None and len(stars) >= ub),
        "tip_mm": [float(x) for x in tip],
        "noise_mm": spec.noise_mm,
        "selection": info,
    }
    if avoid_sources:
        summary["avoid"] = avoid_sources
    return Family(spec=spec, stars=tuple(stars), summary=summary, timings=timings)
