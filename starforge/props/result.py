"""The result of a placement: the chosen markers with everything needed to re-check them."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from starforge.props.costs import CostBreakdown
from starforge.props.optimizer import AnnealResult
from starforge.props.sites import Sites
from starforge.props.spec import PlaceSpec

if TYPE_CHECKING:
    from starforge.props.grips import Grip, HeldPart
    from starforge.props.hand import Capsule
    from starforge.props.mesh import PropMesh
    from starforge.props.rig import Poses, Rig
    from starforge.props.seat import Seat, SeatReport
    from starforge.props.tracked_optimizer import Optimized


@dataclass(frozen=True)
class PlacementResult:
    """One optimized placement with everything needed to re-check it."""

    prop: PropMesh
    spec: PlaceSpec
    seed: int
    rig: Rig
    poses: Poses
    sites: Sites
    forbidden: int
    site_visibility: np.ndarray = field(repr=False)
    marker_sites: tuple[int, ...] = ()
    cost: CostBreakdown | None = None
    anneal: AnnealResult | None = None
    marker_pose_seen: np.ndarray = field(default=None, repr=False)  # (m, scenarios) seen
    timings: dict = field(default_factory=dict)
    rays: int = 0
    tracked: Optimized | None = None  # the tracked objective's optimizer: every candidate and baseline
    warnings: tuple[str, ...] = ()
    spacing_m: float = 0.0
    seat: Seat | None = None
    seat_report: SeatReport | None = None  # over ``sites``
    capsules: tuple[Capsule, ...] = ()  # the hand: every grip's capsules
    removed: dict = field(default_factory=dict)  # sampled sites removed, by reason
    evaluation: dict = field(default_factory=dict)  # starforge.props.evaluate on fresh poses
    marker_masks: np.ndarray = field(default=None, repr=False)  # (m, poses) uint64 camera bits
    shortfall: dict = field(default_factory=dict)  # below track.target_tracked on the held-out sample: why
    grips: tuple[Grip, ...] = ()  # the hand's distribution the layout was scored under
    part: HeldPart | None = None  # where they hold it

    @property
    def marker_points(self) -> np.ndarray:
        return self.sites.points[list(self.marker_sites)]

    @property
    def marker_normals(self) -> np.ndarray:
        return self.sites.normals[list(self.marker_sites)]

    @property
    def marker_rods_mm(self) -> np.ndarray:
        """(m,) the diameter of the rod each marker's post is clamped round, mm (0: it stands on
        its foot; :mod:`starforge.props.clamp`)."""
        rods = None if self.seat_report is None else self.seat_report.clamp_m
        if rods is None:
            return np.zeros(len(self.marker_sites))
        return 2000.0 * np.asarray(rods, float)[list(self.marker_sites)]

    @property
    def marker_rod_axes(self) -> np.ndarray:
        """(m, 3) the axis of the rod each marker is clamped round (zero where it stands on its foot)."""
        axes = None if self.seat_report is None else self.seat_report.clamp_axis
        if axes is None:
            return np.zeros((len(self.marker_sites), 3))
        return np.asarray(axes, float)[list(self.marker_sites)]

    @property
    def marker_visibility(self) -> np.ndarray:
        return self.site_visibility[list(self.marker_sites)]

    @cached_property
    def rigging(self) -> tuple[list[dict], list[dict]]:
        """What the rigging guide says (computed once, for placement.json and the drawings): the
        prop's landmarks (:func:`starforge.props.guide.mesh_landmarks`) and, per marker, where
        it is measured from (:func:`starforge.props.guide.landmarks`)."""
        from starforge.props.guide import landmarks, prop_guide

        guide = prop_guide(self.prop)
        faces = self.sites.faces[list(self.marker_sites)]
        marks = landmarks(guide, self.marker_points, self.marker_normals, faces, self.spec.seat.placement_error_mm)
        return guide.landmarks, marks

    def centres(self, sites=None) -> np.ndarray:
        """(m, 3) ball centres of ``sites`` (default: the markers), m: on the seat's axis."""
        idx = list(self.marker_sites if sites is None else sites)
        return self.sites.points[idx] + self.seat.centre_height_m * self.sites.normals[idx]


def tick(timings: dict, key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = round(now - t0, 4)
    return now
