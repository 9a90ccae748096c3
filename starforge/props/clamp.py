"""Clamps: a marker's post on a printed split ring round a thin round part of the prop.

A shaft, a rod or a tube is too narrow and too curved for a post's flat foot (a 7 mm foot needs
a cylinder of radius 20 mm or more, :mod:`starforge.props.seat`), yet on a screwdriver, an
umbrella or a pointer it is often the only part a hand leaves free.  With ``--standoff MM`` such
a site takes the post on a clamp instead: a ring as wide as the post's foot, split opposite the
post to snap round the rod, the post standing on it along the site's normal, the ball's centre
as high above the rod's surface as on a post anywhere else.

A site takes a clamp (:func:`clamp_fit`) when, round it,

* the prop there is a rod :data:`CLAMP_MIN_R_M` to :data:`CLAMP_MAX_R_M` thick: its axis is
  the direction square to the surface normals found round the site (:func:`_rod_axis`), its
  circle the one fitted to the surface points found round it and across it (:func:`_fit_circles`);
* circles of that radius round the axis, at :data:`RING_POINTS` angles, lie on the surface
  (within :func:`fit_tolerance`) over the ring's width plus the placement error on either side,
  so a ring set that far off its mark along the rod still closes round it;
* nothing else of the prop comes within the ring's wall plus :data:`CLAMP_ROOM_M` of the rod
  over that stretch (a flange, a handle, another part);

and its *margin* is the stretch of straight rod beyond the ring's half-width on its shorter
side, measured as the base's margin is, up to the same cap.  The test samples the surface at
points; a fin thinner than the gaps between them is not seen.  The printed part is
:func:`starforge.props.standoff.clamp_solid`.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.geometry.frames import perpendicular_basis
from starforge.props.surface import surface_distance
from starforge.props.visibility import first_hits

#: rods a clamp takes: radius, m (a 2 mm wire to a 25 mm tube)
CLAMP_MIN_R_M = 1.0e-3
CLAMP_MAX_R_M = 12.5e-3
#: the ring's wall, mm (two perimeters of a 0.4 mm nozzle and then some)
CLAMP_WALL_MM = 2.0
#: room round the ring's outside nothing else of the prop may take, m
CLAMP_ROOM_M = 1.0e-3
#: points round each circle tested on the rod
RING_POINTS = 16
#: the margin along the rod is measured in steps this long, m
MARGIN_STEP_M = 5e-4


def ring_radii_mm(rod_mm: float) -> tuple[float, float]:
    """The ring round a rod ``rod_mm`` across: its bore's and its outside's radii, mm."""
    r = float(rod_mm) / 2.0
    return r, r + CLAMP_WALL_MM


def ring_frame(point, normal, rod_mm: float, rod_axis) -> tuple[np.ndarray, float, float]:
    """Where the ring of a clamp sits on the prop, for a marker whose site is ``point`` (m) with
    outward ``normal``, on a rod ``rod_mm`` across along ``rod_axis``: a (4, 4) placement, m
    (x the site's normal, z the rod's axis, y completing a right-handed frame, the origin on the
    rod's axis under the site) and the bore's and the outside's radii, m.  The picture's solid
    (:func:`starforge.props.files.marker_parts`) and the guide's outline
    (:func:`starforge.render.prop_views.clamp_rings`) both place the ring with it; the printed
    part (:func:`starforge.props.standoff.clamp_solid`) has the same radii in its own frame."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    t = np.asarray(rod_axis, float)
    bore, outside = (x / 1000.0 for x in ring_radii_mm(rod_mm))
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([n, np.cross(t, n), t])
    frame[:3, 3] = np.asarray(point, float) - bore * n
    return frame, bore, outside


def fit_tolerance(radius_m: np.ndarray) -> np.ndarray:
    """How far (m) a point of the fitted circle may lie off the surface: 0.1 mm, or 3 % of the
    radius on a thick rod (a 16-sided prism's flats lie 1.9 % of its radius inside its circle)."""
    return np.maximum(1e-4, 0.03 * np.asarray(radius_m, float))


def clamp_fit(mesh, points: np.ndarray, normals: np.ndarray, width_m: float, error_m: float, cap_m: float):
    """Where a clamp ``width_m`` wide (along the rod) fits round the prop at each site.

    Parameters
    ----------
    mesh : trimesh.Trimesh, m
    points, normals : (s, 3) float
        Sites on the surface and their outward unit normals.
    width_m : float
        The ring's width along the rod (the post's foot).
    error_m : float
        How far along the rod a technician may set it off its mark.
    cap_m : float
        Margins are measured up to this, beyond the ring's half-width.

    Returns
    -------
    radius : (s,) float, m
        The rod's radius where a clamp fits, 0 elsewhere.
    axis : (s, 3) float
        The rod's unit axis (zero where no clamp fits).
    margin : (s,) float, m
        The straight rod beyond the ring's half-width on its shorter side, up to ``cap_m`` (0
        where no clamp fits).
    """
    pts, nrm = np.asarray(points, float).reshape(-1, 3), np.asarray(normals, float).reshape(-1, 3)
    s = len(pts)
    radius, axis, margin = np.zeros(s), np.zeros((s, 3)), np.zeros(s)
    if not s:
        return radius, axis, margin
    # about the rod's radius: half the chord straight in from the site
    eps = 1e-5
    chord, _ = first_hits(mesh, pts - eps * nrm, -nrm)
    chord += eps
    r = chord / 2.0
    idx = np.flatnonzero(np.isfinite(r) & (r >= CLAMP_MIN_R_M) & (r <= CLAMP_MAX_R_M))
    if not len(idx):
        return radius, axis, margin
    p, n, r = pts[idx], nrm[idx], r[idx]
    t, hits = _rod_axis(mesh, p, n, r)
    w = np.cross(t, n)
    # the rod's circle: fitted, square to the axis, through the site, the far end of its chord
    # and the rays' landings round it (a prism's flat puts its own normal off the axis)
    far = p - chord[idx, None] * n
    ring = np.concatenate([p[:, None], far[:, None], hits], axis=1)
    centre, r = _fit_circles(ring - p[:, None], n, w, np.isfinite(ring).all(axis=2))
    c = p + centre[:, :1] * n + centre[:, 1:] * w
    # cheapest test first: the circle through the site itself lies on the surface
    keep = (r >= CLAMP_MIN_R_M) & (r <= CLAMP_MAX_R_M)
    keep[keep] = _rings_fit(mesh, c[keep], t[keep], n[keep], w[keep], r[keep], np.zeros(1))[:, 0]
    idx, p, n, r, t, c, w = idx[keep], p[keep], n[keep], r[keep], t[keep], c[keep], w[keep]
    half = width_m / 2.0
    steps = np.arange(0.0, max(cap_m, error_m) + MARGIN_STEP_M / 2, MARGIN_STEP_M)
    on_rod = _rings_fit(mesh, c, t, n, w, r, np.concatenate([half + steps, -(half + steps)]))
    k = len(steps)
    reach = np.minimum(_run(on_rod[:, :k]), _run(on_rod[:, k:]))  # good steps along the rod either side
    room_m = (reach - 1).clip(0) * MARGIN_STEP_M  # the last good step's offset beyond the half-width
    ok = (reach >= 1) & (room_m >= error_m - 1e-12)
    ok[ok] = _room_round(
        mesh, c[ok], t[ok], n[ok], w[ok], r[ok], np.array([0.0, half + error_m, -(half + error_m)])
    )
    radius[idx[ok]] = r[ok]
    axis[idx[ok]] = t[ok]
    margin[idx[ok]] = np.minimum(room_m[ok], cap_m)
    return radius, axis, margin


def _rod_axis(mesh, p, n, r) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) each rod's unit axis, the direction square to the surface's normals round the site,
    and (k, 9, 3) where the rays below land (NaN for a miss).

    Rays straight down the site's normal from a 3 x 3 grid of points ``0.6 r`` apart in its
    tangent plane land on the rod round it; on a cylinder every normal there is square to the
    axis (on a faceted one too), so the axis is the eigenvector of the normals' scatter with the
    least eigenvalue, and the others spread them round it.  A ray that misses counts nothing;
    where too few land the ring tests that follow refuse the site."""
    u, v = perpendicular_basis(n)
    g = np.array([-0.6, 0.0, 0.6])
    a, b = (x.ravel() for x in np.meshgrid(g, g))
    origins = p[:, None] + r[:, None, None] * (a[None, :, None] * u[:, None] + b[None, :, None] * v[:, None] + 2.0 * n[:, None])
    down = np.repeat(-n, len(a), axis=0)
    dist, face = first_hits(mesh, origins.reshape(-1, 3), down)
    fn = np.asarray(mesh.face_normals, float)[face.clip(0)] * (face >= 0)[:, None]
    fn = fn.reshape(len(p), len(a), 3)
    scatter = np.einsum("kai,kaj->kij", fn, fn)
    t = np.linalg.eigh(scatter)[1][:, :, 0]
    t -= np.einsum("ki,ki->k", t, n)[:, None] * n  # in the tangent plane
    dist = np.where(np.isfinite(dist), dist, np.nan)  # a miss lands nowhere
    hits = (origins.reshape(-1, 3) + dist[:, None] * down).reshape(len(p), len(a), 3)
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12), hits


def _fit_circles(q, n, w, valid):
    """Centres (k, 2), in (n, w) coordinates, and radii (k,) of the least-squares circles
    (Kasa's) through the points ``q`` (k, m, 3) projected on each plane spanned by ``n`` and
    ``w`` (k, 3), the rows of ``valid`` (k, m) only."""
    x = np.where(valid, np.einsum("kmi,ki->km", np.nan_to_num(q), n), 0.0)
    y = np.where(valid, np.einsum("kmi,ki->km", np.nan_to_num(q), w), 0.0)
    one = valid.astype(float)
    A = np.stack([x, y, one], axis=2)  # rows of invalid points are zero
    b = x * x + y * y
    ata = np.einsum("kmi,kmj->kij", A, A) + 1e-18 * np.eye(3)
    sol = np.linalg.solve(ata, np.einsum("kmi,km->ki", A, b)[..., None])[..., 0]
    centre = sol[:, :2] / 2.0
    return centre, np.sqrt(np.maximum(sol[:, 2] + (centre**2).sum(axis=1), 0.0))


def _circle(c, t, n, w, rho, offsets) -> np.ndarray:
    """(k, len(offsets), RING_POINTS, 3) points on circles of radius ``rho`` (k,) round each axis."""
    phi = np.arange(RING_POINTS) * 2 * math.pi / RING_POINTS
    ring = np.cos(phi)[None, :, None] * n[:, None] + np.sin(phi)[None, :, None] * w[:, None]  # (k, R, 3)
    centre = c[:, None] + offsets[None, :, None] * t[:, None]  # (k, O, 3)
    return centre[:, :, None] + rho[:, None, None, None] * ring[:, None]


def _rings_fit(mesh, c, t, n, w, r, offsets) -> np.ndarray:
    """(k, len(offsets)) bool: the circle of the rod's radius at each offset lies on the surface."""
    q = _circle(c, t, n, w, r, offsets)
    tol = fit_tolerance(r)
    d = surface_distance(mesh, q.reshape(-1, 3), float(tol.max(initial=0.0))).reshape(q.shape[:3])
    return (d <= tol[:, None, None]).all(axis=2)


def _room_round(mesh, c, t, n, w, r, offsets) -> np.ndarray:
    """(k,) bool: no part of the prop within the ring's outside plus :data:`CLAMP_ROOM_M`, at
    each offset: a circle that far out keeps its distance from the surface."""
    out = CLAMP_WALL_MM / 1000.0 + CLAMP_ROOM_M
    q = _circle(c, t, n, w, r + out, offsets)
    d = surface_distance(mesh, q.reshape(-1, 3), out).reshape(q.shape[:3])
    return (d >= out - fit_tolerance(r)[:, None, None]).all(axis=(1, 2))


def _run(ok: np.ndarray) -> np.ndarray:
    """(k,) the number of leading true entries of each row."""
    return np.where(ok.all(axis=1), ok.shape[1], (~ok).argmax(axis=1))
