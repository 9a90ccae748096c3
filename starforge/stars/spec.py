"""The star-family specification: validated, with the paper's finger case as the defaults' model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from starforge.errors import StarforgeError
from starforge.spec import from_mapping, positive, require

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
        Exact set packing (HiGHS MILP, time-limited) or the paper's greedy growth.
    count : int or None
        Return exactly this many stars (most compact, widest margins first).
    box_method : "exact" or "covariance"
        "exact": a star fits when some box around its centres fits (minimum-volume box
        reported); "covariance": the paper's covariance OBB must fit.
    time_limit_s : float
        Time limit for the MILP.
    reserve_mm : (3,) float
        Millimetres of the size limit kept free for a mount, along its shortest, middle and
        longest side.  Printed bodies stack their mount on the star's shortest side and the
        plate overhangs the spheres a little; for the default flat mount (1 mm standoff, 2 mm
        plate, margins) ``(3, 1.2, 1.2)`` leaves room so every body fits the limit too.
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
    time_limit_s: float = 5.0
    reserve_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "custom"
    description: str = ""

    def __post_init__(self) -> None:
        require(len(self.box_mm) == 3, f"box_mm needs 3 sizes, got {len(self.box_mm)}")
        for i, b in enumerate(self.box_mm):
            positive(f"box_mm[{i}]", b)
        positive("marker_mm", self.marker_mm)
        positive("delta_mm", self.delta_mm)
        require(self.gap_mm >= 0 and math.isfinite(self.gap_mm), f"gap_mm must be >= 0, got {self.gap_mm}")
        positive("time_limit_s", self.time_limit_s)
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
            f"reserve_mm[0] {self.reserve_mm[0]} leaves no room on the shortest side "
            f"({small:g} mm less one {self.marker_mm:g} mm sphere)",
        )
        require(
            lim[0] <= lim[1] <= lim[2],
            f"reserve_mm {list(self.reserve_mm)} reorders the sides of box_mm {list(self.box_mm)}: "
            f"keep the reserved box's shortest, middle and longest sides in order",
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
        require(hi > lo, f"the edge-length pool is empty: l_min {lo:.3f} mm >= l_max {hi:.3f} mm")
        require(
            self.pool_size >= 6,
            f"delta_mm {self.delta_mm} is too large: the pool [{lo:.2f}, {hi:.2f}] mm holds only "
            f"{self.pool_size} lengths and a star needs 6 different ones (delta_mm <= {(hi - lo) / 5:.3f})",
        )

    @property
    def tol_mm(self) -> float:
        """The face/edge tolerance in effect, mm."""
        return self.delta_mm if self.tolerance_mm is None else self.tolerance_mm

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
        return int(math.floor((hi - lo) / self.delta_mm + 1e-9)) + 1 if hi >= lo else 0


def spec_from_mapping(data: dict, name: str | None = None) -> StarSpec:
    """A StarSpec from TOML/JSON data (unknown keys refused)."""
    data = dict(data)
    if name is not None and "name" not in data:
        data["name"] = name
    if "box_mm" not in data:
        raise StarforgeError("missing key box_mm in spec (the size limit, three numbers in mm)")
    return from_mapping(StarSpec, data)
