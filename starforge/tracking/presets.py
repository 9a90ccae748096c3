"""Vendor presets (catalog data in ``templates/presets/*.toml``) and the rule checks they drive.

Each rule broken is reported as a named :class:`Violation`:

``too_few_markers``, ``too_many_markers``, ``collinear``, ``min_distance`` (smallest distance
inside a body), ``distinct_distances`` (two distances of one body closer than ``distinct_mm``),
``equal_distances`` (closer than the tracker's equality window ``equal_mm``), ``symmetric``
(the body fits itself under a wrong correspondence: it flips), ``congruent`` (two bodies fit
each other within the window), ``mirror_images`` (they fit only mirrored, and the vendor
treats mirror images as the same), ``shared_triangle`` (three markers of one body match three
of another: confused when a marker is hidden), ``own_triangles`` (two triangles of one body
match: it flips when a marker is hidden), ``shared_markers`` (for a tracker that identifies
from 4 or more markers: that many markers of two bodies match).

The window-dependent rules are checked at the window the simulation uses, so the rule check
names exactly the confusions ``starforge check`` can simulate.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field

import numpy as np

from starforge.catalog import list_templates, load_template, values_from
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


#: where a preset's distance window comes from
WINDOWS = {
    "fixed": "the preset's match_mm and residual_mm",
    "qtm_export": "the BoneLengthTolerance and MaximumResidual starforge writes into QTM files for these bodies",
    "rom_export": "the maximum marker error starforge writes into NDI .rom files, and the same distance tolerance",
    "derived": "the distance and residual tolerances starforge derives from the noise and the bodies' margins",
}


@dataclass(frozen=True)
class TrackerSettings:
    """How the preset's tracker identifies: distance window and fit limit (mm), where the window
    comes from (:data:`WINDOWS`), mirror-blind or not, markers needed, and how it picks among
    matches inside the window (:data:`starforge.tracking.identify.CHOOSE`)."""

    match_mm: float = 2.0
    residual_mm: float = 1.0
    reflect: bool = False
    identify_markers: int = 3  # matched markers a reported identification needs
    window: str = "fixed"
    choose: str = "fit"

    def __post_init__(self):
        from starforge.tracking.identify import CHOOSE

        positive("tracker.match_mm", self.match_mm)
        positive("tracker.residual_mm", self.residual_mm)
        require(
            self.identify_markers >= 3, f"tracker.identify_markers must be >= 3, got {self.identify_markers}"
        )
        require(
            self.window in WINDOWS, f"tracker.window must be one of {', '.join(WINDOWS)}, got {self.window!r}"
        )
        require(
            self.choose in CHOOSE, f"tracker.choose must be one of {', '.join(CHOOSE)}, got {self.choose!r}"
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
    with values_from(name_or_path):
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


def design_tolerance_mm(
    preset_name: str | None, noise_mm: float, floor_mm: float | None = None, n_markers: int = 4
) -> float:
    """The face tolerance ``stars`` designs a family with for a tracker (``preset_name``, None:
    starforge's default tracker, which gates by the tolerance written into vendor files) at
    ``noise_mm``: :func:`starforge.tracking.tolerances.design_margin_mm` of its window for
    bodies of ``n_markers`` markers, at least ``floor_mm`` (a vendor rule such as ART's 5 mm
    distinct distances), mm.  ``place`` keeps its layouts' triangles this far apart."""
    from starforge.tracking.tolerances import design_margin_mm

    window = None
    if preset_name is not None:
        tr = load_preset(preset_name).tracker
        window = tr.match_mm if tr.window == "fixed" else None
    margin = design_margin_mm(noise_mm, window, n_markers)
    return max(margin, float(floor_mm)) if floor_mm is not None else margin


def _pair_distances(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ij = np.array(list(itertools.combinations(range(len(P)), 2)), dtype=np.intp)
    return ij, np.linalg.norm(P[ij[:, 0]] - P[ij[:, 1]], axis=1)


def line_deviation_mm(P: np.ndarray) -> float:
    """Largest distance of the points from their best-fit line, mm."""
    X = np.asarray(P, dtype=float) - np.mean(P, axis=0)
    _, _, Vt = np.linalg.svd(X, full_matrices=False)
    d = X - np.outer(X @ Vt[0], Vt[0])
    return float(np.linalg.norm(d, axis=1).max())


def check_body(name: str, P: np.ndarray, rules: Rules, window_mm: float | None = None) -> list[Violation]:
    """Single-body rules.  ``window_mm``: the tracker's distance window for the equality and
    symmetry checks (default ``rules.equal_mm``)."""
    from starforge.tracking.identify import self_matches

    w = rules.equal_mm if window_mm is None else float(window_mm)
    P = np.asarray(P, dtype=float)
    out: list[Violation] = []
    n = len(P)
    if n < rules.min_markers:
        out.append(Violation(name, "too_few_markers", f"{n} markers, needs at least {rules.min_markers}"))
    if rules.max_markers is not None and n > rules.max_markers:
        out.append(Violation(name, "too_many_markers", f"{n} markers, allows at most {rules.max_markers}"))
    if n < 2:
        return out
    if rules.not_collinear and n >= 2 and line_deviation_mm(P) < w:
        out.append(
            Violation(
                name,
                "collinear",
                f"markers lie within {line_deviation_mm(P):.2f} mm of a line (window {w:g} mm)",
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
        if gaps[k] < w:
            out.append(
                Violation(
                    name,
                    "equal_distances",
                    f"distances {srt[k]:.2f} and {srt[k + 1]:.2f} mm count as equal (closer than {w:g} mm)",
                )
            )
    if rules.asymmetric and n >= 3:
        flips = self_matches(P, w, w / 2, reflect=not rules.mirror_unique)
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


def check_between(
    names,
    points,
    rules: Rules,
    limit: int = 1000,
    window_mm: float | None = None,
    identify_markers: int = 3,
) -> list[Violation]:
    """Rules between bodies, and between a body's own marker subsets, at the tracker's window
    ``window_mm`` (default ``rules.equal_mm``), at most ``limit`` reported:

    * ``congruent`` / ``mirror_images``: two bodies fit each other with every marker;
    * with ``identify_markers`` = 3: ``shared_triangle`` (three markers of one body match three of
      another: confused when the others are hidden) and ``own_triangles`` (two of a body's own
      triangles, or one triangle with two vertices swapped, match: it flips when a marker is
      hidden);
    * with ``identify_markers`` >= 4: ``shared_markers`` (that many markers of one body match as
      many of another).
    """
    from starforge.tracking.identify import hypotheses
    from starforge.tracking.library import build_library, close_triangle_pairs

    w = rules.equal_mm if window_mm is None else float(window_mm)
    out: list[Violation] = []
    B = len(points)
    usable = [i for i in range(B) if len(points[i]) >= 3]
    if not usable:
        return out
    lib = build_library([points[i] for i in usable], [names[i] for i in usable])
    nmax = max(len(points[i]) for i in usable)
    pts = np.full((len(usable), nmax, 3), np.nan)
    for k, i in enumerate(usable):
        pts[k, : len(points[i])] = points[i]
    seen: set = set()
    shared: dict = {}
    for reflect in (False, True):
        if reflect and rules.mirror_unique:
            break
        h = hypotheses(lib, pts, w, w / 2, reflect=reflect)
        for sc, c, n in zip(h.scene, h.body, h.n, strict=True):
            if sc == c:
                continue
            a, b = usable[sc], usable[c]
            key = tuple(sorted((a, b)))
            if n >= min(len(points[a]), len(points[b])):
                if key in seen:
                    continue
                seen.add(key)
                rule = "mirror_images" if reflect else "congruent"
                what = "mirror images of each other" if reflect else "congruent"
                out.append(
                    Violation(
                        f"{names[key[0]]} / {names[key[1]]}",
                        rule,
                        f"{what} within {w:g} mm: the tracker cannot tell them apart",
                    )
                )
            elif identify_markers >= 4 and n >= identify_markers:
                shared[key] = max(shared.get(key, 0), int(n))
    if identify_markers >= 4:
        for (a, b), n in sorted(shared.items()):
            if (a, b) not in seen:
                out.append(
                    Violation(
                        f"{names[a]} / {names[b]}",
                        "shared_markers",
                        f"{n} markers of each match within {w:g} mm: confused when the others are hidden",
                    )
                )
        return out[:limit]
    # triangles (identification from three markers): between bodies, and within one body
    qi, qj, d = close_triangle_pairs(lib, w)
    pairs: dict = {}
    for ti, tj, dv in zip(qi, qj, d, strict=True):
        key = tuple(sorted((usable[lib.tri_body[ti]], usable[lib.tri_body[tj]])))
        if key not in pairs or dv < pairs[key]:
            pairs[key] = float(dv)
    gap = np.diff(lib.tri_sorted, axis=1).min(axis=1)
    for t in np.flatnonzero(gap < w):
        a = usable[lib.tri_body[t]]
        if (a, a) not in pairs or gap[t] < pairs[(a, a)]:
            pairs[(a, a)] = float(gap[t])
    for (a, b), dv in sorted(pairs.items(), key=lambda kv: kv[1]):
        if a == b:
            out.append(
                Violation(
                    names[a],
                    "own_triangles",
                    f"two of its marker triangles (or one with two vertices swapped) match within {dv:.2f} mm "
                    f"(window {w:g} mm): it can flip when a marker is hidden",
                )
            )
        elif (a, b) not in seen:
            out.append(
                Violation(
                    f"{names[a]} / {names[b]}",
                    "shared_triangle",
                    f"three markers of each match within {dv:.2f} mm (window {w:g} mm): "
                    f"confused when a marker is hidden",
                )
            )
    return out[:limit]


def check_rules(
    names, points, preset: Preset, window_mm: float | None = None, identify_markers: int | None = None
) -> list[Violation]:
    """Every violation of ``preset``'s rules by bodies ``points`` (list of (n, 3) mm arrays).

    ``window_mm``: the distance window the tracker simulation uses (default the preset's
    ``rules.equal_mm``), so that the rule check names exactly the confusions the simulation can
    make; ``identify_markers``: markers an identification needs (default the preset's).
    """
    k = preset.tracker.identify_markers if identify_markers is None else int(identify_markers)
    out: list[Violation] = []
    for nm, P in zip(names, points, strict=True):
        out.extend(check_body(nm, P, preset.rules, window_mm))
    out.extend(
        check_between(
            list(names),
            [np.asarray(p, dtype=float) for p in points],
            preset.rules,
            window_mm=window_mm,
            identify_markers=k,
        )
    )
    return out
