"""The result of a placement: the chosen markers with everything needed to re-check them."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from starforge.props.costs import CostBreakdown
from starforge.props.optimizer import AnnealResult
from starforge.props.sites import Sites
from starforge.props.spec import PlaceSpec


@dataclass(frozen=True)
class PlacementResult:
    """One optimized placement with everything needed to re-check it."""

    prop: object  # PropMesh
    spec: PlaceSpec
    seed: int
    rig: object  # Rig
    poses: object  # Poses
    sites: Sites
    forbidden: int
    site_visibility: np.ndarray = field(repr=False)
    marker_sites: tuple[int, ...] = ()
    cost: CostBreakdown | None = None
    anneal: AnnealResult | None = None
    marker_pose_seen: np.ndarray = field(default=None, repr=False)  # (m, scenarios) seen
    timings: dict = field(default_factory=dict)
    rays: int = 0
    tracked: object = None  # starforge.props.tracked_optimizer.Optimized for the tracked objective
    warnings: tuple[str, ...] = ()
    spacing_m: float = 0.0
    seat: object = None  # starforge.props.seat.Seat
    seat_report: object = None  # starforge.props.seat.SeatReport over ``sites``
    capsules: tuple = ()  # the hand (starforge.props.hand.Capsule)
    removed: dict = field(default_factory=dict)  # sampled sites removed, by reason
    evaluation: dict = field(default_factory=dict)  # starforge.props.evaluate on fresh poses
    marker_masks: np.ndarray = field(default=None, repr=False)  # (m, poses) uint64 camera bits
    shortfall: dict = field(default_factory=dict)  # below track.target_tracked on the held-out sample: why
    grips: tuple = ()  # starforge.props.grips.Grip: the hand's distribution the layout was scored under
    part: object = None  # starforge.props.grips.HeldPart: where they hold it

    @property
    def marker_points(self) -> np.ndarray:
        return self.sites.points[list(self.marker_sites)]

    @property
    def marker_normals(self) -> np.ndarray:
        return self.sites.normals[list(self.marker_sites)]

    @property
    def marker_visibility(self) -> np.ndarray:
        return self.site_visibility[list(self.marker_sites)]

    def centres(self, sites=None) -> np.ndarray:
        """(m, 3) ball centres of ``sites`` (default: the markers), m: on the seat's axis."""
        idx = list(self.marker_sites if sites is None else sites)
        return self.sites.points[idx] + self.seat.centre_height_m * self.sites.normals[idx]


def tick(timings: dict, key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = round(now - t0, 4)
    return now
