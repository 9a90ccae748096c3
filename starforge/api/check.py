"""What a tracker sees: simulated frames of a lab's bodies, identified the way trackers do.

``starforge check`` is :func:`run_check` (``check.json`` and ``check.png`` written) and
:func:`describe_check` (its summary); a notebook calls :func:`check`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from starforge.errors import StarforgeError
from starforge.io import atomic_write_json, check_writable, staged_output
from starforge.runtime import progress
from starforge.words import counted

__all__ = ["MAX_TIP_MM", "CheckResult", "CheckRun", "CheckSummary", "check", "describe_check", "parse_tip", "run_check"]

#: how far from the body's frame a tip may be, mm (10 m: past any tool's tip)
MAX_TIP_MM = 10_000.0

@dataclass(frozen=True)
class CheckResult:
    """How often a simulated tracker identifies each body (:func:`check`).

    Rates are fractions of (body, frame) events in [0, 1].

    Attributes
    ----------
    rule : str
        The identification rule of the headline rates.
    identified, wrong_body, wrong_pose, missed : float
        Right body with the right labels; another body reported; the right body with its
        markers relabelled (a wrong pose); nothing reported.
    document : dict
        The whole ``check.json`` document (every rule, worst pairs, accuracy).
    """

    rule: str
    identified: float
    wrong_body: float
    wrong_pose: float
    missed: float
    document: dict = field(repr=False)


@dataclass(frozen=True)
class CheckRun:
    """What :func:`run_check` wrote.

    Attributes
    ----------
    folder : Path
        The output folder.
    files : tuple of str
        The files written (``check.json``, and ``check.png`` with a curve).
    document : dict
        ``check.json``'s content.
    """

    folder: Path
    files: tuple[str, ...]
    document: dict = field(repr=False)


@dataclass(frozen=True)
class CheckSummary:
    """A check in words (:func:`describe_check`).

    Attributes
    ----------
    warnings : tuple of str
        About the bodies read (left out, renamed).
    settings : tuple of str
        What was simulated: bodies, frames, noise, the window and where it comes from.
    headline : str
        The headline rates, their rule and what it does (two lines).
    details : tuple of str
        The rates under each rule, the worst confusions, the accuracy, vendor rule violations
        and what was written.
    """

    warnings: tuple[str, ...]
    settings: tuple[str, ...]
    headline: str
    details: tuple[str, ...]


def parse_tip(text: str | None) -> tuple[float, float, float] | None:
    """``"0,0,-48.3"`` -> (0.0, 0.0, -48.3) mm; None stays None.

    Examples
    --------
    >>> parse_tip("0, 0,-48.3")
    (0.0, 0.0, -48.3)
    """
    if text is None:
        return None
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise StarforgeError(f"tip must be three numbers x,y,z in mm, got {text!r}") from None
    if len(v) != 3:
        raise StarforgeError(f"tip must be three numbers x,y,z in mm, got {text!r}")
    if not all(math.isfinite(x) and abs(x) <= MAX_TIP_MM for x in v):
        raise StarforgeError(f"tip must be three finite numbers within {MAX_TIP_MM:,.0f} mm of the body, got {text!r}")
    return v


def run_check(
    sources: Sequence[str | Path],
    out: str | Path = "out/check",
    *,
    tip: str | None = None,
    seed: int = 0,
    preset: str | None = None,
    curve_points: int = 7,
    force: bool = False,
    **settings,
) -> CheckRun:
    """``starforge check`` as one call: simulate and identify the bodies in ``sources``
    (:func:`check`), then write ``check.json`` and, with ``curve_points``, ``check.png`` (the
    rates against noise).  Settings, preset, bodies and existing files are checked first.

    Parameters
    ----------
    tip : str, optional
        Target point ``"x,y,z"`` in the body frame, mm (:func:`parse_tip`).
    **settings
        Other :class:`starforge.tracking.check.CheckSettings` fields (``noise_mm``, ``frames``...).

    Examples
    --------
    >>> import tempfile
    >>> from starforge.api import make_family, plan_family, write_family
    >>> fam = make_family(plan_family(box_mm=(14, 10, 30), delta_mm=2.0, count=3))
    >>> folder = write_family(fam, Path(tempfile.mkdtemp()) / "f")
    >>> run = run_check([folder], folder / "check", frames=100, curve_points=0)
    >>> run.files, run.document["input"]["bodies"]
    (('check.json',), 3)
    """
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.check import CheckSettings
    from starforge.tracking.check import run_check as simulate

    if seed < 0:
        raise StarforgeError(f"seed must be >= 0, got {seed}")
    s = CheckSettings(seed=seed, tip_mm=parse_tip(tip), preset=preset, curve_points=curve_points, **settings)
    if preset is not None:
        from starforge.tracking.presets import load_preset

        load_preset(preset)  # unknown name: one line before any work
    bodyset = load_bodies(sources)
    folder = Path(out)
    names = ("check.json",) + (("check.png",) if curve_points > 0 else ())
    check_writable(folder, names, force)
    doc = simulate(bodyset, s, progress=progress.report({"simulate": "frames", "curve": "noise levels"}))
    with staged_output(folder, force) as stage:
        atomic_write_json(stage / "check.json", doc)
        if curve_points > 0:
            from starforge.render.tracking import rates_plot

            with progress.stage("render", total=1, unit="pictures") as st:
                rates_plot(doc, stage / "check.png")
                st.update(1)
    return CheckRun(folder, names, doc)


def describe_check(run: CheckRun) -> CheckSummary:
    """:func:`run_check`'s result in words; no line nests parentheses."""
    doc = run.document
    s = doc["settings"]
    settings = [
        f"{counted(doc['input']['bodies'], 'body')}, {counted(s['frames'], 'frame')}, {s['world']} world, "
        f"presence {s['presence']:g}, noise {s['noise_mm']} mm, drop {s['drop']} ({s['drop_mode']}), "
        f"ghosts {s['ghosts']}, match {s['match_mm']:.3g} mm, residual {s['residual_mm']:.3g} mm, "
        f"identify from {s['identify_from_markers']} markers",
        f"window from {s['window_source']}",
    ]
    few = doc["input"]["bodies_never_hiding_a_marker"]
    if few:
        settings.append(
            f"{counted(len(few), 'body')} keep all their markers in every frame (3 markers: no hidden-marker "
            f"case): {', '.join(few[:5])}{' ...' if len(few) > 5 else ''}"
        )
    settings += [f"note: {note}" for note in doc["input"]["notes"]]
    details = []
    for rule, r in doc["by_rule"].items():
        kind = "stress model" if r["kind"] == "stress" else "rule"
        details.append(
            f"  {kind} {rule}: identified {100 * r['identification_rate']:.3f} %, wrong body "
            f"{100 * r['wrong_body_rate']:.3f} %, wrong pose {100 * r['flip_rate']:.3f} %; "
            f"{r['means'].removeprefix('stress model: ')}"
        )
    for w in doc["worst_pairs"][:5]:
        what = (
            f"labels swapped: wrong pose: {w['true']}"
            if w["kind"] == "flip"
            else f"wrong body: {w['true']} seen as {w['reported']}"
        )
        details.append(f"  {what}: {w['count']} ({100 * w['rate']:.3f} %)")
    fam = doc["accuracy"]["family"]
    at = doc["accuracy"]["tip_mm"]
    tip = ", ".join(f"{x:.3g}" for x in at) + " mm" if at is not None else "each body's tip"
    hidden = (
        f"one marker hidden: median {fam['tip_tre_hidden_mm_median']:.3f} mm, worst {fam['tip_tre_hidden_mm_worst']:.3f} mm"
        if fam["tip_tre_hidden_mm_median"] is not None
        else "no body has a hidden-marker case"
    )
    details.append(
        f"TRE at {tip}, {doc['accuracy']['tip_source']}: median {fam['tip_tre_mm_median']:.3f} mm, "
        f"worst {fam['tip_tre_mm_worst']:.3f} mm; {hidden}"
    )
    if "rules" in doc:
        v = doc["rules"]["violations"]
        details.append(f"{doc['rules']['vendor']}: {counted(len(v), 'rule violation')}")
        details += [f"  {x['rule']}: {x['body']}: {x['message']}" for x in v[:10]]
        if len(v) > 10:
            details.append(f"  ... {len(v) - 10} more in check.json")
    details.append(f"wrote {run.folder}/: {', '.join(run.files)} ({doc['seconds']['total']:.1f} s)")
    return CheckSummary(tuple(doc["input"]["warnings"]), tuple(settings), _headline(doc), tuple(details))


