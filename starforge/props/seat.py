"""Where a marker can be stuck on: its base must rest on the surface, clear of sharp edges.

A prop marker is a ball on a flat base (the marker catalogue, :mod:`starforge.markers`: the
base diameter ``base_mm`` and the height of the ball's centre above the base plane
``centre_height_mm``).  A candidate site (a surface point with its outward normal) *seats* the
marker when

* the base disc rests on the surface: of an area-uniform sample of the disc (a sunflower
  spiral of :data:`DISC_SAMPLES` points), at least ``min_contact`` have the surface within
  ``flat_mm`` of the base plane, with the surface normal within ``normal_deg`` of the site's
  (so a curved surface counts while its sag under the disc stays within ``flat_mm``: a 7 mm
  base accepts a cylinder of radius 20 mm or more at 0.3 mm, not a 30 mm handle);
* the nearest sharp edge (dihedral angle above ``sharp_deg``, or an open boundary) and the
  nearest surface tilted more than ``sharp_deg`` from the site's plane (a rounded shoulder, a
  fillet: :func:`tilt_distance`) are at least one base radius plus ``placement_error_mm`` away,
  so that a marker stuck that far off its mark still rests on the face it was meant for (its
  *margin*, the room left beyond the base radius, is reported per site and rewarded by the
  tracked objective);
* the ball, centred ``centre_height_mm`` above the site, does not cut into the prop (its
  centre is at least a radius from the surface, less ``clearance_tol_mm``).

With a stand-off post (:func:`with_standoff`) the post's foot is the base tested; where it does
not rest, on a rod 2-25 mm thick, the post may stand on a clamp round the rod instead
(:mod:`starforge.props.clamp`; :attr:`SeatReport.clamp_m`).

Everything is in metres inside, the settings in mm as named.  The edge distance is measured
to points sampled along the sharp edges every :data:`EDGE_STEP_M` (it errs by at most half a
step, 0.125 mm, and only ever upward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.frames import perpendicular_basis
from starforge.markers import MarkerType, post_top
from starforge.props.surface import surface_distance
from starforge.spec import in_range

#: the longest stand-off post, mm (a longer lever on a glued foot breaks off)
MAX_STANDOFF_MM = 60.0
#: points of the base disc tested for contact (area-uniform sunflower spiral)
DISC_SAMPLES = 37
#: spacing of the points sampled along sharp edges, m
EDGE_STEP_M = 2.5e-4
#: at most this many edge points (longer edge sets are sampled more coarsely, and say so)
MAX_EDGE_POINTS = 2_000_000


@dataclass(frozen=True)
class Seat:
    """The marker as it sits on a prop (lengths in mm).

    Attributes
    ----------
    name : str
        Catalogue name of the marker (or ``"<d> mm ball"`` for a plain diameter).
    ball_mm : float
        Finished sphere diameter.
    base_mm : float
        Diameter of the flat base that rests on the prop.
    centre_height_mm : float
        Base plane to sphere centre (the stand-off included).
    standoff_mm : float
        Length of a printed stand-off post between the prop and the marker's own base
        (:func:`with_standoff`; 0: the marker is stuck on the prop).  ``base_mm`` is then the
        post's foot, which is what rests on the prop.
    marker : MarkerType, optional
        The catalogue entry (None for a plain ball): how the marker attaches to a stand-off.
    """

    name: str
    ball_mm: float
    base_mm: float
    centre_height_mm: float
    standoff_mm: float = 0.0
    marker: MarkerType | None = None

    def __post_init__(self):
        in_range("ball_mm", self.ball_mm, 1.0, 50.0)
        in_range("base_mm", self.base_mm, 0.0, 100.0)
        in_range("centre_height_mm", self.centre_height_mm, 0.0, 100.0 + MAX_STANDOFF_MM)
        in_range("standoff_mm", self.standoff_mm, 0.0, MAX_STANDOFF_MM)

    @property
    def centre_height_m(self) -> float:
        return self.centre_height_mm / 1000.0

    @property
    def standoff_m(self) -> float:
        return self.standoff_mm / 1000.0

    @property
    def ball_radius_m(self) -> float:
        return self.ball_mm / 2000.0

    @property
    def base_radius_m(self) -> float:
        return self.base_mm / 2000.0

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "marker"}


def with_standoff(seat: Seat, standoff_mm: float) -> Seat:
    """``seat`` lifted ``standoff_mm`` off the prop on a printed post (:mod:`starforge.props.standoff`):
    the ball's centre that much higher, the base the post's foot (as wide as
    :func:`starforge.markers.post_top` makes the post; 0: ``seat``)."""
    from dataclasses import replace

    h = float(in_range("standoff_mm (--standoff)", standoff_mm, 0.0, MAX_STANDOFF_MM))
    if h == 0.0:
        return seat
    top = post_top(seat.marker, seat.base_mm or 0.75 * seat.ball_mm)
    if h < top.min_length_mm:
        raise StarforgeError(
            f"--standoff {h:g}: a post under a {seat.name} marker is at least {top.min_length_mm:g} mm long "
            f"({top.words}); give --standoff {top.min_length_mm:g} or more"
        )
    return replace(
        seat, name=f"{seat.name} on a {h:g} mm stand-off", base_mm=top.width_mm,
        centre_height_mm=seat.centre_height_mm + h, standoff_mm=h,
    )  # fmt: skip


@dataclass(frozen=True)
class SeatRules:
    """When a site seats a marker (``[seat]`` in the place templates; see the module docstring).

    ``base = false`` keeps only the ball's clearance (the paper's setting: a ball on a vertex).
    """

    base: bool = True
    flat_mm: float = 0.3
    normal_deg: float = 15.0
    min_contact: float = 0.9
    sharp_deg: float = 30.0
    clearance_tol_mm: float = 0.05
    placement_error_mm: float = 2.0

    def __post_init__(self):
        in_range("seat.flat_mm", self.flat_mm, 0.0, 10.0)
        in_range("seat.normal_deg", self.normal_deg, 0.0, 90.0)
        in_range("seat.min_contact", self.min_contact, 0.0, 1.0)
        in_range("seat.sharp_deg", self.sharp_deg, 1.0, 180.0)
        in_range("seat.clearance_tol_mm", self.clearance_tol_mm, 0.0, 10.0)
        in_range("seat.placement_error_mm (--placement-error)", self.placement_error_mm, 0.0, 20.0)

    @property
    def margin_cap_mm(self) -> float:
        """Margins are measured up to this (mm): twice the placement error, at least 3 mm more."""
        return max(2.0 * self.placement_error_mm, self.placement_error_mm + 3.0)


def seat_for(marker: str | float, base_mm: float | None = None) -> Seat:
    """The seat of a catalogue marker (``9.5mm-m3``) or of a plain diameter in mm.

    A plain diameter takes the catalogue entry of the same diameter when there is one, else a
    base of 0.75 diameters with the centre 0.55 diameters above it (the proportions of the
    catalogue's hard markers; starforge's assumption).  ``base_mm`` overrides the base diameter
    (a stick-on pad of that size under the marker)."""
    from starforge.markers import load_marker, marker_diameter_mm, marker_names

    text = str(marker).strip()
    try:
        d = float(text.removesuffix("mm"))
        entry = None
        for n in marker_names():
            m = load_marker(n)
            if abs(m.diameter_mm - d) < 1e-9:
                entry = m
                break
    except ValueError:
        entry = load_marker(text)
        d = entry.diameter_mm
    d = marker_diameter_mm(d)
    if entry is not None:
        seat = Seat(entry.name, entry.diameter_mm, entry.base_mm, entry.centre_height_mm, marker=entry)
    else:
        seat = Seat(f"{d:g} mm ball", d, round(0.75 * d, 3), round(0.55 * d, 3))
    if base_mm is not None:
        from dataclasses import replace

        seat = replace(seat, base_mm=float(in_range("base_mm", base_mm, 0.5, 100.0)), name=f"{seat.name} on a {base_mm:g} mm base")
    return seat


def disc_offsets(count: int = DISC_SAMPLES) -> np.ndarray:
    """(count, 2) area-uniform points of the unit disc (sunflower spiral, the centre first)."""
    k = np.arange(count)
    r = np.sqrt((k + 0.5 * (k > 0)) / count) * (k > 0)
    r = np.minimum(r / max(r.max(), 1e-12), 1.0)
    a = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (n, 3) each, orthogonal to each normal and to each other."""
    return perpendicular_basis(np.asarray(normals, float).reshape(-1, 3))


