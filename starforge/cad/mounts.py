"""Mounts: parametric bases from ``templates/mounts/<name>.toml`` and their plain-data geometry.

A mount template names its ``kind`` (one of :data:`KINDS`), a description, default
``[params]`` and the allowed ``[ranges]`` of each parameter (both in the file, so the ranges are
documented where the values are edited).  Every mount is a plate under the star in the x-z plane
(the star lies flat; +y is up, see :mod:`starforge.cad.primitives`) plus kind-specific features:

- ``flat``: screw holes through the plate, placed clear of the stems;
- ``strap``: a tunnel through the base, crossing it along x, for a Velcro strap that wraps around
  the limb (whose axis runs along the star's long side, z): the strap presses the tunnel's floor
  onto the limb and adds nothing to the body's width; printed plate-down the floor is the first
  layer and the roof is a short bridge across the strap;
- ``saddle``: a concave channel underneath that sits on a cylinder (a finger segment) of a given
  diameter, between two flat rails that the body prints on (no region starts in mid-air: the
  channel's roof is a short bridge between the rails);
- ``adhesive``: a shallow recess underneath for a double-sided adhesive pad;
- ``magnet``: a blind pocket from below for a disc magnet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.cad.primitives import Box, Cylinder, Revolved
from starforge.catalog import list_templates, load_template, values_from
from starforge.spec import in_range, require

COMMON = ("thickness_mm", "margin_mm")
#: candidate spots per side of a footprint at most (a label or hole spot search stays bounded)
MAX_GRID = 400
#: the longest bridge a pocket's ceiling may span, mm (FDM prints about this much unsupported
#: across a gap without sagging; wider pockets narrow to it under a 45 deg chamfer)
PRINTABLE_BRIDGE_MM = 5.0
#: the strap tunnel's roof steps up and in by a multiple of this, mm (45 deg; exact in binary),
#: in at most :data:`STRAP_MAX_STEPS` steps (each a ledge that overhangs by one step)
STRAP_STEP_MM = 0.25
STRAP_MAX_STEPS = 12
#: the strap tunnel is this much wider than the strap (mm)
STRAP_PLAY_MM = 0.5
KINDS: dict[str, tuple[str, ...]] = {
    "flat": (*COMMON, "holes", "hole_mm", "hole_wall_mm"),
    "strap": (*COMMON, "strap_width_mm", "slot_mm", "floor_mm", "wall_mm"),
    "saddle": (*COMMON, "segment_mm", "channel_mm", "land_mm"),
    "adhesive": (*COMMON, "pad_width_mm", "pad_length_mm", "recess_mm", "rim_mm"),
    "magnet": (*COMMON, "magnet_mm", "magnet_height_mm", "floor_mm", "wall_mm"),
}
_INTS = {"holes"}


@dataclass(frozen=True)
class Mount:
    """A validated mount: ``kind`` plus its parameters (lengths in mm).

    Attributes
    ----------
    name : str             template name (or file stem)
    kind : str             one of :data:`KINDS`
    params : dict          parameter -> value (every name of ``KINDS[kind]``)
    ranges : dict          parameter -> (lo, hi), the documented allowed range
    description : str
    """

    name: str
    kind: str
    params: dict = field(hash=False)
    ranges: dict = field(hash=False)
    description: str = ""

    def __getitem__(self, key: str) -> float:
        return self.params[key]


def mount_from_mapping(name: str, data: dict, overrides: dict | None = None) -> Mount:
    """Validate a template mapping (plus ``overrides``, e.g. from ``--set``) into a :class:`Mount`."""
    where = f"mount {name}"
    unknown = sorted(set(data) - {"kind", "description", "params", "ranges"})
    require(
        not unknown,
        f"unknown key(s) {', '.join(unknown)} in {where}; known: kind, description, params, ranges",
    )
    kind = data.get("kind")
    require(kind in KINDS, f"{where}: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    names = KINDS[kind]
    params = dict(data.get("params", {}))
    ranges = dict(data.get("ranges", {}))
    for k, v in (overrides or {}).items():
        params[k] = v
    for table in (params, ranges):
        bad = sorted(set(table) - set(names))
        require(
            not bad,
            f"unknown {kind} mount parameter(s) {', '.join(bad)} in {where}; known: {', '.join(names)}",
        )
    missing = [n for n in names if n not in params or n not in ranges]
    require(not missing, f"{where}: parameter(s) {', '.join(missing)} need a value and a range")
    clean = {}
    for n in names:
        pair = ranges[n]
        require(
            isinstance(pair, list | tuple) and len(pair) == 2
            and all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in pair)
            and pair[0] <= pair[1],
            f"{where}: ranges.{n} must be [low, high], two finite numbers, got {pair!r}",
        )
        lo, hi = float(pair[0]), float(pair[1])
        v = in_range(n, params[n], lo, hi)
        if n in _INTS:
            require(v == int(v), f"{n} must be an integer, got {params[n]}")
            v = int(v)
        clean[n] = v
        ranges[n] = (lo, hi)
    return Mount(
        name=name, kind=kind, params=clean, ranges=ranges, description=str(data.get("description", ""))
    )


def load_mount(name_or_path: str | Path, overrides: dict | None = None) -> Mount:
    """A mount by template name (``flat``) or TOML path; unknown names list the known ones."""
    name, data = load_template("mounts", name_or_path)
    with values_from(name_or_path, given=set(overrides or ())):
        return mount_from_mapping(name, data, overrides)


def list_mounts() -> list[Mount]:
    """Every shipped mount template, validated."""
    return [load_mount(n) for n in list_templates("mounts")]


# --------------------------------------------------------------------------------------------
# Layout in the plate plane (x, z): pure functions.


def rect_circle_clearance(centre_xz, size_xz, circles) -> float:
    """Smallest gap (mm) between an axis-aligned rectangle and circles ``(x, z, r)``; < 0 overlaps."""
    if len(circles) == 0:
        return math.inf
    c = np.atleast_2d(np.asarray(circles, float))
    half = np.asarray(size_xz, float) / 2
    d = np.maximum(np.abs(c[:, :2] - np.asarray(centre_xz, float)) - half, 0.0)
    return float((np.linalg.norm(d, axis=1) - c[:, 2]).min())


def find_spot(footprint, size_xz, circles, edge_mm: float, step_mm: float = 0.25):
    """Centre (x, z) of a ``size_xz`` rectangle inside ``footprint`` clear of ``circles``.

    Parameters
    ----------
    footprint : (x0, x1, z0, z1) mm
    size_xz : (w, h) mm
    circles : (n, 3) obstacles (x, z, radius) mm; the rectangle keeps out of them
    edge_mm : float, distance kept from the footprint's border
    step_mm : float, grid step of the candidate centres (coarsened so that a side holds at most
        :data:`MAX_GRID` candidates: the cost stays bounded however large the footprint)

    Returns the candidate with the largest clearance (capped at 1 mm; ties: nearest the
    footprint's -z end, then its centre line), or None when nothing fits.
    """
    x0, x1, z0, z1 = footprint
    w, h = size_xz
    xs_lo, xs_hi = x0 + edge_mm + w / 2, x1 - edge_mm - w / 2
    zs_lo, zs_hi = z0 + edge_mm + h / 2, z1 - edge_mm - h / 2
    if xs_lo > xs_hi + 1e-9 or zs_lo > zs_hi + 1e-9:
        return None
    step_mm = max(step_mm, (xs_hi - xs_lo) / MAX_GRID, (zs_hi - zs_lo) / MAX_GRID)
    xs = np.arange(xs_lo, xs_hi + 1e-9, step_mm) if xs_hi > xs_lo else np.array([xs_lo])
    zs = np.arange(zs_lo, zs_hi + 1e-9, step_mm) if zs_hi > zs_lo else np.array([zs_lo])
    gx, gz = np.meshgrid(xs, zs)
    cand = np.column_stack([gx.ravel(), gz.ravel()])
    if len(circles) == 0:
        clear = np.full(len(cand), np.inf)
    else:
        c = np.atleast_2d(np.asarray(circles, float))
        d = np.maximum(np.abs(c[None, :, :2] - cand[:, None, :]) - np.array([w, h]) / 2, 0.0)
        clear = (np.linalg.norm(d, axis=2) - c[None, :, 2]).min(axis=1)
    ok = clear >= 0
    if not ok.any():
        return None
    cand, clear = cand[ok], clear[ok]
    xm = (x0 + x1) / 2
    best = np.lexsort(
        (np.abs(cand[:, 0] - xm), np.abs(cand[:, 1] - z0), -np.round(np.minimum(clear, 1.0), 9))
    )[0]
    return (float(cand[best, 0]), float(cand[best, 1]))


def reserve(footprint, size_xz, circles, edge_mm: float):
    """Like :func:`find_spot`, but grows the footprint at its -z end when nothing fits.

    Returns ``(centre_xz, footprint)``; the footprint also widens (in x, symmetric) when the
    rectangle is wider than it.
    """
    spot = find_spot(footprint, size_xz, circles, edge_mm)
    if spot is not None:
        return spot, tuple(footprint)
    x0, x1, z0, z1 = footprint
    w, h = size_xz
    need_w = w + 2 * edge_mm
    if x1 - x0 < need_w:
        xm = (x0 + x1) / 2
        x0, x1 = xm - need_w / 2, xm + need_w / 2
    z0 -= h + edge_mm
    return ((x0 + x1) / 2, z0 + edge_mm + h / 2), (x0, x1, z0, z1)


@dataclass(frozen=True)
class MountGeometry:
    """What a mount adds to and cuts from the body (plain data).

    Attributes
    ----------
    add : tuple of primitives      the plate (and its blocks)
    subtract : tuple of primitives holes, slots, pockets, recesses, the saddle's cylinder
    footprint : (x0, x1, z0, z1)   the plate's extent in the x-z plane, mm
    y_bottom : float               lowest point of the mount, mm
    label_centre : (x, z) or None  where the id label goes on the plate top
    """

    add: tuple
    subtract: tuple
    footprint: tuple
    y_bottom: float
    label_centre: tuple | None


def mount_geometry(
    mount: Mount,
    roots_xz,
    stem_radius_mm: float,
    y_top: float,
    label_size_xz=None,
    min_footprint=None,
    overhead_xz=None,
) -> MountGeometry:
    """The mount under stems rooted at ``roots_xz`` (n, 2) mm, its top face at ``y_top`` mm.

    ``label_size_xz`` (w, h) reserves room for the id label on the top face (None: no label);
    ``min_footprint`` (x0, x1, z0, z1) is a footprint the plate covers at least;
    ``overhead_xz`` (n, 3) circles (x, z, radius) of what hangs over the plate (the spheres):
    screw holes avoid them when they can, so a screwdriver reaches the screw from above.
    """
    p = mount.params
    roots = np.atleast_2d(np.asarray(roots_xz, float))
    m = p["margin_mm"]
    fp = (
        roots[:, 0].min() - stem_radius_mm - m,
        roots[:, 0].max() + stem_radius_mm + m,
        roots[:, 1].min() - stem_radius_mm - m,
        roots[:, 1].max() + stem_radius_mm + m,
    )
    if min_footprint is not None:
        fp = (
            min(fp[0], min_footprint[0]),
            max(fp[1], min_footprint[1]),
            min(fp[2], min_footprint[2]),
            max(fp[3], min_footprint[3]),
        )
    circles = [(x, z, stem_radius_mm + 0.4) for x, z in roots]
    add, sub = [], []
    t = p["thickness_mm"]
    kind = mount.kind

    if kind == "adhesive":
        fp = _at_least(fp, p["pad_width_mm"] + 2 * p["rim_mm"], p["pad_length_mm"] + 2 * p["rim_mm"])
    if kind == "magnet":
        t = max(t, p["magnet_height_mm"] + magnet_chamfer_mm(p) + p["floor_mm"])
        d = p["magnet_mm"] + 2 * p["wall_mm"]
        fp = _at_least(fp, d, d)
    if kind == "strap":
        t = p["thickness_mm"] + p["slot_mm"] + strap_roof_mm(p) + p["floor_mm"]  # roof, vault, tunnel, floor
        fp = _at_least(fp, 0.0, p["strap_width_mm"] + STRAP_PLAY_MM + 2 * p["wall_mm"])
    if kind == "saddle":
        fp = _at_least(fp, p["channel_mm"] + 2 * p["land_mm"], 0.0)

    label_centre = None
    if label_size_xz is not None:
        label_centre, fp = reserve(fp, label_size_xz, circles, edge_mm=min(m, 1.0))
        w, h = label_size_xz
        circles.append((label_centre[0], label_centre[1], 0.5 * math.hypot(w, h)))

    if kind == "flat":
        r = p["hole_mm"] / 2
        for _ in range(int(p["holes"])):
            s = 2 * (r + p["hole_wall_mm"])
            spot = None
            if overhead_xz is not None and len(overhead_xz):
                spot = find_spot(fp, (s, s), [*circles, *map(tuple, np.asarray(overhead_xz, float))], 0.0)
            if spot is None:
                spot, fp = reserve(fp, (s, s), circles, edge_mm=0.0)
            hx, hz = spot
            sub.append(Cylinder((hx, y_top - t - 1.0, hz), (hx, y_top + 0.1, hz), r))
            circles.append((hx, hz, s / 2))
    x0, x1, z0, z1 = fp
    xm, zm, w, ln = (x0 + x1) / 2, (z0 + z1) / 2, x1 - x0, z1 - z0
    y_bottom = y_top - t
    if kind == "saddle":
        sag, half_c = saddle_profile(p)
        y_bottom = y_top - t - sag
        # the channel: the segment's cylinder, its top line t below the plate's top face, cut
        # only between the rails (its chord at the bottom face is channel_mm wide)
        R = p["segment_mm"] / 2
        yc = y_top - t - R
        sub.append(Cylinder((xm, yc, z0 - 1.0), (xm, yc, z1 + 1.0), R))
    if kind == "strap":
        # the tunnel: through along x, strap_width (+ play) wide along z at the plate's middle,
        # slot_mm high above a floor_mm floor, then (for a tunnel wider than a printable bridge)
        # a roof stepping in by one step per step of height (45 deg) down to that bridge; the
        # plate above it is thickness_mm thick.  Coordinates on a 1/1024 mm grid: the steps'
        # faces meet exactly (no slivers).
        g = 1.0 / 1024
        snap = lambda v: round(v / g) * g  # noqa: E731
        y0, zc, xc = snap(y_bottom + p["floor_mm"]), snap(zm), snap(xm)
        wide = snap(p["strap_width_mm"] + STRAP_PLAY_MM)
        top = y0 + snap(p["slot_mm"])
        xs = snap(w + 2.0)
        sub.append(Box((xc, (y0 + top) / 2, zc), (xs, top - y0, wide)))
        n, step = strap_roof(p)
        for k in range(1, n + 1):
            hi = top + k * step
            sub.append(Box((xc, (y0 + hi) / 2, zc), (xs, hi - y0, wide - 2 * k * step)))
    if kind == "adhesive":
        rd = p["recess_mm"]
        sub.append(Box((xm, y_bottom + rd / 2 - 0.5, zm), (p["pad_width_mm"], rd + 1.0, p["pad_length_mm"])))
    if kind == "magnet":
        # the pocket, then a 45 deg chamfer narrowing its ceiling to a printable bridge
        r = p["magnet_mm"] / 2
        h = p["magnet_height_mm"]
        ch = magnet_chamfer_mm(p)
        prof = [(0.0, r), (1.0 + h, r)] + ([(1.0 + h + ch, r - ch)] if ch > 0 else [])
        sub.append(Revolved((xm, y_bottom - 1.0, zm), (xm, y_bottom + h + ch, zm), prof))
    add.append(Box((xm, (y_top + y_bottom) / 2, zm), (w, y_top - y_bottom, ln)))
    return MountGeometry(tuple(add), tuple(sub), (x0, x1, z0, z1), y_bottom, label_centre)


def strap_roof(p) -> tuple[int, float]:
    """(steps, step mm) of the strap tunnel's roof: each step as high as it steps in from each
    side (45 deg), enough to narrow the ceiling to :data:`PRINTABLE_BRIDGE_MM`; the step is the
    smallest multiple of :data:`STRAP_STEP_MM` that needs at most :data:`STRAP_MAX_STEPS`."""
    half = (p["strap_width_mm"] + STRAP_PLAY_MM - PRINTABLE_BRIDGE_MM) / 2
    if half <= 1e-9:
        return 0, STRAP_STEP_MM
    step = STRAP_STEP_MM * max(1, math.ceil(half / (STRAP_STEP_MM * STRAP_MAX_STEPS) - 1e-9))
    return math.ceil(half / step - 1e-9), step


def strap_roof_mm(p) -> float:
    """Height of the strap tunnel's stepped roof above ``slot_mm``, mm."""
    n, step = strap_roof(p)
    return n * step


def magnet_chamfer_mm(p) -> float:
    """Height of the 45 deg chamfer over a magnet pocket, mm: it narrows the ceiling from
    ``magnet_mm`` to :data:`PRINTABLE_BRIDGE_MM` (0 for a pocket that narrow already)."""
    return max(0.0, (p["magnet_mm"] - PRINTABLE_BRIDGE_MM) / 2)


def saddle_profile(p) -> tuple[float, float]:
    """(channel depth below the plate, channel half-width), mm: the segment's circle cut at the
    chord ``channel_mm`` wide, so each rail keeps a flat land on the bed."""
    R = p["segment_mm"] / 2
    half = p["channel_mm"] / 2
    require(half < R, f"saddle: channel_mm {p['channel_mm']:g} must be < segment_mm {p['segment_mm']:g}")
    return R - math.sqrt(R * R - half * half), half


def _at_least(fp, w_min: float, l_min: float):
    x0, x1, z0, z1 = fp
    if x1 - x0 < w_min:
        xm = (x0 + x1) / 2
        x0, x1 = xm - w_min / 2, xm + w_min / 2
    if z1 - z0 < l_min:
        zm = (z0 + z1) / 2
        z0, z1 = zm - l_min / 2, zm + l_min / 2
    return (x0, x1, z0, z1)
