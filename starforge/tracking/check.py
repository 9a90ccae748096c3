"""``starforge check``: simulate what a tracker sees, identify, score, and write ``check.json``.

The document (``format: starforge.check``, version 1, all lengths mm)::

    {"identification_rate", "mislabel_rate" (flips + wrong bodies), "flip_rate",
     "wrong_body_rate", "missed_rate", "phantom_rate",
     "confusion": {"labels": [...], "matrix": B x B (true row, reported column; diagonal correct)},
     "flips": [...], "missed": [...],              per body
     "worst_pairs": [...],                          most frequent confusions in the simulation
     "closest_triangles": [...],                    smallest geometric margins (drop-1 confusions)
     "accuracy": {"tip_mm", "noise_mm", "bodies": [{"body", "markers", "tip_tre_mm",
                  "tip_tre_hidden_mm", "worst_hidden_marker", "rotation_deg"}], "family": {...}},
     "rules": {"preset", "violations": [...]},      with --preset
     "curve": {"noise_mm": [...], "identification_rate": [...], "mislabel_rate": [...]}}
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from starforge.spec import non_negative, require

FORMAT = "starforge.check"
VERSION = 1


@dataclass(frozen=True)
class CheckSettings:
    """Simulation settings.

    noise_mm : per-axis Gaussian sigma of marker centres, mm
    drop : markers hidden per body per frame (uniform 0..drop; exactly drop if drop_exact)
    ghosts : random extra points near each body per frame
    frames : simulated frames
    seed : random seed
    match_mm : distance matching window (None: the preset's, else the family tolerance, else 2 mm)
    residual_mm : rigid-fit RMS limit (None: the preset's, else match_mm / 2)
    tip_mm : (3,) target point in each body's frame for the TRE, mm (None: the family's default
        tip, :func:`starforge.geometry.rigid.default_tip_mm`; the prop's origin for placements)
    preset : vendor preset name or None
    curve_points : noise levels on the rates-vs-noise curve (0: no curve)
    curve_frames : frames per curve point (None: max(100, frames // 10))
    world : "open" (each cluster identified on its own; default) or "closed" (each label once
        per frame: assumes every body is in every frame)
    presence : probability that a body is in a frame (bodies come and go)
    """

    noise_mm: float = 0.2
    drop: int = 1
    ghosts: int = 0
    frames: int = 10000
    seed: int = 0
    match_mm: float | None = None
    residual_mm: float | None = None
    tip_mm: tuple[float, float, float] | None = None
    preset: str | None = None
    drop_exact: bool = False
    curve_points: int = 7
    curve_frames: int | None = None
    world: str = "open"
    presence: float = 1.0

    def __post_init__(self):
        require(self.world in ("open", "closed"), f"world must be open or closed, got {self.world!r}")
        require(0 < self.presence <= 1, f"presence must be in (0, 1], got {self.presence}")
        require(self.curve_points <= 50, f"curve must be at most 50 noise levels, got {self.curve_points}")
        non_negative("noise", self.noise_mm)
        require(self.drop >= 0, f"drop must be >= 0, got {self.drop}")
        require(self.ghosts >= 0, f"ghosts must be >= 0, got {self.ghosts}")
        require(self.frames >= 1, f"frames must be >= 1, got {self.frames}")
        require(self.curve_points >= 0, f"curve_points must be >= 0, got {self.curve_points}")
        if self.match_mm is not None:
            require(self.match_mm > 0, f"match must be > 0 mm, got {self.match_mm}")
        if self.residual_mm is not None:
            require(self.residual_mm > 0, f"residual must be > 0 mm, got {self.residual_mm}")


def closest_triangles(lib, window_mm: float, k: int = 10) -> list[dict]:
    """The ``k`` body pairs (a body with itself included: two of its own triangles) whose
    triangles come closest: bottleneck distance of sorted sides, mm (below ``window_mm`` only)."""
    S, tb = lib.tri_sorted, lib.tri_body
    best: dict = {}
    lo = np.searchsorted(S[:, 2], S[:, 2] - window_mm, side="left")
    hi = np.searchsorted(S[:, 2], S[:, 2] + window_mm, side="right")
    cnt = hi - lo
    q = np.repeat(np.arange(len(S)), cnt)
    j = lo[q] + (np.arange(len(q)) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    keep = j > q
    q, j = q[keep], j[keep]
    d = np.abs(S[q] - S[j]).max(axis=1)
    keep = d < window_mm
    for a, b, dv in zip(tb[q[keep]], tb[j[keep]], d[keep], strict=True):
        key = (min(a, b), max(a, b))
        if key not in best or dv < best[key]:
            best[key] = float(dv)
    rows = sorted(best.items(), key=lambda kv: kv[1])[:k]
    return [{"a": lib.names[a], "b": lib.names[b], "margin_mm": round(v, 6)} for (a, b), v in rows]


def _worst_pairs(tally, names, k: int = 10) -> list[dict]:
    n = max(tally.frames, 1)
    rows = []
    B = len(names)
    for i in range(B):
        if tally.flips[i]:
            rows.append((int(tally.flips[i]), names[i], names[i], "flip"))
        for j in range(B):
            if i != j and tally.confusion[i, j]:
                rows.append((int(tally.confusion[i, j]), names[i], names[j], "wrong body"))
    rows.sort(key=lambda r: (-r[0], r[1], r[2]))
    return [{"true": t, "reported": r, "kind": kind, "count": c, "rate": c / n} for c, t, r, kind in rows[:k]]


def resolve_windows(bodyset, s: CheckSettings, preset=None) -> tuple[float, float, bool]:
    """(match_mm, residual_mm, reflect) in effect."""
    reflect = bool(preset.tracker.reflect) if preset is not None else False
    if s.match_mm is not None:
        match = s.match_mm
    elif preset is not None:
        match = preset.tracker.match_mm
    elif bodyset.tolerance_mm is not None:
        match = float(bodyset.tolerance_mm)
    else:
        match = 2.0
    if s.residual_mm is not None:
        res = s.residual_mm
    elif preset is not None and s.match_mm is None:
        res = preset.tracker.residual_mm
    else:
        res = match / 2
    return match, res, reflect


def accuracy_report(bodyset, s: CheckSettings) -> dict:
    """Predicted accuracy of every body at the tip, with all markers and with the worst single
    marker hidden (:mod:`starforge.geometry.rigid`), and the family's worst and median."""
    from starforge.geometry.rigid import (
        fle_from_sigma,
        rotation_error_deg,
        rotation_error_hidden_deg,
        tre_hidden,
        tre_rms,
    )

    tip = np.asarray(s.tip_mm if s.tip_mm is not None else bodyset.default_tip_mm, dtype=float)
    fle = fle_from_sigma(max(s.noise_mm, 1e-12))
    rows = []
    for b in bodyset.bodies:
        P = b.points_mm
        hid = tre_hidden(P, tip, fle) if len(P) > 3 else np.full(len(P), np.inf)
        rows.append(
            {
                "body": b.name,
                "markers": len(P),
                "tip_tre_mm": float(tre_rms(P, tip, fle)),
                "tip_tre_hidden_mm": float(hid.max()),
                "worst_hidden_marker": int(hid.argmax()) + 1,
                "rotation_deg": float(rotation_error_deg(P, s.noise_mm)),
                "rotation_hidden_deg": float(rotation_error_hidden_deg(P, s.noise_mm).max())
                if len(P) > 3
                else None,
            }
        )
    allm = np.array([r["tip_tre_mm"] for r in rows])
    hidm = np.array([r["tip_tre_hidden_mm"] for r in rows])
    return {
        "tip_mm": [float(x) for x in tip],
        "tip_source": "--tip" if s.tip_mm is not None else bodyset.tip_source,
        "noise_mm": s.noise_mm,
        "bodies": rows,
        "family": {
            "tip_tre_mm_median": float(np.median(allm)),
            "tip_tre_mm_worst": float(allm.max()),
            "tip_tre_hidden_mm_median": float(np.median(hidm)),
            "tip_tre_hidden_mm_worst": float(hidm.max()),
        },
    }


def run_check(bodyset, s: CheckSettings, progress=None) -> dict:
    """The check document for ``bodyset`` (see module docstring).

    ``progress(stage, done, total)`` is called as frames are processed.
    """
    from starforge.tracking import identify as ident

    t0 = time.perf_counter()
    preset = None
    if s.preset is not None:
        from starforge.tracking.presets import load_preset

        preset = load_preset(s.preset)
    names = bodyset.names
    points = [b.points_mm for b in bodyset.bodies]
    require(
        min(len(p) for p in points) >= 3,
        f"every body needs at least 3 markers to be identified; the smallest has {min(len(p) for p in points)}",
    )
    lib = ident.build_library(points, names)
    match, res, reflect = resolve_windows(bodyset, s, preset)
    ident.check_settings(lib, s.noise_mm, s.drop, s.ghosts, s.frames, match, res)
    rng = np.random.default_rng(s.seed)
    cb = (lambda d, n: progress("frames", d, n)) if progress else None
    min_markers = preset.tracker.identify_markers if preset is not None else 3
    require(
        min_markers <= lib.counts.min() - s.drop or not s.drop_exact,
        f"drop {s.drop} leaves fewer than the {min_markers} markers the preset identifies from",
    )
    world = {"world": s.world, "presence": s.presence, "min_markers": min_markers}
    tally = ident.run(
        lib,
        s.frames,
        s.noise_mm,
        s.drop,
        s.ghosts,
        rng,
        match,
        res,
        s.drop_exact,
        reflect,
        progress=cb,
        **world,
    )
    t_main = time.perf_counter() - t0
    curve = None
    if s.curve_points > 0:
        cf = s.curve_frames if s.curve_frames is not None else max(100, s.frames // 10)
        top = max(2 * s.noise_mm, match / 2)
        levels = np.unique(np.round(np.concatenate([np.linspace(0.0, top, s.curve_points), [s.noise_mm]]), 9))
        idr, mis = [], []
        for i, nz in enumerate(levels):
            t = ident.run(
                lib, cf, float(nz), s.drop, s.ghosts, rng, match, res, s.drop_exact, reflect, **world
            )
            r = t.rates()
            idr.append(r["identification_rate"])
            mis.append(r["mislabel_rate"])
            if progress:
                progress("curve", i + 1, len(levels))
        curve = {"noise_mm": levels.tolist(), "frames": cf, "identification_rate": idr, "mislabel_rate": mis}
    acc = accuracy_report(bodyset, s)
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "units": "mm",
        "input": {"kind": bodyset.kind, "files": list(bodyset.sources), "bodies": len(names)},
        "settings": {
            "noise_mm": s.noise_mm,
            "drop": s.drop,
            "drop_mode": "exact" if s.drop_exact else "uniform 0..drop",
            "ghosts": s.ghosts,
            "frames": s.frames,
            "seed": s.seed,
            "match_mm": match,
            "residual_mm": res,
            "mirror_blind": reflect,
            "preset": s.preset,
            "world": s.world,
            "presence": s.presence,
            "identify_from_markers": min_markers,
            "tip_mm": acc["tip_mm"],
        },
        **tally.rates(),
        "instances": tally.instances,
        "confusion": {"labels": names, "matrix": tally.confusion.tolist()},
        "flips": tally.flips.tolist(),
        "missed": tally.missed.tolist(),
        "phantoms": tally.phantoms.tolist(),
        "worst_pairs": _worst_pairs(tally, names),
        "closest_triangles": closest_triangles(lib, 2 * match),
        "accuracy": acc,
    }
    if preset is not None:
        from starforge.tracking.presets import check_rules

        viol = check_rules(names, points, preset)
        doc["rules"] = {
            "preset": preset.name,
            "vendor": preset.vendor,
            "source": preset.source,
            "sources": dict(preset.sources),
            "violations": [v.to_json() for v in viol],
        }
    if curve is not None:
        doc["curve"] = curve
    doc["seconds"] = {"main": round(t_main, 3), "total": round(time.perf_counter() - t0, 3)}
    return doc
