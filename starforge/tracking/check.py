"""``starforge check``: simulate what a tracker sees, identify, score, and write ``check.json``.

The document (``format: starforge.check``, version 1, all lengths mm)::

    {"input": {"kind", "files", "bodies", "notes"},
     "settings": {... every setting a rate depends on: noise, drop (mode), ghosts, frames, seed,
                  match_mm / residual_mm and where they come from, world, presence,
                  identify_from_markers, choose, preset, tip_mm},
     "identification_rate", "mislabel_rate" (wrong poses + wrong bodies), "flip_rate" (wrong
     pose: the right body with its labels swapped), "wrong_body_rate", "missed_rate",
     "phantom_rate", "withheld_rate" (part of the missed: ambiguous matches withheld)
                                                   the headline: under ``headline_rule``, the worst
                                                   of the headline rules (or ``--choose``'s),
     "headline_means", "headline_rules", "safe_under" (headline rules with no wrong body or pose),
     "by_rule": {rule: {rates, "means", "kind" (headline or stress), "source"}}, same frames,
     "confusion": {"labels": [...], "matrix": B x B (true row, reported column; diagonal correct)},
     "flips": [...], "missed": [...],              per body
     "worst_pairs": [...],                          most frequent confusions in the simulation
     "closest_triangles": [...],                    smallest geometric margins (drop-1 confusions)
     "drop1_margin_mm",                             the smallest of them (and of own-triangle flips)
     "accuracy": {"tip_mm" (or null: per body), "tip_source", "noise_mm",
                  "bodies": [{"body", "markers", "tip_mm", "tip_tre_mm", "tip_tre_hidden_mm",
                              "worst_hidden_marker", "rotation_deg", "rotation_hidden_deg"}],
                  "family": {median and worst, all markers and worst one hidden}},
     "rules": {"preset", "window_mm", "violations": [...]},   with --preset
     "curve": {"rule" (the headline's), "noise_mm": [...], "identification_rate": [...],
               "mislabel_rate": [...]}}
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from starforge.spec import non_negative, require
from starforge.stars.spec import MAX_NOISE_MM

FORMAT = "starforge.check"
VERSION = 1


#: largest marker noise a check simulates, mm (a tracker's noise is well under a millimetre)
#: the largest matching window and rigid-fit limit accepted, mm: a window wider than any marker
#: body matches every triangle to every other (and their pairs fill memory)
MAX_WINDOW_MM = 100.0


@dataclass(frozen=True)
class CheckSettings:
    """Simulation settings.

    noise_mm : per-axis Gaussian sigma of marker centres, mm
    drop : markers hidden per body per frame (uniform 0..drop; exactly drop if drop_exact)
    ghosts : random extra points near each body per frame
    frames : simulated frames
    seed : random seed
    match_mm : distance matching window (None: a fixed-window preset's, else the bone-length
        tolerance written into vendor files: :func:`resolve_windows`)
    residual_mm : rigid-fit RMS limit (None: a fixed-window preset's, else the maximum residual
        written into vendor files)
    tip_mm : (3,) target point in each body's frame for the TRE, mm (None: the family's default
        tip, :func:`starforge.geometry.rigid.default_tip_mm`; the prop's origin for placements)
    preset : vendor preset name or None
    curve_points : noise levels on the rates-vs-noise curve (0: no curve)
    curve_frames : frames per curve point (None: max(100, frames // 10))
    world : "open" (each cluster identified on its own; default) or "closed" (each label once
        per frame: assumes every body is in every frame)
    presence : probability that a body is in a frame (bodies come and go)
    ambiguity : a headline rule reports a match only when it is this many times as likely as
        every rival explanation of its points with as many markers, under Gaussian noise of
        ``noise_mm`` (:func:`starforge.tracking.identify.unambiguous`; 1: never withheld); None:
        :data:`starforge.tracking.identify.AMBIGUITY`
    choose : simulate one ranking rule only (:data:`starforge.tracking.identify.CHOOSE`: ``fit``,
        ``sides`` or the stress model ``window``); None: every rule, headlined by the worst
        headline rule
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
    choose: str | None = None
    ambiguity: float | None = None

    def __post_init__(self):
        from starforge.tracking.identify import CHOOSE

        if self.choose is not None:
            require(self.choose in CHOOSE, f"choose must be one of {', '.join(CHOOSE)}, got {self.choose!r}")
        require(self.world in ("open", "closed"), f"world must be open or closed, got {self.world!r}")
        require(0 < self.presence <= 1, f"presence must be in (0, 1], got {self.presence}")
        require(
            0 <= self.curve_points <= 50,
            f"curve must be in [0, 50] noise levels (0: no curve), got {self.curve_points}",
        )
        non_negative("noise", self.noise_mm)
        require(
            self.noise_mm <= MAX_NOISE_MM,
            f"noise must be at most {MAX_NOISE_MM:g} mm (sigma per axis), got {self.noise_mm:g}",
        )
        require(self.drop >= 0, f"drop must be >= 0, got {self.drop}")
        require(self.ghosts >= 0, f"ghosts must be >= 0, got {self.ghosts}")
        require(self.frames >= 1, f"frames must be >= 1, got {self.frames}")
        if self.ambiguity is not None:
            require(
                1.0 <= self.ambiguity <= 1e6,
                f"ambiguity must be in [1, 1000000] (1: report the best match however close a rival), "
                f"got {self.ambiguity}",
            )
        if self.match_mm is not None:
            require(0 < self.match_mm <= MAX_WINDOW_MM, f"match must be in (0, {MAX_WINDOW_MM:g}] mm, got {self.match_mm:g}")
        if self.residual_mm is not None:
            require(
                0 < self.residual_mm <= MAX_WINDOW_MM,
                f"residual must be in (0, {MAX_WINDOW_MM:g}] mm, got {self.residual_mm:g}",
            )


def closest_triangles(lib, window_mm: float, k: int = 10) -> list[dict]:
    """The ``k`` body pairs (a body with itself included: two of its own triangles) whose
    triangles come closest: bottleneck distance of sorted sides, mm (below ``window_mm`` only)."""
    from starforge.tracking.library import close_triangle_pairs

    qi, qj, d = close_triangle_pairs(lib, window_mm)
    best: dict = {}
    for a, b, dv in zip(lib.tri_body[qi], lib.tri_body[qj], d, strict=True):
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


def resolve_windows(bodyset, s: CheckSettings, preset=None) -> dict:
    """The tracker in effect: ``match_mm``, ``residual_mm``, ``reflect``, ``choose``,
    ``min_markers`` and where the window comes from (``window_source``).

    The window is ``--match`` if given, else the preset's (fixed, or for QTM, NDI and Motive
    the tolerance starforge writes into vendor files for these bodies), else that tolerance
    itself: the bone-length tolerance and residual limit of
    :func:`starforge.tracking.tolerances.export_tolerances` at the simulated noise, so that
    ``check`` simulates the gates the lab's files carry.  The residual limit is ``--residual``,
    else the preset's (fixed presets), else the one written into the files.
    """
    from starforge.tracking.tolerances import export_tolerances

    reflect = bool(preset.tracker.reflect) if preset is not None else False
    choose = s.choose or (preset.tracker.choose if preset is not None else "fit")
    res = None
    written = None
    if s.match_mm is None or s.residual_mm is None:
        written = export_tolerances([b.points_mm for b in bodyset.bodies], s.noise_mm)
    if s.match_mm is not None:
        match, source = s.match_mm, "--match"
    elif preset is not None and preset.tracker.window == "fixed":
        match, res, source = preset.tracker.match_mm, preset.tracker.residual_mm, f"preset {preset.name}"
    else:
        match, res = written["bone_length_tolerance_mm"], written["maximum_residual_mm"]
        what = {
            "qtm_export": "the BoneLengthTolerance and MaximumResidual starforge writes into QTM files",
            "rom_export": "the maximum marker error starforge writes into NDI .rom files (residual) and the same "
            "distance tolerance (NDI's window is not published)",
        }.get(
            preset.tracker.window if preset is not None else "",
            "the bone tolerance and residual limit starforge writes into vendor files",
        )
        who = f"preset {preset.name}: " if preset is not None else ""
        source = (
            f"{who}{what} for these bodies at {s.noise_mm:g} mm noise (half their smallest key margin "
            f"{written['margin_mm']:g} mm, at least {written['bone_from_noise_mm']:.3g} mm for the noise)"
        )
    if s.residual_mm is not None:
        res = s.residual_mm
    elif res is None:
        res = written["maximum_residual_mm"] if written is not None else match / 2
    return {
        "match_mm": float(match),
        "residual_mm": float(res),
        "reflect": reflect,
        "choose": choose,
        "min_markers": preset.tracker.identify_markers if preset is not None else 3,
        "window_source": source,
        "margin_mm": float(written["margin_mm"]) if written is not None else None,
    }


def headline_rule(by_rule: dict, rules) -> str:
    """The rule ``check`` headlines: the worst (lowest identification, then most wrong bodies
    and poses) of the headline rules simulated, or of ``rules`` when none is (``--choose``)."""
    from starforge.tracking.identify import HEADLINE_RULES

    pool = [r for r in rules if r in HEADLINE_RULES] or list(rules)
    return min(pool, key=lambda r: (by_rule[r]["identification_rate"], -by_rule[r]["mislabel_rate"]))


def safe_rules(by_rule: dict) -> list[str]:
    """The simulated headline rules under which no frame gave a wrong body or a wrong pose."""
    from starforge.tracking.identify import HEADLINE_RULES

    return [r for r in HEADLINE_RULES if r in by_rule and by_rule[r]["mislabel_rate"] == 0]


def accuracy_report(bodyset, s: CheckSettings) -> dict:
    """Predicted accuracy of every body at its tip (``--tip``, else the body's own tip: see
    :mod:`starforge.tracking.bodies`), with all markers and with the worst single marker
    hidden (:mod:`starforge.geometry.rigid`), and the family's median and worst."""
    from starforge.geometry.rigid import (
        fle_from_sigma,
        rotation_error_deg,
        rotation_error_hidden_deg,
        tre_hidden,
        tre_rms,
    )

    tips = (
        np.broadcast_to(np.asarray(s.tip_mm, dtype=float), (len(bodyset.bodies), 3))
        if s.tip_mm is not None
        else bodyset.tips_mm()
    )
    fle = fle_from_sigma(s.noise_mm)
    rows = []
    for b, tip in zip(bodyset.bodies, tips, strict=True):
        P = b.points_mm
        # a 3-marker body has no hidden-marker case: a tracker cannot identify it from 2 markers
        hid = tre_hidden(P, tip, fle) if len(P) > 3 else None
        rows.append(
            {
                "body": b.name,
                "markers": len(P),
                "tip_mm": [float(x) for x in tip],
                "tip_tre_mm": float(tre_rms(P, tip, fle)),
                "tip_tre_hidden_mm": float(hid.max()) if hid is not None else None,
                "worst_hidden_marker": int(hid.argmax()) + 1 if hid is not None else None,
                "rotation_deg": float(rotation_error_deg(P, s.noise_mm)),
                "rotation_hidden_deg": float(rotation_error_hidden_deg(P, s.noise_mm).max())
                if len(P) > 3
                else None,
            }
        )
    allm = np.array([r["tip_tre_mm"] for r in rows])
    hidm = np.array([r["tip_tre_hidden_mm"] for r in rows if r["tip_tre_hidden_mm"] is not None])
    same_tip = bool((tips == tips[0]).all())
    return {
        "tip_mm": [float(x) for x in tips[0]] if same_tip else None,
        "tip_source": "--tip" if s.tip_mm is not None else bodyset.tip_source,
        "noise_mm": s.noise_mm,
        "bodies": rows,
        "family": {
            "tip_tre_mm_median": float(np.median(allm)),
            "tip_tre_mm_worst": float(allm.max()),
            "tip_tre_hidden_mm_median": float(np.median(hidm)) if len(hidm) else None,
            "tip_tre_hidden_mm_worst": float(hidm.max()) if len(hidm) else None,
            "bodies_without_hidden_case": [r["body"] for r in rows if r["tip_tre_hidden_mm"] is None],
        },
    }


def run_check(bodyset, s: CheckSettings, progress=None) -> dict:
    """The check document for ``bodyset`` (see module docstring).

    ``progress(stage, done, total)`` is called as frames are processed.
    """
    from starforge.tracking import identify as ident
    from starforge.tracking.library import build_library, drop1_margin_mm

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
    lib = build_library(points, names)
    tr = resolve_windows(bodyset, s, preset)
    match, res = tr["match_mm"], tr["residual_mm"]
    ident.check_settings(lib, s.noise_mm, s.drop, s.ghosts, s.frames, match, res)
    # markers left per body: a body never drops below 3 (3-marker bodies have no hidden case)
    left = lib.counts - np.minimum(s.drop, lib.counts - 3)
    big = lib.counts >= tr["min_markers"]
    most = int(left[big].min()) if big.any() else int(left.min())
    require(
        not s.drop_exact or tr["min_markers"] <= most,
        f"--drop {s.drop} --exact-drop leaves {most} markers, fewer than the {tr['min_markers']} "
        f"the tracker identifies from",
    )
    capped = [names[i] for i in np.flatnonzero(lib.counts - 3 < s.drop)]
    rules = (s.choose,) if s.choose is not None else ident.RULES
    rng = np.random.default_rng(s.seed)
    cb = (lambda d, n: progress("simulate", d, n)) if progress else None
    if cb is not None:
        cb(0, s.frames)  # the stage starts with its work
    kw = {
        "world": s.world,
        "presence": s.presence,
        "min_markers": tr["min_markers"],
        "drop_exact": s.drop_exact,
        "reflect": tr["reflect"],
        "rules": rules,
        "ambiguity": ident.AMBIGUITY if s.ambiguity is None else s.ambiguity,
        "assumed_noise_mm": s.noise_mm,
    }
    tallies = ident.run_rules(lib, s.frames, s.noise_mm, s.drop, s.ghosts, rng, match, res, progress=cb, **kw)
    by_rule = {r: t.rates() for r, t in tallies.items()}
    head = headline_rule(by_rule, rules)
    tally = tallies[head]
    t_main = time.perf_counter() - t0
    curve = None
    if s.curve_points > 0:
        cf = s.curve_frames if s.curve_frames is not None else max(100, s.frames // 10)
        top = max(2 * s.noise_mm, match / 2)
        levels = np.unique(np.round(np.concatenate([np.linspace(0.0, top, s.curve_points), [s.noise_mm]]), 9))
        idr, mis = [], []
        for i, nz in enumerate(levels):
            # the headline's rule only: check.png plots the rule the headline names
            r = ident.run_rules(lib, cf, float(nz), s.drop, s.ghosts, rng, match, res, **{**kw, "rules": (head,)})
            rate = r[head].rates()
            idr.append(rate["identification_rate"])
            mis.append(rate["mislabel_rate"])
            if progress:
                progress("curve", i + 1, len(levels))
        curve = {
            "rule": head,
            "noise_mm": levels.tolist(),
            "frames": cf,
            "identification_rate": idr,
            "mislabel_rate": mis,
        }
    acc = accuracy_report(bodyset, s)
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "units": "mm",
        "input": {
            "kind": bodyset.kind,
            "files": list(bodyset.sources),
            "bodies": len(names),
            "notes": list(bodyset.notes),
            "warnings": list(getattr(bodyset, "warnings", ())),
            "markers_per_body": sorted({int(c) for c in lib.counts}),
            "bodies_never_hiding_a_marker": capped,
        },
        "settings": {
            "noise_mm": s.noise_mm,
            "drop": s.drop,
            "drop_mode": "exact" if s.drop_exact else "uniform 0..drop",
            "ghosts": s.ghosts,
            "frames": s.frames,
            "seed": s.seed,
            "match_mm": match,
            "residual_mm": res,
            "window_source": tr["window_source"],
            "key_margin_mm": tr["margin_mm"],
            "mirror_blind": tr["reflect"],
            "preset": s.preset,
            "world": s.world,
            "presence": s.presence,
            "identify_from_markers": tr["min_markers"],
            "choose": tr["choose"],
            "choose_means": ident.CHOOSE[tr["choose"]],
            "ambiguity_likelihood_ratio": ident.AMBIGUITY if s.ambiguity is None else s.ambiguity,
            "rules": list(rules),
            "tip_mm": acc["tip_mm"],
        },
        **tally.rates(),
        "headline_rule": head,
        "headline_means": ident.CHOOSE[head],
        "headline_rules": [r for r in ident.HEADLINE_RULES if r in by_rule],
        "safe_under": safe_rules(by_rule),
        "by_rule": {
            r: {**v, "means": ident.CHOOSE[r], "kind": "stress" if r in ident.STRESS_RULES else "headline",
                "source": ident.RULE_SOURCES.get(r)}
            for r, v in by_rule.items()
        },
        "instances": tally.instances,
        "confusion": {"labels": names, "matrix": tally.confusion.tolist()},
        "flips": tally.flips.tolist(),
        "missed": tally.missed.tolist(),
        "phantoms": tally.phantoms.tolist(),
        "worst_pairs": _worst_pairs(tally, names),
        "closest_triangles": closest_triangles(lib, 2 * match),
        "drop1_margin_mm": drop1_margin_mm(lib),
        "accuracy": acc,
    }
    if preset is not None:
        from starforge.tracking.presets import check_rules

        viol = check_rules(names, points, preset, window_mm=match, identify_markers=tr["min_markers"])
        doc["rules"] = {
            "preset": preset.name,
            "vendor": preset.vendor,
            "source": preset.source,
            "sources": dict(preset.sources),
            "window_mm": match,
            "violations": [v.to_json() for v in viol],
        }
    if curve is not None:
        doc["curve"] = curve
    doc["seconds"] = {"main": round(t_main, 3), "total": round(time.perf_counter() - t0, 3)}
    return doc
