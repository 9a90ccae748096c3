"""From a spec to a verified family: enumerate, select, place, measure margins."""

from __future__ import annotations

import time

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.tetra import face_sides, vertices_from_lengths
from starforge.stars.boxes import place_stars
from starforge.stars.enumerate import Candidates, enumerate_candidates
from starforge.stars.model import Family, Star
from starforge.stars.rules import grid_steps, internal_ok, window_rows
from starforge.stars.select import select_family
from starforge.stars.spec import StarSpec


def margins(lengths: np.ndarray) -> list[dict]:
    """Per-star margins, mm, for a family of length vectors (n, 6).

    internal_mm: the smallest difference between two of the star's own six lengths.
    family_face_mm: the smallest face difference to any other face in the family (another
    star's, or another of its own), where two faces differ by the largest difference of their
    sorted sides (the face rule needs this >= tolerance).
    family_pair_mm: for the paper's rule, the smallest over other stars and relabellings of the
    largest "both lengths of one opposite pair differ" amount.
    """
    from starforge.geometry.tetra import RELABELLINGS

    L = np.asarray(lengths, dtype=float)
    n = len(L)
    srt = np.sort(L, axis=1)
    internal = np.diff(srt, axis=1).min(axis=1)
    F = face_sides(L).reshape(-1, 3)  # (4n, 3)
    owner = np.repeat(np.arange(n), 4)
    diff = np.abs(F[:, None, :] - F[None, :, :]).max(axis=2)
    np.fill_diagonal(diff, np.inf)
    face_m = np.full(n, np.inf)
    np.minimum.at(face_m, owner, diff.min(axis=1))
    pair_m = np.full(n, np.inf)
    if n > 1:
        forms = L[:, RELABELLINGS]  # (n, 24, 6)
        for i in range(n):
            # both lengths of pair k differ by min(|a_k - b_k|, |A_k - B_k|); a pair of stars is
            # told apart by the best pair; the worst relabelling decides.
            d = np.abs(forms[None, i, 0, :] - forms[:, :, :])  # (n, 24, 6)
            both = np.minimum(d[..., 0::2], d[..., 1::2]).max(axis=2)  # (n, 24)
            worst = both.min(axis=1)
            worst[i] = np.inf
            pair_m[i] = worst.min()
    return [
        {"internal_mm": float(internal[i]), "family_face_mm": float(face_m[i]), "family_pair_mm": float(pair_m[i])}
        for i in range(n)
    ]


def make_family(spec: StarSpec, progress=None, candidates: Candidates | None = None) -> Family:
    """Enumerate, select and place a family for ``spec``.

    Raises StarforgeError when no star fits, or when ``spec.count`` exceeds what is achievable
    (naming the largest family found and the proven bound).
    """
    t0 = time.perf_counter()
    cands = candidates if candidates is not None else enumerate_candidates(spec, progress=progress)
    t_enum = time.perf_counter() - t0
    m = grid_steps(spec.tol_mm, spec.delta_mm)
    ok = internal_ok(cands.index, spec.rule, m)
    index = cands.index[ok]
    volume = cands.box_volume[ok]
    if len(index) == 0:
        raise StarforgeError(
            f"no star fits: box_mm {list(spec.box_mm)} with {spec.marker_mm} mm markers and delta_mm "
            f"{spec.delta_mm} admits no tetrahedron of 6 different pool lengths (try a smaller delta_mm or a larger box)"
        )
    star_of, row, n_rows = window_rows(index, spec.rule, m, len(cands.pool_mm))
    t1 = time.perf_counter()
    pool = cands.pool_mm
    sel = select_family(index, pool, volume, star_of, row, n_rows, spec)
    t_sel = time.perf_counter() - t1
    chosen = sel.chosen
    if spec.count is not None:
        if spec.count > len(chosen):
            bound = f"; proven upper bound {sel.upper_bound}" if sel.upper_bound is not None else ""
            raise StarforgeError(
                f"count {spec.count} is not achievable: the largest family found has {len(chosen)} stars{bound}"
            )
    L = pool[index[chosen]]
    marg = margins(L)
    # most compact first, then widest margins
    tol_key = np.array([mm["family_face_mm"] if spec.rule == "face" else mm["family_pair_mm"] for mm in marg])
    order = np.lexsort((-tol_key, L.sum(axis=1), volume[chosen]))
    if spec.count is not None:
        order = order[: spec.count]
        L = L[order]
        marg = margins(L)
        order = np.arange(len(L))
    else:
        L = L[order]
        marg = [marg[i] for i in order]
    P = vertices_from_lengths(L)
    limit = spec.centre_limit_mm
    stars = []
    for i, (V, T, ext, how, fits) in enumerate(place_stars(P, limit, spec.box_method)):
        if not fits:  # cannot happen for enumerated candidates; guard the invariant loudly
            raise RuntimeError(f"internal error: selected star {L[i].tolist()} does not fit")
        stars.append(Star(id=i + 1, lengths=L[i], vertices=V, obb_extents=ext, obb_transform=T, obb_method=how, margins=marg[i]))
    info = dict(sel.info)
    timings = {k: info.pop(k) for k in list(info) if k.endswith("_s") and k != "time_limit_s"}
    enum_stats = {k: v for k, v in cands.stats.items() if k != "seconds"}
    timings.update(enumerate=round(t_enum, 3), select=round(t_sel, 3), total=round(time.perf_counter() - t0, 3))
    summary = {
        "size": len(stars),
        "rule": spec.rule,
        "select": spec.select,
        "tolerance_mm": spec.tol_mm,
        "pool_mm": [round(float(x), 9) for x in pool],
        "candidates": int(len(index)),
        "enumeration": enum_stats,
        "best_found": int(len(chosen)),
        "upper_bound": sel.upper_bound,
        "gap": (sel.upper_bound - len(chosen)) if sel.upper_bound is not None else None,
        "selection": info,
    }
    return Family(spec=spec, stars=tuple(stars), summary=summary, timings=timings)