def _headline(doc: dict) -> str:
    """Two lines: the headline's rates, the rule they are under and the rules under which no
    frame gave a wrong body or a wrong pose; then what that rule does."""
    s = doc["settings"]
    head = doc["headline_rule"]
    rules = doc["headline_rules"]
    worst = f"the worse of {' and '.join(rules)}" if len(rules) > 1 else "the rule simulated"
    safe = doc["safe_under"]
    verdict = (
        f"no frame gave a wrong body or pose under {', '.join(safe)}"
        if safe
        else "some frames gave a wrong body or pose under every headline rule"
    )
    w = doc.get("withheld_rate", 0.0)
    withheld = f" ({100 * w:.3f} % withheld: a rival explanation nearly as likely)" if w > 0 else ""
    return (
        f"identified {100 * doc['identification_rate']:.3f} %, wrong body {100 * doc['wrong_body_rate']:.3f} %, "
        f"wrong pose {100 * doc['flip_rate']:.3f} %, missed {100 * doc['missed_rate']:.3f} %{withheld} under rule {head}, "
        f"{worst}; {verdict}\n  rule {head}: {doc['headline_means']}; window {s['match_mm']:.3g} mm, "
        f"residual {s['residual_mm']:.3g} mm; a match is withheld unless {s['ambiguity_likelihood_ratio']:g} times as likely as any rival"
    )


def check(
    sources: Sequence[str | Path],
    *,
    noise_mm: float = 0.2,
    drop: int = 1,
    ghosts: int = 0,
    frames: int = 2000,
    seed: int = 0,
    preset: str | None = None,
    **settings,
) -> CheckResult:
    """Simulate tracker frames for the bodies in ``sources`` and identify them as trackers do.

    Parameters
    ----------
    sources : sequence of path
        Families, placements and a lab's tracker files, in any mix.
    noise_mm : float
        Marker centre noise, sigma per axis, mm.
    drop : int
        Up to this many markers hidden per body and frame.
    ghosts : int
        Stray points near each body per frame.
    **settings
        Other :class:`starforge.tracking.check.CheckSettings` fields.
    """
    from starforge.tracking.bodies import load_bodies
    from starforge.tracking.check import CheckSettings, run_check

    s = CheckSettings(
        noise_mm=noise_mm, drop=drop, ghosts=ghosts, frames=frames, seed=seed, preset=preset, **settings
    )
    doc = run_check(load_bodies([Path(p) for p in sources]), s)
    return CheckResult(
        rule=doc["headline_rule"],
        identified=doc["identification_rate"],
        wrong_body=doc["wrong_body_rate"],
        wrong_pose=doc["flip_rate"],
        missed=doc["missed_rate"],
        document=doc,
    )
