"""Placement settings: the place templates (``templates/place/*.toml``) as validated values,
and the command-line options applied to them."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

from starforge.errors import StarforgeError
from starforge.props.costs import CostSettings
from starforge.props.optimizer import ChainSettings
from starforge.props.seat import MAX_STANDOFF_MM, SeatRules
from starforge.props.sites import Constraints
from starforge.props.tracked import TrackSettings
from starforge.spec import in_range, require


@dataclass(frozen=True)
class EvalSettings:
    """The independent evaluation (:mod:`starforge.props.evaluate`): fresh random poses, none of
    them used by the optimizer, each with its own random camera loss and the hand."""

    poses: int = 1000
    cameras_lost: float = 0.5  # fraction of the rig's cameras lost at random in each pose
    seed_offset: int = 1_000_003  # the evaluation's generator: seed + this (never the optimizer's)

    def __post_init__(self):
        in_range("evaluation.poses", self.poses, 0, 100_000)
        in_range("evaluation.cameras_lost", self.cameras_lost, 0.0, 1.0)


@dataclass(frozen=True)
class PlaceSpec:
    """Everything a placement run needs besides the prop and the seed (``templates/place/*.toml``)."""

    description: str = ""
    objective: Literal["tracked", "paper"] = "paper"
    sites: int = 1000
    resolution: int = 4
    orientations: int = 1
    grazing_limit_deg: float = 80.0
    occlusion: bool = True
    rig: str = "default"
    mesh_format: Literal["glb", "stl"] = "glb"
    costs: CostSettings = field(default_factory=CostSettings)
    chain: ChainSettings = field(default_factory=ChainSettings)
    track: TrackSettings = field(default_factory=TrackSettings)
    constraints: Constraints = field(default_factory=Constraints)
    seat: SeatRules = field(default_factory=SeatRules)
    base_mm: float = 0.0  # diameter of the base under the marker, mm; 0: the marker's own
    standoff_mm: float = 0.0  # a printed post this long lifts every marker off the prop, mm; 0: none
    hand: bool = True  # a hand holds the prop at its grip (an occluder; no markers under it)
    evaluation: EvalSettings = field(default_factory=EvalSettings)
    name: str = "custom"

    def __post_init__(self):
        require(
            self.objective in ("tracked", "paper"),
            f"objective must be tracked or paper, got {self.objective!r}",
        )
        in_range("sites", self.sites, 1, 100000)
        in_range("resolution", self.resolution, 1, 64)
        in_range("orientations", self.orientations, 1, 1000)
        in_range("grazing_limit_deg", self.grazing_limit_deg, 1e-6, 180.0)
        in_range("base_mm", self.base_mm, 0.0, 100.0)
        in_range("standoff_mm (--standoff)", self.standoff_mm, 0.0, MAX_STANDOFF_MM)

    @property
    def marker_diameter_m(self) -> float:
        """The marker ball in effect, m."""
        return self.track.marker_mm / 1000.0 if self.objective == "tracked" else self.costs.marker_diameter_m

    def marker_seat(self):
        """The :class:`starforge.props.seat.Seat` in effect: the catalogue marker of this diameter
        (or ``track.marker``) on its own base or ``base_mm``, lifted ``standoff_mm`` on a post;
        the paper's 2 mm-radius ball rests on the surface (centre one radius up)."""
        from starforge.props.seat import Seat, seat_for, with_standoff

        if self.objective == "paper":
            d = self.costs.marker_diameter_m * 1000.0
            return with_standoff(Seat(f"{d:g} mm ball", d, 0.0, d / 2), self.standoff_mm)
        return with_standoff(seat_for(self.track.marker or self.track.marker_mm, self.base_mm or None), self.standoff_mm)




def load_spec(name_or_path: str = "default") -> PlaceSpec:
    """A placement spec from a shipped template (``default``, ``long``, ``paper``) or a TOML file."""
    from starforge.catalog import load_template, values_from
    from starforge.spec import from_mapping

    name, data = load_template("place", name_or_path)
    data = dict(data)
    data.setdefault("name", name)
    with values_from(name_or_path):
        return from_mapping(PlaceSpec, data, where=f"place spec {name}")


def as_spec(spec: str | PlaceSpec) -> PlaceSpec:
    """``spec`` itself, or the template or TOML file it names (:func:`load_spec`)."""
    return spec if isinstance(spec, PlaceSpec) else load_spec(spec)


def with_overrides(
    spec: PlaceSpec,
    markers: int | None = None,
    resolution: int | None = None,
    orientations: int | None = None,
    sites: int | None = None,
    restarts: int | None = None,
    rig: str | None = None,
    constraints: Constraints | None = None,
    mesh_format: str | None = None,
    marker_mm: str | float | None = None,
    base_mm: float | None = None,
    standoff_mm: float | None = None,
    hand: bool | None = None,
    cameras_lost: float | None = None,
    placement_error_mm: float | None = None,
    distinct_mm: float | None = None,
) -> PlaceSpec:
    """The spec with CLI options applied (each validated by the dataclasses).  ``marker_mm``: a
    diameter in mm or a marker catalogue name (:mod:`starforge.markers`); ``base_mm``: the base
    under it (0: its own); ``standoff_mm``: a printed post under every marker (0: none); ``cameras_lost``: the fraction of the cameras lost in each scenario;
    ``placement_error_mm``: how far off its mark a marker may be stuck and still seat;
    ``distinct_mm``: how far (every sorted side) each marker triangle keeps from the layout's
    others and from other bodies' (``track.avoid_tolerance_mm``)."""
    if markers is not None:
        cs = spec.track if spec.objective == "tracked" else spec.costs
        require(
            cs.min_markers <= markers <= cs.max_markers,
            f"markers must be in [{cs.min_markers}, {cs.max_markers}], got {markers}",
        )
        if spec.objective == "tracked":  # a count asked for is the count placed
            spec = replace(spec, track=replace(spec.track, target_markers=int(markers), grow_markers=False))
        else:
            spec = replace(spec, costs=replace(spec.costs, target_markers=int(markers)))
    if marker_mm is not None:
        from starforge.markers import load_marker, marker_diameter_mm, marker_names

        d = marker_diameter_mm(marker_mm)
        text = str(marker_mm).strip()
        known = {n: load_marker(n).diameter_mm for n in marker_names()}
        if text.lower().endswith("mm") and text not in known and all(abs(v - d) > 1e-9 for v in known.values()):
            raise StarforgeError(
                f"--marker {text}: no catalogue marker is {d:g} mm (known: {', '.join(known)}); for a generic "
                f"ball give its diameter as a plain number (--marker {d:g}: a base of 0.75 diameters is assumed)"
            )
        try:
            float(str(marker_mm).strip().removesuffix("mm"))
            name = ""
        except ValueError:
            name = str(marker_mm).strip()
        spec = replace(
            spec,
            track=replace(spec.track, marker_mm=d, marker=name),
            costs=replace(spec.costs, marker_diameter_m=d / 1000),
        )
    if restarts is not None:
        spec = replace(
            spec,
            chain=replace(spec.chain, restarts=int(restarts)),
            track=replace(spec.track, restarts=int(restarts)),
        )
    if cameras_lost is not None:
        spec = replace(spec, track=replace(spec.track, cameras_lost=float(cameras_lost)))
    if distinct_mm is not None:
        spec = replace(spec, track=replace(spec.track, avoid_tolerance_mm=float(distinct_mm)))
    if placement_error_mm is not None:
        spec = replace(spec, seat=replace(spec.seat, placement_error_mm=float(placement_error_mm)))
    kw = {
        k: v
        for k, v in dict(
            base_mm=None if base_mm is None else float(base_mm),
            standoff_mm=None if standoff_mm is None else float(standoff_mm),
            hand=hand,
            resolution=resolution,
            orientations=orientations,
            sites=sites,
            rig=rig,
            constraints=constraints,
            mesh_format=mesh_format,
        ).items()
        if v is not None
    }
    if "mesh_format" in kw:
        require(
            kw["mesh_format"] in ("glb", "stl"), f"mesh_format must be glb or stl, got {kw['mesh_format']!r}"
        )
    return replace(spec, **kw) if kw else spec