def sharp_edge_points(mesh, sharp_deg: float = 30.0) -> np.ndarray:
    """(k, 3) points every :data:`EDGE_STEP_M` along the mesh's sharp edges, m: edges whose two
    faces meet at more than ``sharp_deg`` degrees, and boundary edges of an open mesh."""
    angles = np.asarray(mesh.face_adjacency_angles)
    edges = [np.asarray(mesh.face_adjacency_edges)[angles > math.radians(sharp_deg)]]
    edges.append(np.asarray(mesh.edges_sorted)[_boundary(mesh)])
    e = np.concatenate([x.reshape(-1, 2) for x in edges])
    if not len(e):
        return np.zeros((0, 3))
    a, b = mesh.vertices[e[:, 0]], mesh.vertices[e[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    step = max(EDGE_STEP_M, float(length.sum()) / MAX_EDGE_POINTS)
    n = np.maximum(1, np.ceil(length / step).astype(np.int64))
    rep = np.repeat(np.arange(len(e)), n + 1)
    t = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n])
    return a[rep] + t[:, None] * (b - a)[rep]


def _boundary(mesh) -> np.ndarray:
    """(e,) bool over ``mesh.edges_sorted``: edges used by one face only."""
    es = np.asarray(mesh.edges_sorted)
    if not len(es):
        return np.zeros(0, bool)
    key = es[:, 0].astype(np.int64) * (int(es.max()) + 1) + es[:, 1]  # one integer per edge: a fast unique
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    return cnt[inv.ravel()] == 1


