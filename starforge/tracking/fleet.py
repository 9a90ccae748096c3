"""A fleet of bodies (props, copies of one airframe) checked as a tracker sees them from the
fewest markers it identifies from.

:func:`closest_pairs` finds, for every body, the other body whose marker triangles come closest
(the bottleneck distance of sorted sides, :func:`starforge.tracking.identify.close_triangle_pairs`);
:func:`fleet_report` adds each body's own margin (:func:`starforge.tracking.library.drop1_margin_mm`
of the body alone: its triangles against each other and relabelled) and the ``starforge check``
simulation (:func:`starforge.tracking.check.run_check`) with exactly three markers of every body
seen, under every headline rule, at the tracker's window for the noise (or the preset's).
"""

from __future__ import annotations

import math

import numpy as np

from starforge.tracking.bodies import Body, BodySet
from starforge.tracking.check import CheckSettings, run_check
from starforge.tracking.library import Library, build_library, close_triangle_pairs, drop1_margin_mm


def closest_pairs(lib: Library, start_mm: float = 2.0) -> list[tuple[int, float]]:
    """For every body of ``lib``: ``(other body, margin mm)``, the body whose triangles come
    closest to its own and how close (``(-1, inf)`` for a lone body).  The search window starts
    at ``start_mm`` and doubles until every body has met another (or it spans every side)."""
    B = lib.n_bodies
    best = [(-1, math.inf)] * B
    if B < 2:
        return best
    top = 2.0 * float(lib.tri_sorted[:, 2].max()) + 1.0
    window = max(start_mm, 1e-3)
    while True:
        qi, qj, d = close_triangle_pairs(lib, window)
        a, b = lib.tri_body[qi], lib.tri_body[qj]
        other = a != b
        best = [(-1, math.inf)] * B
        for x, y, v in zip(a[other], b[other], d[other], strict=True):
            for p, q in ((x, y), (y, x)):
                if v < best[p][1]:
                    best[p] = (int(q), float(v))
        if all(k >= 0 for k, _ in best) or window > top:
            return best
        window *= 2.0


def fleet_report(
    names, points_mm, noise_mm: float = 0.2, preset: str | None = None, frames: int = 2000, seed: int = 0
) -> dict:
    """The fleet's margins and its ``check`` with exactly 3 markers of every body seen.

    Parameters
    ----------
    names : list of str
        One per body, distinct.
    points_mm : list of (n_i, 3) float, mm
        Marker centres of each body (n_i >= 3).
    noise_mm, preset, frames, seed
        As ``starforge check`` takes them (the window: the preset's, else the one starforge
        writes into vendor files for these bodies at this noise).

    Returns
    -------
    dict
        ``window_mm``, ``residual_mm``, ``window_source``, ``headline_rule``, ``wrong_rate``
        (wrong body + wrong pose, the headline), ``by_rule`` ({rule: wrong_body_rate,
        flip_rate, identification_rate}), ``bodies`` (per body: ``self_margin_mm``,
        ``closest``, ``closest_margin_mm``, ``wrong_rate``, ``flip_rate``, ``wrong_body_rate``
        under the headline rule), ``closest_pair`` (``a``, ``b``, ``margin_mm``) and ``worst``
        (the body with the highest wrong rate).
    """
    pts = [np.asarray(p, dtype=float).reshape(-1, 3) for p in points_mm]
    bodies = tuple(Body(str(n), i + 1, p) for i, (n, p) in enumerate(zip(names, pts, strict=True)))
    nmax = max(len(p) for p in pts)
    settings = CheckSettings(
        noise_mm=noise_mm,
        drop=nmax - 3,
        drop_exact=True,
        frames=frames,
        seed=seed,
        preset=preset,
        curve_points=0,
    )
    doc = run_check(BodySet("placement", (), bodies), settings)
    lib = build_library(pts, [b.name for b in bodies])
    near = closest_pairs(lib)
    conf = np.asarray(doc["confusion"]["matrix"], dtype=float)
    flips = np.asarray(doc["flips"], dtype=float)
    n = max(1, frames)
    rows = []
    for i, b in enumerate(bodies):
        wrong_body = (conf[i].sum() - conf[i, i]) / n
        rows.append({
            "name": b.name,
            "markers": len(b.points_mm),
            "self_margin_mm": float(drop1_margin_mm(build_library([b.points_mm]))),
            "closest": bodies[near[i][0]].name if near[i][0] >= 0 else None,
            "closest_margin_mm": near[i][1],
            "wrong_body_rate": float(wrong_body),
            "flip_rate": float(flips[i] / n),
            "wrong_rate": float(wrong_body + flips[i] / n),
        })  # fmt: skip
    pair = min(range(len(rows)), key=lambda i: (rows[i]["closest_margin_mm"], i))
    worst = max(range(len(rows)), key=lambda i: (rows[i]["wrong_rate"], -i))
    return {
        "noise_mm": noise_mm,
        "frames": frames,
        "markers_seen": 3,
        "window_mm": doc["settings"]["match_mm"],
        "residual_mm": doc["settings"]["residual_mm"],
        "window_source": doc["settings"]["window_source"],
        "headline_rule": doc["headline_rule"],
        "wrong_rate": doc["mislabel_rate"],
        "by_rule": {
            r: {k: v[k] for k in ("identification_rate", "wrong_body_rate", "flip_rate", "mislabel_rate")}
            for r, v in doc["by_rule"].items()
        },
        "bodies": rows,
        "closest_pair": {
            "a": rows[pair]["name"],
            "b": rows[pair]["closest"],
            "margin_mm": rows[pair]["closest_margin_mm"],
        },  # fmt: skip
        "worst": {"name": rows[worst]["name"], "wrong_rate": rows[worst]["wrong_rate"]},
    }
