"""Vendor presets (catalog data in ``templates/presets/*.toml``) and the rule checks they drive.

Each rule broken is reported as a named :class:`Violation`:

``too_few_markers``, ``too_many_markers``, ``collinear``, ``min_distance`` (smallest distance
inside a body), ``distinct_distances`` (two distances of one body closer than ``distinct_mm``),
``equal_distances`` (closer than the tracker's equality window ``equal_mm``), ``symmetric``
(the body fits itself under a wrong correspondence: it flips), ``congruent`` (two bodies fit
each other within the window), ``mirror_images`` (they fit only mirrored, and the vendor
treats mirror images as the same), ``shared_triangle`` (three markers of one body match three
of another: confused when a marker is hidden).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field

import numpy as np

from starforge.catalog import list_templates, load_template
from starforge.errors import StarforgeError
from starforge.spec import from_mapping, positive, require
from starforge.tol import tol


@dataclass(frozen=True)
class Rules:
    """A vendor's rigid-body rules (lengths mm)."""

    min_markers: int = 3
    max_markers: int | None = None
    min_distance_mm: float | None = None
    distinct_mm: float | None = None
    equal_mm: float = 2.0
    not_collinear: bool = True
    asymmetric: bool = True
    mirror_unique: bool = True

    def __post_init__(self):
        require(self.min_markers >= 3, f"rules.min_markers must be >= 3, got {self.min_markers}")
        if self.max_markers is not None:
            require(
                self.max_markers >= self.min_markers,
                f"rules.max_markers must be >= min_markers ({self.min_markers}), got {self.max_markers}",
            )
        positive("rules.equal_mm", self.equal_mm)
        for name in ("min_distance_mm", "distinct_mm"):
            if getattr(self, name) is not None:
                positive(f"rules.{name}", getattr(self, name))


@dataclass(frozen=True)
class TrackerSettings:
    """How the preset's tracker identifies: distance window, fit limit (mm), mirror-blind or not."""

    match_mm: float = 2.0
    residual_mm: float = 1.0
    reflect: bool = False
    identify_markers: int = 3  # matched markers a reported identification needs

    def __post_init__(self):
        positive("tracker.match_mm", self.match_mm)
        positive("tracker.residual_mm", self.residual_mm)
        require(
            self.identify_markers >= 3, f"tracker.identify_markers must be >= 3, got {self.identify_markers}"
        )


@dataclass(frozen=True)
class Preset:
    name: str
    vendor: str
    source: str
    rules: Rules = field(default_factory=Rules)
    tracker: TrackerSettings = field(default_factory=TrackerSettings)
    stars: dict = field(default_factory=dict)
    #: where every number comes from: {"rules.min_markers": "URL: what it says", ...}; a number
    #: with no entry is starforge's own choice (its TOML comment says so)
    sources: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Violation:
    """One broken rule: which body (or ``a / b`` pair), the rule's name, a readable message."""

    body: str
    rule: str
    message: str

    def to_json(self) -> dict:
        return {"body": self.body, "rule": self.rule, "message": self.message}


def preset_names() -> list[str]:
    return list_templates("presets")


def load_preset(name_or_path: str) -> Preset:
    """A preset by name (``art``, ``ndi``, ``qualisys``, ``optitrack``) or TOML path.

    An unknown name raises StarforgeError listing the known ones.
    """
    name, data = load_template("presets", name_or_path)
    data = dict(data)
    data.setdefault("name", name)
    p = from_mapping(Preset, data, where=f"preset {name}")
    from starforge.stars.spec import StarSpec

    known = {f.name for f in dataclasses.fields(StarSpec)}
    bad = sorted(set(p.stars) - known)
    if bad:
        raise StarforgeError(f"preset {name}: unknown StarSpec field(s) {', '.join(bad)} in [stars]")
    return p


def star_spec_overrides(preset_name: str) -> dict:
    """StarSpec field overrides that generate a family under the preset's tolerances.

    E.g. ``star_spec_overrides("art") == {"delta_mm": 5.0, "tolerance_mm": 5.0, "l_min_mm": 31.0}``.
    """
    return dict(load_preset(preset_name).stars)