@dataclass(frozen=True)
class SeatReport:
    """Per site: how the marker's base rests there (arrays of the sites' length).

    contact : base-disc fraction resting on the surface, [0, 1]
    edge_m : distance to the nearest sharp edge, m (inf when the mesh has none)
    clearance_m : ball centre to the prop's surface, m (on a post, ``inf`` past 1 mm more than the
        marker's own centre height: the ball clears it)
    ok : the site seats the marker (every rule of the module docstring)
    margin_m : room beyond the base radius to the nearest sharp edge or surface tilted more than
        ``sharp_deg``, m, measured up to :attr:`SeatRules.margin_cap_mm` (a site with more gets the cap);
        on a clamp, the straight rod beyond the ring's half-width (:mod:`starforge.props.clamp`)
    clamp_m : the radius of the rod a clamp holds the marker's post round, m (0: the post's foot
        or the base rests on the surface); None without a stand-off
    clamp_axis : (s, 3) that rod's unit axis (zero where no clamp); None without a stand-off
    """

    contact: np.ndarray
    edge_m: np.ndarray
    clearance_m: np.ndarray
    ok: np.ndarray
    margin_m: np.ndarray = None
    clamp_m: np.ndarray = None
    clamp_axis: np.ndarray = None

    def subset(self, keep: np.ndarray) -> SeatReport:
        """The report of the sites where the boolean mask ``keep`` is true."""
        m, c, a = (None if x is None else x[keep] for x in (self.margin_m, self.clamp_m, self.clamp_axis))
        return SeatReport(self.contact[keep], self.edge_m[keep], self.clearance_m[keep], self.ok[keep], m, c, a)


