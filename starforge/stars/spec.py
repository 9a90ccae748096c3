"""The star-family specification: validated, with the paper's finger case as the defaults' model."""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, fields
from typing import Literal, get_args

from starforge.errors import StarforgeError
from starforge.spec import from_mapping, positive, require

#: default work budget of the exact selection, nonzeros x branch-and-bound nodes
WORK = 8_000_000
#: largest work budget accepted (about a day of solving)
MAX_WORK = 10**12
#: largest marker noise accepted, mm (sigma per axis): beyond, no tracker identifies anything
MAX_NOISE_MM = 100.0

Rule = Literal["face", "pair"]
Select = Literal["max", "greedy"]
BoxMethod = Literal["exact", "covariance"]


@dataclass(frozen=True)
class StarSpec:
    """What family to make.  All lengths in mm.

    Attributes
    ----------
    box_mm : (3,) float
        Size limit for the physical star (sphere surfaces included), any order.
    marker_mm : float
        Finished marker sphere diameter.
    delta_mm : float
        Minimal length variation: the step of the edge-length pool (the paper's delta).
    gap_mm : float
        Minimum clear gap between two sphere surfaces; ``l_min_mm`` defaults to marker + gap.
    l_min_mm, l_max_mm : float or None
        Edge-length pool bounds; ``l_max_mm`` defaults to the diagonal of the centre box
        (``box_mm - marker_mm``), the longest segment that can fit.
    rule : "face" or "pair"
        Uniqueness rule (see :mod:`starforge.stars.rules`).
    tolerance_mm : float or None
        Two faces (or edges) closer than this are indistinguishable; defaults to ``delta_mm``.
    select : "max" or "greedy"
        As large a family as can be found (exact set packing where it can be proven, with a
        certified upper bound) or the paper's greedy growth.
    count : int or None
        Return exactly this many stars: the most accurate (smallest predicted tip error with one
        marker hidden) that are mutually distinguishable.
    box_method : "exact" or "covariance"
        "exact": a star fits when some rotation puts its centres' box inside the limit (decided
        by branch and bound, complete up to 0.01 mm; :mod:`starforge.geometry.fit`);
        "covariance": the paper's covariance OBB must fit.
    min_depth_mm : float or None
        Smallest allowed depth of a star: its width, the smallest side of any box around its
        centres in any orientation.  Default half the marker diameter; 0 allows flat stars.
    tip_mm : (3,) float or None
        Target point for the predicted accuracy, in each star's placement frame; default
        :func:`starforge.geometry.rigid.default_tip_mm` (long axis, one limit length below).
    noise_mm : float
        Marker-centre noise (sigma per axis) for the predicted accuracy, mm.
    work : int
        The exact solver's work budget, in nonzeros of the set packing x branch-and-bound nodes
        (HiGHS's node limit): deterministic, so the family, its bound and whether it is proven
        optimal are the same on any machine and at any load.  The default proves the finger
        cases optimal where HiGHS can; a spec whose proof needs more reports "not optimal" with
        its certified bound.
    reserve_mm : (3,) float
        Millimetres of the size limit kept free for a mount, along its shortest, middle and
        longest side (a manual override; ``mount`` computes it).
    mount : str or None
        The mount the family is printed with (``starforge mounts``): its room is reserved from
        its geometry (:func:`starforge.cad.reserve.mount_reserve_mm`) and every star's printed
        body is checked against the limit, so ``export`` with this mount never refuses.
    marker : str or None
        The catalogue marker the bodies are designed for (``templates/markers``, or a TOML file);
        ``marker_mm`` is its diameter.  With ``mount``, its seat's room is reserved too.
    seat : str or None
        What each stem ends in (sphere, glue, post, screw, insert; see
        :class:`starforge.cad.body.BodySpec`); None: the marker's own attachment, else a sphere.
    name : str
        Family name; the default output folder is ``out/<name>``.
    description : str
        Free text carried into family.json.
    """

    box_mm: tuple[float, float, float]
    marker_mm: float = 4.0
    delta_mm: float = 1.5
    gap_mm: float = 1.0
    l_min_mm: float | None = None
    l_max_mm: float | None = None
    rule: Rule = "face"
    tolerance_mm: float | None = None
    select: Select = "max"
    count: int | None = None
    box_method: BoxMethod = "exact"
    min_depth_mm: float | None = None
    tip_mm: tuple[float, float, float] | None = None
    noise_mm: float = 0.2
    work: int = WORK
    reserve_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount: str | None = None
    marker: str | None = None
    seat: str | None = None
    name: str = "custom"
    description: str = ""

    def __post_init__(self) -> None:
        require(len(self.box_mm) == 3, f"box_mm needs 3 sizes, got {len(self.box_mm)}")
        for i, b in enumerate(self.box_mm):
            positive(f"box_mm[{i}]", b)
        positive("marker_mm", self.marker_mm)
        require(
            self.marker_mm >= 0.5,
            f"marker_mm must be >= 0.5 mm (retroreflective markers are about 2-40 mm), got {self.marker_mm:g}",
        )
        require(
            self.seat is None or self.seat in ("sphere", "glue", "post", "screw", "insert"),
            f"seat must be one of sphere, glue, post, screw, insert, got {self.seat!r}",
        )
        positive("delta_mm", self.delta_mm)
        require(
            self.delta_mm >= 1e-3,
            f"delta_mm must be >= 0.001 mm (a length variation no printer or tracker resolves below that), "
            f"got {self.delta_mm}",
        )
        for i, b in enumerate(self.box_mm):
            require(b <= 10_000, f"box_mm[{i}] must be <= 10000 mm (a star of 4 markers), got {b}")
        if self.min_depth_mm is not None:
            require(
                math.isfinite(self.min_depth_mm) and self.min_depth_mm >= 0,
                f"min_depth_mm must be >= 0, got {self.min_depth_mm}",
            )
        if self.tip_mm is not None:
            require(len(self.tip_mm) == 3, f"tip_mm needs 3 coordinates, got {len(self.tip_mm)}")
            for i, t in enumerate(self.tip_mm):
                require(math.isfinite(t) and abs(t) <= 1e5, f"tip_mm[{i}] must be within 100 m, got {t}")
        require(math.isfinite(self.noise_mm) and self.noise_mm > 0, f"noise_mm must be > 0, got {self.noise_mm}")
        require(
            self.noise_mm <= MAX_NOISE_MM,
            f"noise_mm must be at most {MAX_NOISE_MM:g} mm (sigma per axis), got {self.noise_mm:g}",
        )
        require(self.gap_mm >= 0 and math.isfinite(self.gap_mm), f"gap_mm must be >= 0, got {self.gap_mm}")
        require(self.gap_mm <= 10_000, f"gap_mm must be <= 10000 mm (the largest box side), got {self.gap_mm:g}")
        require(
            isinstance(self.work, int) and 1 <= self.work <= MAX_WORK,
            f"work must be an integer in [1, {MAX_WORK:.0e}] (nonzeros x solver nodes), got {self.work}",
        )
        if self.tolerance_mm is not None:
            positive("tolerance_mm", self.tolerance_mm)
        if self.count is not None:
            require(self.count >= 1, f"count must be >= 1, got {self.count}")
        small = min(self.box_mm)
        require(
            small > self.marker_mm,
            f"box_mm {list(self.box_mm)} is too small for one {self.marker_mm} mm sphere "
            f"(smallest side {small} mm must exceed marker_mm)",
        )
        require(len(self.reserve_mm) == 3, f"reserve_mm needs 3 values, got {len(self.reserve_mm)}")
        for i, r in enumerate(self.reserve_mm):
            require(math.isfinite(r) and r >= 0, f"reserve_mm[{i}] must be >= 0, got {r}")
        lim = [x - self.marker_mm - r for x, r in zip(sorted(self.box_mm), self.reserve_mm, strict=True)]
        require(
            lim[0] > 0,
            f"{'mount ' + self.mount + ' needs ' if self.mount else 'reserve_mm[0] '}{self.reserve_mm[0]} mm, which leaves no room on the shortest side "
            f"({small:g} mm less one {self.marker_mm:g} mm sphere)",
        )
        why = f"mount {self.mount} needs" if self.mount else "reserve_mm"
        require(
            lim[0] <= lim[1] <= lim[2],
            f"{why} {list(self.reserve_mm)} mm of the sorted sides of box_mm {list(self.box_mm)}, leaving "
            f"{[round(x, 3) for x in lim]} mm for the sphere centres out of order: the body no longer lies flat "
            f"in this limit (choose another mount or a larger box)",
        )
        if self.l_min_mm is not None:
            positive("l_min_mm", self.l_min_mm)
            require(
                self.l_min_mm >= self.marker_mm,
                f"l_min_mm must be >= marker_mm ({self.marker_mm}) so spheres do not overlap, got {self.l_min_mm}",
            )
        if self.l_max_mm is not None:
            positive("l_max_mm", self.l_max_mm)
        lo, hi = self.pool_bounds_mm
        require(
            hi > lo,
            f"no star fits: its shortest edge (marker_mm + gap_mm, {lo:.2f} mm) is longer than the longest "
            f"that fits in box_mm {[float(x) for x in self.box_mm]} less one marker ({hi:.2f} mm)"
            if self.l_min_mm is None and self.l_max_mm is None
            else f"the edge-length pool is empty: l_min_mm {lo:.2f} mm >= l_max_mm {hi:.2f} mm",
        )
        require(
            self.pool_size >= 6,
            f"delta_mm {self.delta_mm} is too large: the pool [{lo:.2f}, {hi:.2f}] mm holds only "
            f"{self.pool_size} lengths and a star needs 6 different ones (delta_mm <= {(hi - lo) / 5:.3f})",
        )
        require(
            (hi - lo) >= 5 * self.tol_mm - 1e-9,
            f"tolerance_mm {self.tol_mm:g} is too large for the pool [{lo:.2f}, {hi:.2f}] mm: a star needs six "
            f"lengths that differ pairwise by the tolerance, so it must be <= {(hi - lo) / 5:.3f} mm",
        )
        require(
            self.depth_mm < self.centre_limit_mm[0],
            f"min_depth_mm {self.depth_mm:g} leaves no star: the centres' box is at most "
            f"{self.centre_limit_mm[0]:.3g} mm deep inside this limit",
        )

    @property
    def tol_mm(self) -> float:
        """The face/edge tolerance in effect, mm."""
        return self.delta_mm if self.tolerance_mm is None else self.tolerance_mm

    @property
    def grid_steps(self) -> int:
        """m: two pool lengths are told apart iff they differ by >= m pool steps (>= tolerance)."""
        return max(1, math.ceil(self.tol_mm / self.delta_mm - 1e-9))

    @property
    def depth_mm(self) -> float:
        """The minimum depth in effect, mm (default half the marker diameter)."""
        return self.marker_mm / 2 if self.min_depth_mm is None else float(self.min_depth_mm)

    @property
    def centre_limit_mm(self) -> tuple[float, float, float]:
        """Sorted (ascending) box that the sphere centres must fit, mm: the limit less one marker
        diameter, and its shortest side less ``reserve_mm``."""
        a, b, c = (x - self.marker_mm - r for x, r in zip(sorted(self.box_mm), self.reserve_mm, strict=True))
        return (a, b, c)

    @property
    def pool_bounds_mm(self) -> tuple[float, float]:
        lo = self.marker_mm + self.gap_mm if self.l_min_mm is None else self.l_min_mm
        if self.l_max_mm is None:
            hi = math.sqrt(sum(c * c for c in self.centre_limit_mm))
        else:
            hi = self.l_max_mm
        return lo, hi

    @property
    def pool_size(self) -> int:
        lo, hi = self.pool_bounds_mm
        if not hi >= lo:
            return 0
        n = (hi - lo) / self.delta_mm + 1e-9
        return int(math.floor(n)) + 1 if n < 1e9 else 10**9  # capped: bounded-cost checks refuse it


#: what each field of a StarSpec is when neither a template nor an option sets it (the CLI's help)
STAR_DEFAULTS = {f.name: f.default for f in fields(StarSpec) if f.default is not MISSING}

#: the values each choice field accepts
STAR_CHOICES = {"rule": get_args(Rule), "select": get_args(Select), "box_method": get_args(BoxMethod)}


def spec_from_mapping(data: dict, name: str | None = None) -> StarSpec:
    """A StarSpec from TOML/JSON data (unknown keys refused)."""
    data = dict(data)
    # a wall-clock limit (written by older files) no longer decides anything: the work budget does
    data.pop("time_limit_s", None)
    if name is not None and "name" not in data:
        data["name"] = name
    if "box_mm" not in data:
        raise StarforgeError("missing key box_mm in spec (the size limit, three numbers in mm)")
    return from_mapping(StarSpec, data)