def _pair_distances(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ij = np.array(list(itertools.combinations(range(len(P)), 2)), dtype=np.intp)
    return ij, np.linalg.norm(P[ij[:, 0]] - P[ij[:, 1]], axis=1)


def line_deviation_mm(P: np.ndarray) -> float:
    """Largest distance of the points from their best-fit line, mm."""
    X = np.asarray(P, dtype=float) - np.mean(P, axis=0)
    _, _, Vt = np.linalg.svd(X, full_matrices=False)
    d = X - np.outer(X @ Vt[0], Vt[0])
    return float(np.linalg.norm(d, axis=1).max())


def check_body(name: str, P: np.ndarray, rules: Rules) -> list[Violation]:
    """Single-body rules."""
    from starforge.tracking.identify import self_matches

    P = np.asarray(P, dtype=float)
    out: list[Violation] = []
    n = len(P)
    if n < rules.min_markers:
        out.append(Violation(name, "too_few_markers", f"{n} markers, needs at least {rules.min_markers}"))
    if rules.max_markers is not None and n > rules.max_markers:
        out.append(Violation(name, "too_many_markers", f"{n} markers, allows at most {rules.max_markers}"))
    if n < 2:
        return out
    if rules.not_collinear and n >= 2 and line_deviation_mm(P) < rules.equal_mm:
        out.append(
            Violation(
                name,
                "collinear",
                f"markers lie within {line_deviation_mm(P):.2f} mm of a line (window {rules.equal_mm} mm)",
            )
        )
    ij, d = _pair_distances(P)
    if rules.min_distance_mm is not None and d.min() <= rules.min_distance_mm:
        out.append(
            Violation(
                name,
                "min_distance",
                f"smallest distance {d.min():.2f} mm, must be over {rules.min_distance_mm} mm",
            )
        )
    if len(d) > 1:
        srt = np.sort(d)
        gaps = np.diff(srt)
        k = int(gaps.argmin())
        if rules.distinct_mm is not None and gaps[k] < rules.distinct_mm - tol.compare_mm:
            out.append(
                Violation(
                    name,
                    "distinct_distances",
                    f"distances {srt[k]:.2f} and {srt[k + 1]:.2f} mm differ by "
                    f"{gaps[k]:.2f} mm, must differ by at least {rules.distinct_mm} mm",
                )
            )
        if gaps[k] < rules.equal_mm:
            out.append(
                Violation(
                    name,
                    "equal_distances",
                    f"distances {srt[k]:.2f} and {srt[k + 1]:.2f} mm count as equal "
                    f"(closer than {rules.equal_mm} mm)",
                )
            )
    if rules.asymmetric and n >= 3:
        flips = self_matches(P, rules.equal_mm, rules.equal_mm / 2, reflect=not rules.mirror_unique)
        if flips:
            rms, a = flips[0]
            out.append(
                Violation(
                    name,
                    "symmetric",
                    f"fits itself under the wrong correspondence {a.tolist()} with RMS "
                    f"{rms:.3f} mm: the body can flip",
                )
            )
    return out


def check_between(names, points, rules: Rules, limit: int = 1000) -> list[Violation]:
    """Rules between bodies: congruent / mirror images / shared triangles (at most ``limit`` reported)."""
    from starforge.tracking.identify import build_library, hypotheses

    out: list[Violation] = []
    B = len(points)
    if B < 2:
        return out
    usable = [i for i in range(B) if len(points[i]) >= 3]
    if len(usable) < 2:
        return out
    lib = build_library([points[i] for i in usable], [names[i] for i in usable])
    nmax = max(len(points[i]) for i in usable)
    pts = np.full((len(usable), nmax, 3), np.nan)
    for s, i in enumerate(usable):
        pts[s, : len(points[i])] = points[i]
    w = rules.equal_mm
    seen = set()
    for reflect in (False, True):
        if reflect and rules.mirror_unique:
            break
        h = hypotheses(lib, pts, w, w / 2, reflect=reflect)
        for s, c, n in zip(h.scene, h.body, h.n, strict=True):
            if s == c:
                continue
            a, b = usable[s], usable[c]
            if n < min(len(points[a]), len(points[b])):
                continue
            key = tuple(sorted((a, b)))
            if key in seen:
                continue
            seen.add(key)
            rule = "mirror_images" if reflect else "congruent"
            what = "mirror images of each other" if reflect else "congruent"
            out.append(
                Violation(
                    f"{names[key[0]]} / {names[key[1]]}",
                    rule,
                    f"{what} within {w} mm: the tracker cannot tell them apart",
                )
            )
    # triangles shared between bodies (bottleneck distance of sorted sides below the window)
    S = lib.tri_sorted
    tb = lib.tri_body
    pairs: dict = {}
    for i0 in range(0, len(S), 2048):
        blk = S[i0 : i0 + 2048]
        lo = np.searchsorted(S[:, 2], blk[:, 2] - w, side="left")
        hi = np.searchsorted(S[:, 2], blk[:, 2] + w, side="right")
        for k in range(len(blk)):
            j = np.arange(lo[k], hi[k])
            j = j[tb[j] > tb[i0 + k]]
            if len(j) == 0:
                continue
            dd = np.abs(S[j] - blk[k]).max(axis=1)
            for jj, dv in zip(j[dd < w], dd[dd < w], strict=True):
                key = (usable[tb[i0 + k]], usable[tb[jj]])
                if key not in pairs or dv < pairs[key]:
                    pairs[key] = float(dv)
    for (a, b), dv in sorted(pairs.items(), key=lambda kv: kv[1]):
        if tuple(sorted((a, b))) in seen:
            continue
        out.append(
            Violation(
                f"{names[a]} / {names[b]}",
                "shared_triangle",
                f"three markers of each match within {dv:.2f} mm (window {w} mm): "
                f"confused when a marker is hidden",
            )
        )
    return out[:limit]


def check_rules(names, points, preset: Preset) -> list[Violation]:
    """Every violation of ``preset``'s rules by bodies ``points`` (list of (n, 3) mm arrays)."""
    out: list[Violation] = []
    for nm, P in zip(names, points, strict=True):
        out.extend(check_body(nm, P, preset.rules))
    out.extend(check_between(list(names), [np.asarray(p, dtype=float) for p in points], preset.rules))
    return out