def seat_report(mesh, points: np.ndarray, normals: np.ndarray, seat: Seat, rules: SeatRules) -> SeatReport:
    """Test every site (``points`` (s, 3) m on the surface, outward unit ``normals``).

    With ``rules.base`` false only the ball's clearance is required (the paper's setting, where
    a marker is a ball on a vertex and has no base); contact is then reported, not required.
    """
    from scipy.spatial import cKDTree

    from starforge.props.visibility import first_hits

    pts = np.asarray(points, float)
    nrm = np.asarray(normals, float)
    s = len(pts)
    if s == 0:
        z = np.zeros(0)
        return SeatReport(z, z, z, np.zeros(0, bool), z)
    R = seat.base_radius_m
    flat = rules.flat_mm / 1000.0
    u, v = tangent_frames(nrm)
    off = disc_offsets() * R
    q = pts[:, None] + off[None, :, :1] * u[:, None] + off[None, :, 1:] * v[:, None]  # (s, k, 3)
    lift = 2.0 * flat + 1e-4
    origins = (q + lift * nrm[:, None]).reshape(-1, 3)
    dirs = np.repeat(-nrm, len(off), axis=0)
    dist, face = first_hits(mesh, origins, dirs)
    dev = np.abs(dist - lift)
    fn = np.asarray(mesh.face_normals)[np.clip(face, 0, None)]
    agree = np.einsum("ij,ij->i", fn, dirs) <= -math.cos(math.radians(rules.normal_deg))
    contact = ((face >= 0) & (dev <= flat) & agree).reshape(s, -1).mean(axis=1)
    edges = sharp_edge_points(mesh, rules.sharp_deg)
    edge_m = cKDTree(edges).query(pts)[0] if len(edges) else np.full(s, np.inf)
    cap = R + rules.margin_cap_mm / 1000.0
    tilt = tilt_distance(mesh, pts, nrm, rules.sharp_deg, cap)
    margin = np.minimum(np.minimum(edge_m, tilt), cap) - R
    centres = pts + seat.centre_height_m * nrm
    # the centre is at most its height off the surface (the site is on it); on a post, past the
    # ball's own height it only needs to clear; the post's axis (one measurement with the centres)
    # only needs its radius
    axis = post_axis(pts, nrm, R, seat.standoff_m).reshape(-1, 3)
    reach = np.repeat([seat.centre_height_m - seat.standoff_m + 1e-3, R], [s, len(axis)])
    dist = surface_distance(mesh, np.concatenate([centres, axis]), reach)
    clearance = dist[:s]
    need = min(seat.ball_radius_m, seat.centre_height_m) - rules.clearance_tol_mm / 1000.0
    ok = clearance >= need
    if len(axis):
        ok &= (dist[s:].reshape(s, -1) >= R - rules.clearance_tol_mm / 1000.0).all(axis=1)
    if not rules.base:
        return SeatReport(contact, edge_m, clearance, ok, margin)
    err = rules.placement_error_mm / 1000.0
    rests = (contact >= rules.min_contact) & (margin >= err - 1e-12)
    clamp = axis = None
    if seat.standoff_m > 0:  # a post that cannot stand on its foot may stand on a clamp round a rod
        from starforge.props.clamp import clamp_fit

        clamp, axis = np.zeros(s), np.zeros((s, 3))
        todo = np.flatnonzero(ok & ~rests)
        r, t, room = clamp_fit(mesh, pts[todo], nrm[todo], 2 * R, err, cap - R)
        on = r > 0
        clamp[todo[on]], axis[todo[on]], margin[todo[on]] = r[on], t[on], room[on]
        rests[todo[on]] = True
    return SeatReport(contact, edge_m, clearance, ok & rests, margin, clamp, axis)


#: a stand-off post's axis is tested for clearance at points this far apart, m
POST_CLEAR_STEP_M = 1e-3


