"""Held-out samples of the tracked objective: fresh random poses with their own camera losses
that rank the candidate layouts, tune the held-out polish, and explain a layout tracked below the
target (never the samples the layouts were searched on, nor the fresh-pose evaluation)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from starforge.props.ceiling import tracked_ceiling
from starforge.props.evaluate import random_poses
from starforge.props.grips import GRIP_SEED_OFFSET, assign_grips, grip_arrays
from starforge.props.hand import inside_capsules, posts_in_hands
from starforge.props.layout_search import held_out_polish
from starforge.props.rig import Poses
from starforge.props.scenarios import alive_masks
from starforge.props.tracked import Problem
from starforge.props.visibility import compute_table
from starforge.runtime.stored import content_key, stored

#: the held-out sample's generator is seeded with seed + this (the evaluation's differs again)
VALIDATION_SEED_OFFSET = 2_000_029
#: the tuning sample that the held-out polish searches (never the ranking's or the evaluation's)
TUNING_SEED_OFFSET = 4_000_037


class HeldOut:
    """A held-out sample: ``track.validation_poses`` fresh random poses (generator ``seed +
    offset``), each met ``track.loss_patterns`` times with its own random camera losses, drawn
    as :func:`starforge.props.scenarios.loss_scenarios` draws them; tables are built on demand
    for the sites (and poses) asked.  A site's row of camera masks depends on that site alone,
    so the rows over every pose are kept (with and without the hand) and a later call computes
    only the sites it has not met: the ranking scores the polished layouts on the rows of the
    candidates they share sites with, and the tuning polish reuses its start's rows.  A table is a
    pure function of the prepared inputs (kept under their key, :func:`starforge.props.prepare.prepare`),
    the sample and the sites and poses asked: kept in the cache folder under those too."""

    def __init__(self, prop, spec, seed: int, prep, offset: int):

        ts, rig = spec.track, prep.rig
        rng = np.random.default_rng(seed + offset)
        self.poses = random_poses(rig.volume, ts.validation_poses, prep.poses.pivot, rng)
        self.patterns = ts.loss_patterns if int(round(ts.cameras_lost * len(rig.cameras))) > 0 else 1
        self.alive = alive_masks(len(rig.cameras), ts.cameras_lost, len(self.poses) * self.patterns, rng)
        self.grip = assign_grips(len(self.poses), prep.grips, np.random.default_rng(seed + offset + GRIP_SEED_OFFSET))
        self.prop, self.spec, self.prep = prop, spec, prep
        self._rows: dict = {}  # (site, hand) -> (poses,) uint64 masks over every pose
        self._key = content_key("held-out", prep.key, spec, seed, offset) if prep.key else ""

    def _table(self, sites, k, hand: bool) -> np.ndarray:
        if not self._key:
            return self._computed(sites, k, hand)
        key = content_key(self._key, [int(s) for s in sites], np.asarray(k, dtype=np.int64), bool(hand))
        return stored("held-out", key, lambda: self._computed(sites, k, hand))[0]

    def _computed(self, sites, k, hand: bool) -> np.ndarray:
        prep, spec = self.prep, self.spec
        sub = Poses(self.poses.rotations[k], self.poses.translations[k], self.poses.pivot)
        occ, starts = grip_arrays(prep.grips if hand else ())
        return compute_table(
            self.prop, prep.sites.points[sites], prep.sites.normals[sites], prep.rig, sub,
            spec.grazing_limit_deg, radius_m=prep.seat.ball_radius_m, centre_m=prep.seat.centre_height_m,
            occlusion=spec.occlusion, occluders=occ, occluder_starts=starts,
            pose_grip=self.grip[k] if hand and prep.grips else None, post_m=prep.seat.standoff_m,
        ).masks  # fmt: skip

    def seen(self, sites, poses=None, hand: bool = True):
        """(seen (len(sites), scenarios) bool, masks (len(sites), poses) uint64): the scenarios
        of ``poses`` (indices, default all), without the hand when ``hand`` is false."""
        sites = [int(x) for x in sites]
        every = np.arange(len(self.poses))
        k = every if poses is None else np.asarray(poses, dtype=np.int64)
        masks = np.zeros((len(sites), len(k)), dtype=np.uint64)
        kept = [i for i, s in enumerate(sites) if (s, hand) in self._rows]
        for i in kept:
            masks[i] = self._rows[(sites[i], hand)][k]
        new = [i for i, s in enumerate(sites) if (s, hand) not in self._rows]
        if new:
            idx = [sites[i] for i in new]
            if poses is None:  # rows over every pose: kept for later calls
                rows = self._table(idx, every, hand)
                for s, row in zip(idx, rows, strict=True):
                    self._rows[(s, hand)] = row
            else:
                rows = self._table(idx, k, hand)
            masks[new] = rows
        L = self.patterns
        scen = (k[:, None] * L + np.arange(L)[None]).ravel()  # scenario j of pose k: k * L + j
        seen = np.bitwise_count(masks[:, np.repeat(np.arange(len(k)), L)] & self.alive[scen][None]) >= 2
        return seen, masks


def validator(sample: HeldOut, spec, centres, prob):
    """``validate(layouts) -> [{"untracked", "cost"}]``: each layout's untracked fraction and cost
    on the ranking sample (``sample``, :data:`VALIDATION_SEED_OFFSET`)."""
    def validate(layouts):
        union = sorted({int(x) for lay in layouts for x in lay})
        seen, _ = sample.seen(union)
        held = Problem(
            centres[union], seen, seen.mean(axis=1), spec.track, prob.spacing, prob.spread_target, prob.avoid_faces,
            None if prob.margin is None else prob.margin[union], prob.margin_target,
        )  # fmt: skip
        at = {s: i for i, s in enumerate(union)}
        out = []
        for lay in layouts:
            t = held.terms([at[int(x)] for x in lay])
            out.append({"untracked": t["untracked"], "cost": t["total"]})
        return out

    return validate


#: at most this many sites take part in the held-out polish (the winner's, every candidate's,
#: then the winner's nearest neighbours)
POLISH_SITES = 120


def polisher(prop, spec, seed, prep, centres, prob):
    """``polish(sites) -> sites``: :func:`starforge.props.layout_search.held_out_polish` on the hard
    poses of a tuning sample of its own (:data:`TUNING_SEED_OFFSET`: neither the ranking sample
    nor the evaluation), the poses in which ``sites`` leave fewer than ``spare_markers`` seen in
    some scenario; the sites near the winner's and the other candidates' take part.  ``searched``:
    the problem the layouts were searched in (default ``prob``; a layout grown past its target
    keeps the triangle tolerance of its own count)."""
    sample = HeldOut(prop, spec, seed, prep, TUNING_SEED_OFFSET)  # one for every polish: rows shared

    def polish(sites, others=(), searched=None):
        searched = prob if searched is None else searched
        ts = replace(spec.track, avoid_tolerance_mm=searched.settings.avoid_tolerance_mm)
        sites = [int(x) for x in sites]
        seen, _ = sample.seen(sites)
        L = sample.patterns
        few = (seen.sum(axis=0) < max(3, ts.spare_markers)).reshape(-1, L).any(axis=1)
        hard = np.flatnonzero(few)
        if not len(hard):
            return tuple(sites)
        pool = list(dict.fromkeys(sites + sorted({int(x) for o in others for x in o})))
        near = range(len(prob.points)) if len(prob.points) <= POLISH_SITES else prob.knn[sites].T.ravel().tolist()
        for i in near:  # nearest neighbours of every marker first, then the next nearest
            if len(pool) >= POLISH_SITES:
                break
            if int(i) not in pool:
                pool.append(int(i))
        hseen, _ = sample.seen(pool, hard)
        tuning = Problem(centres[pool], hseen, hseen.mean(axis=1), ts, prob.spacing, prob.spread_target, prob.avoid_faces)
        found = held_out_polish(tuning, searched, list(range(len(sites))), np.asarray(pool))
        return tuple(pool[i] for i in found)

    return polish


def explain_shortfall(sample: HeldOut, spec, prep, prob, chosen, removed, fit) -> dict:
    """Why the chosen layout is tracked in fewer held-out scenarios than ``track.target_tracked``:
    the same scenarios re-scored with every camera and without the hand, the untracked ones split
    into too few markers seen and markers in a line, and the sites the layout had to work with."""
    ts, idx = spec.track, list(chosen)
    seen, masks = sample.seen(idx)  # the ranking sample
    held = Problem(prob.points[idx], seen, seen.mean(axis=1), ts, prob.spacing, prob.spread_target)
    everything = np.repeat(np.bitwise_count(masks) >= 2, seen.shape[1] // masks.shape[1], axis=1)
    seen_nh, _ = sample.seen(idx, hand=False) if prep.capsules else (seen, None)
    marks = list(range(len(idx)))
    ok = held.tracked_scenarios(marks)
    tracked = float(ok.mean())
    few = float(((seen.sum(axis=0) < 3)).mean())
    out = {
        "target": ts.target_tracked,
        "validation_tracked": tracked,
        "scenarios": int(seen.shape[1]),
        "untracked_too_few_seen": few,
        "untracked_in_a_line": max(0.0, 1.0 - tracked - few),
        "tracked_with_every_camera": 1.0 - Problem(prob.points[idx], everything, everything.mean(axis=1), ts, prob.spacing, prob.spread_target).untracked(marks),
        "tracked_without_the_hand": 1.0 - Problem(prob.points[idx], seen_nh, seen_nh.mean(axis=1), ts, prob.spacing, prob.spread_target).untracked(marks),
        "markers": len(idx),
        "markers_asked": spec.track.target_markers,
        "markers_that_fit_at_the_spacing": fit,
        "usable_sites": len(prep.sites),
        "sites_under_the_hand": removed["under_hand"],
        "hidden_by_the_hand": hidden_share(
            prep.sites.points + prep.seat.centre_height_m * prep.sites.normals, prep.grips,
            prep.sites.points if prep.seat.standoff_m > 0 else None,
        ),  # fmt: skip
    }
    if prep.grips:
        grip = np.repeat(sample.grip, sample.patterns)  # scenario k * patterns + j is pose k's
        out["untracked_by_grip"] = untracked_by_grip(ok, grip, len(prep.grips))

    # no layout on these sites is tracked where fewer than 3 of them are seen at all (counted on
    # the searched scenarios, whose table holds every site: the held-out one would cost a table
    # of every site over every held-out pose)
    out["under_three_sites_seen"] = float((prob.pose_seen.sum(axis=0) < 3).mean())
    out["searched_scenarios"] = int(prob.poses)
    every = np.arange(len(prob.points))
    out["ceiling"] = tracked_ceiling(
        prob.points, lambda: sample.seen(every)[0], prob.spacing, held.min_spread2, ts.target_markers
    )
    return out


def untracked_by_grip(ok: np.ndarray, grip: np.ndarray, grips: int) -> list[float]:
    """Per grip (in the order ``place`` lists them): the share of the scenarios held in it that
    the layout does not track (``ok`` (s,) bool per scenario, ``grip`` (s,) int its grip); empty
    without a hand."""
    if not grips:
        return []
    held = np.bincount(grip, minlength=grips)
    lost = np.bincount(grip[~ok], minlength=grips)
    return [round(float(lo / n), 6) if n else 0.0 for lo, n in zip(lost, held, strict=True)]


def numbers_as_ranges(numbers: list[int]) -> str:
    """``[7, 8, 9, 12]`` -> ``"7-9, 12"``: consecutive numbers share ``n - position``."""
    out = []
    for _, run in itertools.groupby(enumerate(sorted(numbers)), key=lambda t: t[1] - t[0]):
        r = [n for _, n in run]
        out.append(f"{r[0]}-{r[-1]}" if len(r) > 1 else f"{r[0]}")
    return ", ".join(out)


def hidden_share(centres: np.ndarray, grips, bases: np.ndarray | None = None) -> float:
    """The share of the poses (by the grips' weights) held in a grip whose capsules enclose all but
    at most 2 of the markers' ball ``centres`` (n, 3), m, or, with ``bases`` (n, 3) (the feet of
    stand-off posts), hold their posts: a marker inside the hand is lost, so no 3 markers are seen
    in those poses whatever the layout."""
    total = sum(g.weight for g in grips)
    if not total:
        return 0.0
    held = np.zeros((len(centres), len(grips)), bool)
    if bases is not None:
        held = posts_in_hands(bases, centres, *grip_arrays(grips))
    lost = sum(
        g.weight for k, g in enumerate(grips) if int((~(inside_capsules(centres, g.capsules) | held[:, k])).sum()) < 3
    )
    return float(lost / total)


def shortfall_warning(sf: dict, spacing_m: float, hand: bool) -> str:
    """One line: how far below the target the layout is on the held-out scenarios, the cause the
    numbers point to, and what to change."""
    cause = []
    if sf["markers_that_fit_at_the_spacing"] < sf["markers_asked"]:
        cause.append(
            f"only {sf['markers_that_fit_at_the_spacing']} markers fit {spacing_m * 1000:.1f} mm apart on its "
            f"{sf['usable_sites']} usable sites" + (f" ({sf['sites_under_the_hand']} sites under the hand)" if hand else "")
        )
    hidden = sf.get("hidden_by_the_hand", 0.0)
    if hand and hidden > 0:
        cause.append(
            f"in {100 * hidden:.0f} % of the poses the hand encloses all but at most "
            "2 of the usable sites, so no layout is tracked there"
        )
    share = sf["untracked_too_few_seen"] / max(1e-12, 1.0 - sf["validation_tracked"])
    cause.append(f"{100 * share:.0f} % of the untracked scenarios see fewer than 3 markers, the rest see them in a line")
    by = sf.get("untracked_by_grip") or []
    lost = [g + 1 for g, x in enumerate(by) if x > 0]
    if hand and 0 < len(lost) < len(by):
        cause.append(
            f"all of them are held in grip{'s' if len(lost) > 1 else ''} {numbers_as_ranges(lost)} of the {len(by)} "
            "listed (the others are tracked in every scenario)"
        )
    elif hand and lost:
        worst = sorted(range(len(by)), key=lambda g: (-by[g], g))[:3]
        cause.append("the grips tracked least: " + ", ".join(f"{g + 1} ({100 * (1 - by[g]):.0f} %)" for g in worst))
    c = sf.get("ceiling")
    if c is not None:
        cause.append(
            f"no layout of markers {spacing_m * 1000:.1f} mm apart on these sites does better than "
            f"{100 * c['ceiling']:.2f} % of these scenarios (all {c['layouts']:,} such layouts scored)"
        )
    bare = sf.get("under_three_sites_seen", 0.0)
    if 1.0 - bare < sf["target"]:
        cause.append(
            f"in {100 * bare:.1f} % of the {sf['searched_scenarios']} searched scenarios fewer than 3 of the "
            f"{sf['usable_sites']} usable sites are seen at all, so no layout stuck on its surface tracks more "
            f"than {100 * (1.0 - bare):.1f} % of them: markers held clear of the hand and the prop on posts can"
        )
    helps = [f"with every camera {100 * sf['tracked_with_every_camera']:.1f} %"]
    if hand:
        helps.append(f"without the hand {100 * sf['tracked_without_the_hand']:.1f} %")
    advice = "a smaller --marker or --base-mm (more markers fit, more sites seat), --standoff MM (markers on posts, or on longer ones)"
    if hand:
        advice += ", another --grip or --no-hand"
    return (
        f"the layout is tracked in {100 * sf['validation_tracked']:.1f} % of {sf['scenarios']} held-out scenarios, "
        f"below the {100 * sf['target']:g} % target ({', '.join(helps)}): {'; '.join(cause)}; try {advice}"
    )
