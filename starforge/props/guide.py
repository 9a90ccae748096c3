"""What a prop team needs to stick the markers on and check them: landmarks, calipers, tilt.

Every marker is located from features of the mesh a person finds by hand
(:func:`mesh_landmarks`): the prop's *ends* both ways along each principal axis where a person
can find them (the middle of a flat end face, such as a handle's end or a box's side; a single
farthest point, such as an apex or a rib's tip; none where the end is a line, as along the side
of a cylinder) and its *corners* (vertices where three or more edges sharper than
:data:`CORNER_DEG` meet).  Per marker (:func:`landmarks`): the straight
distances (mm, a ruler or caliper from the point) to the :data:`MEASURED` landmarks that locate
it best (:func:`locating_errors`: under a model of a distance measured by hand, the three whose
readings pin the mark down most tightly on the surface, which the nearest three need not do:
at the end of a long prop they can lie nearly in one line with it), how tightly they do, the
face it sits on (a flat face of the mesh at least :data:`FLAT_MIN_MM2` with edges a person
finds, :data:`FLAT_EDGE_DEG`, named by the direction it faces; or the curved surface, the
facets of a tessellated round body included), its tilt (the angle of its normal from the prop's
+z, and the direction it leans), and, as before, its distances from the sides of the
axis-aligned bounding box.  The caliper check (:func:`caliper_pairs`): every pair of ball
centres, with the tolerance two markers each stuck up to the placement error off their marks
can show.  The drawings are made by :mod:`starforge.render.guide`; the prop with the bases
merged by :func:`bases_mesh`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from starforge.geometry.frames import perpendicular_basis

#: a marker whose normal is within this angle of an axis, and that lies within FACE_MM of the
#: box's side there, is "on" that box face
FACE_DEG = 5.0
FACE_MM = 1.0
AXES = "xyz"
#: edges sharper than this (degrees) make a corner where three or more meet
CORNER_DEG = 60.0
#: at most this many corners are named (farthest apart first)
MAX_CORNERS = 12
#: landmarks closer than this (m) to one already named are the same landmark
SAME_M = 0.005
#: landmarks a marker is measured from (two locate a point on a surface up to a mirror image;
#: the third tells the two apart and checks them)
MEASURED = 3
#: a distance measured by hand from a landmark to a mark is off by about TAPE_MM plus TAPE_REL
#: of it (one standard deviation): reading a rule to half a millimetre, and holding a longer one
#: straight between two points in the air
TAPE_MM = 0.5
TAPE_REL = 0.005
#: the locating error bounds where 95 % of marks set from the readings land: the region whose
#: readings differ from the mark's by at most this (a chi-square of 2 degrees of freedom at
#: 0.95, -2 ln 0.05: the mark's two coordinates on the surface)
LOCATE_CHI2 = -2.0 * math.log(0.05)
#: a landmark nearer than this (mm) to the mark is not measured from (it gives no direction)
MIN_MEASURE_MM = 5.0
#: a mark may be set off a landmark in its own plane (out of it by at most IN_PLANE of the
#: distance), the direction named judged by eye to OFFSET_DEG (one standard deviation)
IN_PLANE = 0.1
OFFSET_DEG = 15.0
#: points sampled on the prop to look for those its readings cannot tell from a mark
LOCATE_SAMPLES = 20_000
#: a point facing more than this (degrees) away from the mark is told from it by the way it faces
FACING_DEG = 45.0
#: a flat face named as such covers at least this area (mm^2), and at least FLAT_EDGE_SHARE of
#: its outline (by length) bends by FLAT_EDGE_DEG (degrees) or more into the faces beside it: an
#: edge a person sees and feels.  The facets of a tessellated round body (a 24-sided mug, its
#: sides bending 15 degrees into each other) are the curved surface, not faces to find.
FLAT_MIN_MM2 = 150.0
FLAT_EDGE_DEG = 25.0
FLAT_EDGE_SHARE = 0.5
#: vertices within this (m) of a prop's farthest point along a direction make its end there
TIP_BAND_M = 0.0005
#: an end no wider than this (m) is a point a person finds (an apex, a corner, a rib's tip)
TIP_POINT_M = 0.002
#: a flat end whose area is at least this share of its outline's convex hull is convex, and
#: one at least END_WIDTH_M across every way is no sliver: its middle is found by measuring
#: across it; it faces within END_DEG (degrees) of the direction it ends the prop in
CONVEX_SHARE = 0.9
END_WIDTH_M = 0.01
END_DEG = 20.0


def _direction(v: np.ndarray, within_deg: float = 20.0) -> str:
    """``+z`` when ``v`` is within ``within_deg`` of an axis, else its rounded components."""
    v = np.asarray(v, float) / max(float(np.linalg.norm(v)), 1e-300)
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) >= math.cos(math.radians(within_deg)):
        return f"{'+' if v[k] > 0 else '-'}{AXES[k]}"
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def heading(v: np.ndarray) -> str:
    """An in-plane direction as a person sets it off by eye: its nearest axis turned by a whole
    number of degrees towards the next (``-y turned 24 deg to +x``; ``+x`` when it rounds to
    none), off the true direction by at most half a degree, well inside the eye's
    :data:`OFFSET_DEG`; its rounded components where it leaves the plane of those two axes by
    more than 2 degrees."""
    v = np.asarray(v, float) / max(float(np.linalg.norm(v)), 1e-300)
    k, j, out = np.argsort(-np.abs(v), kind="stable")
    if abs(v[out]) > math.sin(math.radians(2.0)):
        return _direction(v, 0.0)
    turn = round(math.degrees(math.atan2(abs(v[j]), abs(v[k]))))
    main = f"{'+' if v[k] > 0 else '-'}{AXES[k]}"
    return main if turn == 0 else f"{main} turned {turn} deg to {'+' if v[j] > 0 else '-'}{AXES[j]}"


def _end(mesh, v: np.ndarray, c: np.ndarray, d: np.ndarray) -> tuple[str, np.ndarray] | None:
    """The prop's end along ``d`` as a point a person finds by hand, with its description: the
    middle of the flat face the farthest point lies on, where that face faces within
    :data:`END_DEG` of ``d`` and is convex and at least :data:`END_WIDTH_M` across every way (a
    disc, a square: found by measuring across it); else the farthest point where the end is one
    (an apex, a rib's tip: the vertices within :data:`TIP_BAND_M` of the farthest lie within
    :data:`TIP_POINT_M` of each other); else None: the end is a line or a curved strip (the side
    of a cylinder), of which no one point stands out."""
    proj = (v - c) @ d
    far = int(np.argmax(proj))
    face = _flat_end(mesh, v, far, d)
    if face is not None:
        return f"the middle of the flat end towards {_direction(d)}", face
    pts = v[proj >= proj[far] - TIP_BAND_M]
    if np.linalg.norm(pts - pts.mean(axis=0), axis=1).max() <= TIP_POINT_M:
        return f"the end towards {_direction(d)}", v[far]
    return None


def _flat_end(mesh, v: np.ndarray, vertex: int, d: np.ndarray) -> np.ndarray | None:
    """The middle (m) of the flat face (a facet of coplanar faces, or one triangle) at
    ``vertex`` facing within :data:`END_DEG` of ``d``, the largest such, when it is convex (its
    area at least :data:`CONVEX_SHARE` of its outline's hull) and :data:`END_WIDTH_M` wide."""
    from scipy.spatial import ConvexHull

    faces = np.asarray(mesh.faces)
    fn = np.asarray(mesh.face_normals)
    area = np.asarray(mesh.area_faces)
    touching = np.flatnonzero((faces == vertex).any(axis=1) & (fn @ d >= math.cos(math.radians(END_DEG))))
    if not len(touching):
        return None
    facet = _facet_of(mesh)
    groups = [np.asarray(mesh.facets[k], np.int64) for k in sorted({int(k) for k in facet[touching] if k >= 0})]
    groups += [np.array([f]) for f in touching if facet[f] < 0]
    g = max(groups, key=lambda g: float(area[g].sum()))
    a = area[g]
    if a.sum() * 1e6 < FLAT_MIN_MM2:
        return None
    e1, e2 = perpendicular_basis(fn[g[0]])
    corners = v[np.unique(faces[g])]
    flat = np.column_stack([corners @ e1, corners @ e2])
    try:
        hull = ConvexHull(flat)
    except Exception:  # noqa: BLE001  (qhull: a degenerate outline is no face to measure across)
        return None
    if a.sum() < CONVEX_SHARE * hull.volume:  # in 2-D, volume is the area
        return None
    ring = flat[hull.vertices]
    edges = np.roll(ring, -1, axis=0) - ring
    normals = np.column_stack([-edges[:, 1], edges[:, 0]]) / np.linalg.norm(edges, axis=1)[:, None]
    spans = ring @ normals.T  # the hull's width across each of its edges
    if float((spans.max(axis=0) - spans.min(axis=0)).min()) < END_WIDTH_M:
        return None
    return (np.asarray(mesh.triangles_center)[g] * a[:, None]).sum(axis=0) / a.sum()


def mesh_landmarks(mesh) -> list[dict]:
    """The ends and corners of the mesh (:func:`_end`): ``[{"name": "T1", "kind": "tip" |
    "corner", "what": text, "point": [x, y, z] m}]``, the ends first."""
    from starforge.props.grips import principal_axes

    v = np.asarray(mesh.vertices, float)
    c, axes = principal_axes(v)
    found: list[tuple[str, str, np.ndarray]] = []

    def add(kind, what, p):
        if all(np.linalg.norm(p - q) >= SAME_M for _, _, q in found):
            found.append((kind, what, p))

    for ax in axes:
        for sign in (1.0, -1.0):
            end = _end(mesh, v, c, sign * ax)
            if end is not None:
                add("tip", *end)
    angles = np.asarray(mesh.face_adjacency_angles)
    sharp = np.asarray(mesh.face_adjacency_edges)[angles > math.radians(CORNER_DEG)]
    if len(sharp):
        count = np.bincount(sharp.ravel(), minlength=len(v))
        cand = v[count >= 3]
        if len(cand):  # farthest-point order from the first tip (or the centroid): spread, deterministic
            d = np.linalg.norm(cand - (found[0][2] if found else c), axis=1)
            for _ in range(min(len(cand), 4 * MAX_CORNERS)):
                k = int(np.argmax(d))
                if d[k] < SAME_M or sum(1 for f in found if f[0] == "corner") >= MAX_CORNERS:
                    break
                add("corner", "a corner", cand[k])
                d = np.minimum(d, np.linalg.norm(cand - cand[k], axis=1))
    out, n = [], {"tip": 0, "corner": 0}
    for kind, what, p in found:
        n[kind] += 1
        name = f"{'T' if kind == 'tip' else 'C'}{n[kind]}"
        where = ", ".join(f"{1000 * x:.0f}" for x in p)
        out.append({"name": name, "kind": kind, "what": f"{what} ({where} mm)", "point": [round(float(x), 6) + 0.0 for x in p]})
    return out


def _facet_of(mesh) -> np.ndarray:
    """(f,) int: the facet (``mesh.facets``: coplanar neighbours) each face belongs to, -1 if none."""
    out = np.full(len(mesh.faces), -1, np.int64)
    for k, g in enumerate(mesh.facets):
        out[g] = k
    return out


class FlatFaces(NamedTuple):
    """The flat faces a person finds on a mesh (:func:`flat_faces`), numbered F1, F2, ...
    largest first."""

    rank: np.ndarray  # (f,) int: the number of the flat face each mesh face lies on; 0: none
    facing: tuple[str, ...]  # the direction F1, F2, ... face
    area_mm2: np.ndarray  # the area of F1, F2, ..., mm^2

    def of(self, face: int) -> dict | None:
        """``{"id", "facing", "area_mm2"}`` of the flat face mesh face ``face`` lies on; None
        when it lies on none."""
        k = int(self.rank[face]) - 1
        if k < 0:
            return None
        return {"id": f"F{k + 1}", "facing": self.facing[k], "area_mm2": round(float(self.area_mm2[k]), 0)}


def flat_faces(mesh) -> FlatFaces:
    """The mesh's flat faces: facets of coplanar faces, or single triangles, of at least
    :data:`FLAT_MIN_MM2`, outlined by edges a person finds (:data:`FLAT_EDGE_DEG`)."""
    tri_area = np.asarray(mesh.area_faces) * 1e6
    fn = np.asarray(mesh.face_normals)
    facets = [np.asarray(f, int) for f in mesh.facets]
    group = _facet_of(mesh)  # face -> its group: the facets, then lone triangles
    lone = np.flatnonzero((group < 0) & (tri_area >= FLAT_MIN_MM2))
    group[lone] = len(facets) + np.arange(len(lone))
    first = np.array([g[0] for g in facets] + lone.tolist(), np.int64)  # a face of each group
    areas = np.array([tri_area[g].sum() for g in facets] + tri_area[lone].tolist())
    named = (areas >= FLAT_MIN_MM2) & _crisp_outline(mesh, group, len(areas))
    order = np.flatnonzero(named)[np.argsort(-areas[named], kind="stable")]
    rank = np.zeros(len(areas) + 1, np.int32)  # the last entry: faces in no group (group -1)
    rank[order] = np.arange(1, len(order) + 1)
    return FlatFaces(
        rank[group], tuple(_direction(fn[first[k]], 1.0) for k in order), np.asarray(areas[order], float)
    )


def _crisp_outline(mesh, group: np.ndarray, n_groups: int) -> np.ndarray:
    """(n_groups,) bool: at least :data:`FLAT_EDGE_SHARE` of the group's outline (the edges
    between its faces and other groups', by length) bends by :data:`FLAT_EDGE_DEG` or more
    (an outline along open edges only, which no neighbour bends from, counts as crisp)."""
    pairs = np.asarray(mesh.face_adjacency, np.int64).reshape(-1, 2)
    edges = np.asarray(mesh.face_adjacency_edges, np.int64).reshape(-1, 2)
    v = np.asarray(mesh.vertices, float)
    length = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    sharp = np.asarray(mesh.face_adjacency_angles, float) >= math.radians(FLAT_EDGE_DEG)
    total, bent = np.zeros(n_groups), np.zeros(n_groups)
    for side in (0, 1):
        g, other = group[pairs[:, side]], group[pairs[:, 1 - side]]
        rim = (g >= 0) & (g != other)
        np.add.at(total, g[rim], length[rim])
        np.add.at(bent, g[rim], length[rim] * sharp[rim])
    return (total == 0) | (bent >= FLAT_EDGE_SHARE * total)


def tilt(normal: np.ndarray) -> tuple[float, str]:
    """The marker's tilt: degrees of its normal from the prop's +z, and the way it leans
    (``+x``, ``-y``, ... the larger horizontal component; ``""`` when upright or upside down)."""
    n = np.asarray(normal, float) / max(float(np.linalg.norm(normal)), 1e-300)
    deg = math.degrees(math.acos(float(np.clip(n[2], -1.0, 1.0))))
    h = n[:2]
    if float(np.linalg.norm(h)) < math.sin(math.radians(1.0)):
        return deg, ""
    k = int(np.argmax(np.abs(h)))
    return deg, f"{'+' if h[k] > 0 else '-'}{AXES[k]}"


def locating_errors(point, normal, landmark_points, triples, surface=None, surface_mm=None) -> np.ndarray:
    """How tightly each triple of landmarks locates a mark at ``point`` (m) on a surface of
    ``normal``: (t,) mm, for ``triples`` (t, 3) indices into ``landmark_points`` (k, 3) m.

    Each distance is read with a standard deviation of :data:`TAPE_MM` + :data:`TAPE_REL` of it.
    To first order a reading's error moves the mark along the distance's gradient projected
    into the tangent plane, so the readings' weighted least squares has the information matrix
    ``M = sum_j g_j g_j^T / sigma_j^2`` (2 x 2), and 95 % of marks land in the ellipse
    ``delta^T M delta <= LOCATE_CHI2``, which reaches ``sqrt(LOCATE_CHI2 / lambda_min(M))`` from
    the mark (inf where the triple's directions are parallel).  First order misses what the
    surface does further off: on a round handle the readings change less and less as the mark
    goes round it, and a mirror image of the mark can fit them as well.  With ``surface`` (a
    :class:`SurfaceSample` of the prop), the error also reaches the farthest of its points inside
    the same region measured on the surface, ``sum_j ((|q - L_j| - |p - L_j|) / sigma_j)^2 <=
    LOCATE_CHI2``, among those facing within :data:`FACING_DEG` of the mark (the guide names the
    way the mark faces, which tells it from the far side of a handle); ``surface_mm``: their
    distances (q, k) to the landmarks in mm, when known."""
    p = np.asarray(point, float)
    n = np.asarray(normal, float) / max(float(np.linalg.norm(normal)), 1e-300)
    t1, t2 = perpendicular_basis(n)
    lp = np.asarray(landmark_points, float).reshape(-1, 3)
    triples = np.asarray(triples, np.int64).reshape(-1, MEASURED)
    v = p - lp
    d_mm = np.linalg.norm(v, axis=1) * 1000.0
    u = v / np.maximum(d_mm[:, None] / 1000.0, 1e-300)
    g = np.stack([u @ t1, u @ t2], axis=1)
    sigma = TAPE_MM + TAPE_REL * d_mm
    outer = np.stack([g[:, 0] ** 2, g[:, 0] * g[:, 1], g[:, 1] ** 2], axis=1) / sigma[:, None] ** 2
    a, b, c = outer[triples].sum(axis=1).T
    lam = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.where(lam > 1e-12 * np.maximum(a + c, 1e-300), np.sqrt(LOCATE_CHI2 / lam), np.inf)
    if surface is None or not len(triples):
        return err
    q = surface.points
    facing = np.flatnonzero(surface.normals @ n >= math.cos(math.radians(FACING_DEG)))
    dist = surface_mm[facing] if surface_mm is not None else np.linalg.norm(q[facing, None, :] - lp[None], axis=2) * 1000.0
    z2 = ((dist - d_mm) / sigma) ** 2  # (facing, k)
    fit = (z2 <= LOCATE_CHI2).sum(axis=1) >= MEASURED  # may fit some triple
    z2, rows = z2[fit], facing[fit]
    far = np.linalg.norm(q[rows] - p, axis=1) * 1000.0
    step = max(1, 1_000_000 // max(len(rows), 1))  # (rows, step, 3) floats at a time: 24 MB at most
    for lo in range(0, len(triples), step):
        t = triples[lo : lo + step]
        fits = z2[:, t].sum(axis=2) <= LOCATE_CHI2  # (rows, t)
        worst = np.where(fits, far[:, None], 0.0).max(axis=0, initial=0.0)
        err[lo : lo + step] = np.maximum(err[lo : lo + step], worst)
    return err


class SurfaceSample(NamedTuple):
    """Points sampled on a prop (:func:`surface_sample`): where :func:`locating_errors` looks for
    points the readings cannot tell from a mark."""

    points: np.ndarray  # (q, 3) m
    normals: np.ndarray  # (q, 3) the outward normal of each point's face


def surface_sample(mesh) -> SurfaceSample:
    """:data:`LOCATE_SAMPLES` points on ``mesh``, uniform by area, the same on every run."""
    import trimesh

    pts, face = trimesh.sample.sample_surface(mesh, LOCATE_SAMPLES, seed=np.random.default_rng(0))
    return SurfaceSample(np.asarray(pts, float), np.asarray(mesh.face_normals, float)[face])


class MeshGuide(NamedTuple):
    """What the rigging guide reads off the mesh alone (:func:`mesh_guide`): what
    :func:`landmarks` locates every marker from."""

    landmarks: list[dict]  # :func:`mesh_landmarks`
    bounds: np.ndarray  # (2, 3) m: the axis-aligned bounding box
    flat: FlatFaces
    surface: SurfaceSample


def mesh_guide(mesh) -> MeshGuide:
    """The landmarks, bounding box, flat faces and surface sample of ``mesh`` (a
    ``trimesh.Trimesh``, m)."""
    return MeshGuide(mesh_landmarks(mesh), np.asarray(mesh.bounds, float), flat_faces(mesh), surface_sample(mesh))


def prop_guide(prop) -> MeshGuide:
    """:func:`mesh_guide` of a :class:`~starforge.props.mesh.PropMesh`, kept in the cache folder
    (:func:`starforge.runtime.stored.stored`) by its arrays: a later run on the same prop reads it
    back without building the mesh."""
    from starforge.runtime.stored import content_key, stored

    key = content_key("guide", prop.vertices, prop.faces, libraries=("numpy", "scipy", "trimesh"))
    return stored("guide", key, lambda: mesh_guide(prop.mesh))[0]


def _measured_from(p, n, lp: np.ndarray, d: np.ndarray, surface, surface_mm) -> tuple[np.ndarray, float, bool]:
    """The landmarks (indices into ``lp``, ``d`` mm from ``p``; nearest first) that locate the
    mark at ``p`` best, and their locating error (mm; inf when they cannot): the
    :data:`MEASURED` whose readings do (:func:`locating_errors`), or the nearest in the mark's
    own tangent plane (within :data:`IN_PLANE`: on its flat face) when setting the mark off it,
    the distance read and the direction named, does better (:func:`_offset_error`; then the
    flag is true)."""
    from itertools import combinations

    usable = np.flatnonzero(d >= MIN_MEASURE_MM)
    if len(usable) < MEASURED:  # too few apart from the mark: the nearest, however poor
        order = np.argsort(d, kind="stable")[:MEASURED]
        err = float(locating_errors(p, n, lp, [order], surface, surface_mm)[0]) if len(order) == MEASURED else math.inf
        chosen = order
    else:
        triples = np.array(list(combinations(usable.tolist(), MEASURED)), np.int64)
        errs = locating_errors(p, n, lp, triples, surface, surface_mm)
        # the tightest; among those within a micrometre of it, the shortest readings
        key = np.where(np.isfinite(errs), np.round(errs, 3), np.inf)
        best = int(np.lexsort((d[triples].sum(axis=1), key))[0])
        chosen, err = triples[best][np.argsort(d[triples[best]], kind="stable")], float(errs[best])
    # a landmark in the mark's own plane (on its flat face): set the mark off it, if that is tighter
    off = lp - p
    level = np.abs(off @ n) <= IN_PLANE * np.linalg.norm(off, axis=1)
    if level.any():
        j = int(np.flatnonzero(level)[np.argmin(d[level])])
        if _offset_error(d[j]) < err:
            return np.array([j]), _offset_error(d[j]), True
    return chosen, err, False


def _offset_error(d_mm: float) -> float:
    """How far (mm) 95 % of marks set ``d_mm`` off a landmark in the direction named land: the
    reading's error along it, and across it the direction judged by eye to :data:`OFFSET_DEG`
    (one standard deviation), the larger of the two as in :func:`locating_errors`."""
    return math.sqrt(LOCATE_CHI2) * max(TAPE_MM + TAPE_REL * d_mm, d_mm * math.sin(math.radians(OFFSET_DEG)))


def landmarks(
    guide: MeshGuide, points: np.ndarray, normals: np.ndarray, faces=None, placement_error_mm: float = math.inf
) -> list[dict]:
    """Per marker (surface ``points`` (m, 3) m, outward ``normals``, the mesh ``faces`` they lie
    on): ``{"from": {"x": "min"|"max", ...}, "distance_mm": [dx, dy, dz] (from the nearer side of
    the bounding box on each axis), "face": {"kind": "flat" | "curved", ...}, "measure_from":
    [{"name", "distance_mm"}] (:func:`_measured_from`), "locating_error_mm" (how tightly those
    readings place the mark, :func:`locating_errors`; None when they cannot), "tilt_deg",
    "leans", "text"}``, from ``guide`` (:func:`mesh_guide` of the mesh).  A mark the readings
    locate less tightly than ``placement_error_mm`` is said to be placed by the drawings (the
    views, the template)."""
    lo, hi = np.asarray(guide.bounds, float)
    marks = guide.landmarks
    lp = np.array([m["point"] for m in marks], float).reshape(-1, 3)
    surface = guide.surface if len(points) else None
    surface_mm = None if surface is None else np.linalg.norm(surface.points[:, None, :] - lp[None], axis=2) * 1000.0
    out = []
    for i, (p, n) in enumerate(zip(np.asarray(points, float), np.asarray(normals, float), strict=True)):
        side, dist = {}, []
        for k, ax in enumerate(AXES):
            a, b = p[k] - lo[k], hi[k] - p[k]
            side[ax] = "min" if a <= b else "max"
            dist.append(round(float(min(a, b)) * 1000.0, 1) + 0.0)
        f = guide.flat.of(int(faces[i])) if faces is not None else None
        if f is not None:
            face = {"kind": "flat", **f}
            on = f"on flat face {f['id']} (facing {f['facing']}, {f['area_mm2']:.0f} mm2)"
        else:
            face = {"kind": "curved", "facing": _direction(n)}
            on = f"on the curved surface (facing {_direction(n)})"
        d = np.linalg.norm(lp - p, axis=1) * 1000.0
        order, err, set_off = _measured_from(p, n, lp, d, surface, surface_mm)
        near = [{"name": marks[j]["name"], "distance_mm": round(float(d[j]), 1) + 0.0} for j in order]
        if set_off:  # set off a landmark on its own face, in the direction named
            off = p - lp[order[0]]
            near[0]["towards"] = heading(off - (off @ n) * n)
        deg, leans = tilt(n)
        lean = f", leaning {leans}" if leans and 1.0 <= deg <= 179.0 else ""
        if err <= placement_error_mm:
            located = f" (to {err:.1f} mm)"
        else:  # the readings cannot place it within the margin: the drawings must
            located = f" (to {err:.1f} mm only: place it by the drawings)" if math.isfinite(err) else " (place it by the drawings)"
        readings = ", ".join(f"{m['distance_mm']:.1f} mm from {m['name']}" + (f" towards {m['towards']}" if "towards" in m else "") for m in near)
        text = f"{on}; {readings or 'no landmark to measure from'}{located}; tilt {deg:.0f} deg from +z{lean}"
        out.append({"from": side, "distance_mm": dist, "face": face, "measure_from": near,
                    "locating_error_mm": round(float(err), 2) if math.isfinite(err) else None,
                    "tilt_deg": round(deg, 1), "leans": leans, "text": text})  # fmt: skip
    return out


def caliper_pairs(centres: np.ndarray, ball_mm: float, placement_error_mm: float) -> list[dict]:
    """Every pair of ball centres (m): ``{"a", "b" (1-based), "centre_mm", "outside_mm" (a
    caliper across both balls' outsides: the centre distance plus a diameter), "tolerance_mm"}``;
    the tolerance is twice the placement error (each marker up to that far off its mark)."""
    c = np.asarray(centres, float)
    out = []
    for i in range(len(c)):
        for j in range(i + 1, len(c)):
            d = float(np.linalg.norm(c[i] - c[j])) * 1000.0
            out.append({"a": i + 1, "b": j + 1, "centre_mm": round(d, 1) + 0.0, "outside_mm": round(d + ball_mm, 1) + 0.0,
                        "tolerance_mm": round(2.0 * placement_error_mm, 2)})  # fmt: skip
    return out


def template_scale(extent_mm: tuple[float, float], page_mm: tuple[float, float] = (257.0, 160.0)) -> int:
    """The largest of 1:1, 1:2, 1:5, 1:10 (returned as the divisor) at which a view ``extent_mm``
    (width, height) fits the printable area ``page_mm`` (A4 landscape less margins)."""
    for k in (1, 2, 5, 10, 20):
        if extent_mm[0] / k <= page_mm[0] and extent_mm[1] / k <= page_mm[1]:
            return k
    return 50


def bases_mesh(prop_mesh, points: np.ndarray, normals: np.ndarray, base_mm: float, height_mm: float = 1.0):
    """The prop with a flat pad under every marker (a cylinder of the base's diameter standing
    ``height_mm`` off the surface and sunk as deep into it), united with manifold3d: a
    3D-printed prop comes out with the seats on it.  Returns a ``trimesh.Trimesh`` (m)."""
    import trimesh

    from starforge.props.solids import union_solids

    h = height_mm / 1000.0
    parts = [prop_mesh.copy()]
    for p, n in zip(np.asarray(points, float), np.asarray(normals, float), strict=True):
        tf = trimesh.geometry.align_vectors([0, 0, 1], n)
        tf[:3, 3] = p
        parts.append(trimesh.creation.cylinder(radius=base_mm / 2000.0, height=2 * h, sections=32, transform=tf))
    merged = union_solids(parts)
    return merged if merged is not None else trimesh.util.concatenate(parts)