def post_axis(points: np.ndarray, normals: np.ndarray, radius_m: float, length_m: float) -> np.ndarray:
    """(s, k, 3) the points of each post's axis that must clear the prop: from one radius up
    along each site's normal to ``length_m``, every :data:`POST_CLEAR_STEP_M` (k = 0 for a post
    no longer than its radius).  Below one radius the foot sits on the surface; the base rules
    test it."""
    pts, nrm = np.asarray(points, float).reshape(-1, 3), np.asarray(normals, float).reshape(-1, 3)
    if length_m <= radius_m:
        return np.zeros((len(pts), 0, 3))
    h = np.linspace(radius_m, length_m, max(2, int(math.ceil((length_m - radius_m) / POST_CLEAR_STEP_M)) + 1))
    return pts[:, None] + h[None, :, None] * nrm[:, None]


def post_clear(mesh, points: np.ndarray, normals: np.ndarray, radius_m: float, length_m: float, tol_m: float) -> np.ndarray:
    """(s,) bool: a post of ``radius_m`` standing ``length_m`` along each site's normal clears the
    prop: every point of its axis (:func:`post_axis`) lies at least the radius (less ``tol_m``)
    from the surface."""
    axis = post_axis(points, normals, radius_m, length_m)
    if not axis.size:
        return np.ones(len(axis), bool)
    return (surface_distance(mesh, axis.reshape(-1, 3), radius_m).reshape(len(axis), -1) >= radius_m - tol_m).all(axis=1)


#: surface samples for :func:`tilt_distance`: this far apart (m), at most :data:`TILT_SAMPLES`
TILT_STEP_M = 1e-3
TILT_SAMPLES = 200_000


def tilt_distance(mesh, points: np.ndarray, normals: np.ndarray, tilt_deg: float, reach_m: float) -> np.ndarray:
    """(s,) m: from each site to the nearest surface point whose normal is more than ``tilt_deg``
    from the site's (``normals``), up to ``reach_m`` (a site with none nearer gets ``reach_m``).

    The tilted faces are found by an even sample of the surface (one point per
    :data:`TILT_STEP_M` squared of area, at most :data:`TILT_SAMPLES`, from a fixed seed) within
    ``reach_m`` plus the sample's spacing; the distance is then the exact closest point on them
    (a tilted face no sample lands on is found through its sampled neighbours, so the distance
    errs upward by at most the spacing, and only at such slivers).  The far side of a thin wall
    (faces turned away from the site's normal, below its plane) is not a surface the base could
    slide onto and is left out."""
    import trimesh
    from scipy.spatial import cKDTree

    pts = np.asarray(points, float)
    nrm = np.asarray(normals, float)
    out = np.full(len(pts), float(reach_m))
    if not len(pts):
        return out
    area = float(mesh.area)
    n = int(min(TILT_SAMPLES, max(1000, area / TILT_STEP_M**2)))
    step = math.sqrt(area / n)
    sample, face = trimesh.sample.sample_surface(mesh, n, seed=np.random.default_rng(0))
    sample = np.asarray(sample, float)
    fn = np.asarray(mesh.face_normals)[face]
    # samples per site: one look-up per site, not one per sample (the same pairs; sorted below)
    near = cKDTree(sample).query_ball_point(pts, reach_m + step, return_sorted=False)
    cnt = np.fromiter(map(len, near), np.int64, len(near))
    if not cnt.sum():
        return out
    smp = np.concatenate([np.asarray(x, np.int64) for x in near if x])
    site = np.repeat(np.arange(len(pts)), cnt)
    c = np.einsum("ij,ij->i", fn[smp], nrm[site])
    below = np.einsum("ij,ij->i", sample[smp] - pts[site], nrm[site]) < 0
    keep = (c < math.cos(math.radians(tilt_deg))) & ~((c < 0) & below)
    pairs = np.unique(np.column_stack([site[keep], face[smp[keep]]]), axis=0)
    if not len(pairs):
        return out
    tri = np.asarray(mesh.triangles)[pairs[:, 1]]
    d = np.linalg.norm(trimesh.triangles.closest_point(tri, pts[pairs[:, 0]]) - pts[pairs[:, 0]], axis=1)
    np.minimum.at(out, pairs[:, 0], d)
    return out
