"""The visibility table: which camera pair sees which candidate site at which pose.

Computed once, so that every optimizer step is a table lookup rather than a render.

A camera sees a site at a pose when (all in the prop frame, where the prop is fixed and the
cameras move): the site is inside the camera's field of view (in front of it, within the
horizontal and vertical half-angles), the surface faces the camera within the grazing-angle
limit (angle between the outward normal and the direction to the camera at most
``grazing_limit_deg``), and the segment from the site to the camera hits no part of the prop
(one embree occlusion query per segment, :mod:`starforge.props.rays`; the segment starts a
hair above the surface to step off its own triangle).  A pair sees the site when both cameras do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import types
from numba.extending import intrinsic

from starforge.errors import StarforgeError
from starforge.props.hand import CAPSULE_COLUMNS, posts_in_hands
from starforge.props.rays import ray_scene
from starforge.runtime.kernels import numba
from starforge.runtime.threads import threads_for_work
from starforge.spec import in_range

# rays start this far (fraction of the prop's bounding-box diagonal, clipped) above the surface
RAY_OFFSET_FRACTION = 1e-4
RAY_OFFSET_MAX_M = 1e-4
RAY_OFFSET_MIN_M = 1e-7


@dataclass(frozen=True)
class VisibilityTable:
    """Which cameras see every site at every pose.

    Attributes
    ----------
    masks : (s, p) uint64
        Bit ``c`` of ``masks[i, k]``: camera ``c`` sees site ``i`` at pose ``k``.  A site seen
        by fewer than two cameras at a pose has mask 0 there (it cannot be triangulated, so its
        rays are not cast).
    pairs : (c, 2) int
        The rig's camera pairs (the paper's model: a pair sees a site when both cameras do).
    rays : int
        Occlusion rays cast against the prop.
    """

    masks: np.ndarray = field(repr=False)
    pairs: np.ndarray = field(repr=False)
    rays: int = 0

    @property
    def seen(self) -> np.ndarray:
        """(s, p, pairs) bool: ``seen[i, k, j]``, site ``i`` at pose ``k`` is seen by both
        cameras of pair ``j``."""
        m = self.masks
        a = (m[..., None] >> self.pairs[:, 0].astype(np.uint64)) & np.uint64(1)
        b = (m[..., None] >> self.pairs[:, 1].astype(np.uint64)) & np.uint64(1)
        return (a & b).astype(bool)

    @property
    def site_visibility(self) -> np.ndarray:
        """(s,) float in [0, 1]: fraction of (pose, pair) combinations that see each site."""
        s = self.masks.shape[0]
        return self.seen.reshape(s, -1).mean(axis=1)

    def cameras_seen(self) -> np.ndarray:
        """(s, p) int: how many cameras see each site at each pose."""
        return np.bitwise_count(self.masks).astype(np.int64)


def ray_offset(mesh) -> float:
    """Distance (m) rays start above the surface for a mesh of this size."""
    size = ray_scene(mesh).size
    return float(np.clip(RAY_OFFSET_FRACTION * size, RAY_OFFSET_MIN_M, RAY_OFFSET_MAX_M))


def segment_occluded(mesh, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(n,) bool: the segment from each origin to its target crosses ``mesh`` (a PropMesh or a
    ``trimesh.Trimesh``): :meth:`starforge.props.rays.RayScene.blocked` of its scene."""
    return ray_scene(mesh).blocked(origins, targets)


def camera_arrays(rig):
    """Positions (c,3), bases (c,3,3) and half-angle tangents (c,2) of the rig's cameras."""
    pos = np.array([c.position for c in rig.cameras], dtype=float)
    basis = np.array([c.basis() for c in rig.cameras])
    tans = np.array([c.half_tangents for c in rig.cameras])
    return pos, basis, tans


def in_view(points_world: np.ndarray, rig) -> np.ndarray:
    """(n, c) bool: each world point inside each camera's field of view (no occlusion)."""
    pos, basis, tans = camera_arrays(rig)
    d = points_world[:, None, :] - pos[None]
    cam = np.einsum("cij,ncj->nci", basis, d)
    z = cam[..., 2]
    return (z > 0) & (np.abs(cam[..., 0]) <= tans[:, 0] * z) & (np.abs(cam[..., 1]) <= tans[:, 1] * z)


def check_rig_sees_volume(rig, positions_world: np.ndarray) -> None:
    """StarforgeError unless some camera pair sees at least one pose position."""
    v = in_view(positions_world, rig)
    pairs = np.array(rig.pairs)
    both = v[:, pairs[:, 0]] & v[:, pairs[:, 1]]
    if not both.any():
        raise StarforgeError(
            "no camera pair sees the capture volume: check the rig's camera targets and fields of view"
        )


@intrinsic
def _fma(typingctx, a, b, c):
    """``a * b + c`` rounded once (LLVM's fma): the step of the BLAS dot product that numba's
    ``@`` on float64 vectors calls (OpenBLAS's ``ddot``), so that the scalar kernels below
    reproduce its sums bit for bit."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@numba.njit(cache=True, nogil=True, inline="always")
def _dot3(ax, ay, az, bx, by, bz):
    """The dot product of two 3-vectors, summed as BLAS's ``ddot`` sums it (fused, in order)."""
    return _fma(az, bz, _fma(ay, by, ax * bx))


@numba.njit(cache=True, nogil=True)
def _seg_seg_dist2(p0x, p0y, p0z, p1x, p1y, p1z, q0x, q0y, q0z, q1x, q1y, q1z):
    """Squared distance between segments p0-p1 and q0-q1 (closest points, clamped), from their
    coordinates (scalars: no arrays are made in the kernel's inner loop)."""
    d1x, d1y, d1z = p1x - p0x, p1y - p0y, p1z - p0z
    d2x, d2y, d2z = q1x - q0x, q1y - q0y, q1z - q0z
    rx, ry, rz = p0x - q0x, p0y - q0y, p0z - q0z
    a = _dot3(d1x, d1y, d1z, d1x, d1y, d1z)
    e = _dot3(d2x, d2y, d2z, d2x, d2y, d2z)
    f = _dot3(d2x, d2y, d2z, rx, ry, rz)
    s = 0.0
    t = 0.0
    if a <= 1e-300 and e <= 1e-300:
        return _dot3(rx, ry, rz, rx, ry, rz)
    if a <= 1e-300:
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = _dot3(d1x, d1y, d1z, rx, ry, rz)
        if e <= 1e-300:
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = _dot3(d1x, d1y, d1z, d2x, d2y, d2z)
            den = a * e - b * b
            if den > 1e-300:
                s = min(max((b * f - c * e) / den, 0.0), 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    wx = (p0x + d1x * s) - (q0x + d2x * t)
    wy = (p0y + d1y * s) - (q0y + d2y * t)
    wz = (p0z + d1z * s) - (q0z + d2z * t)
    return _dot3(wx, wy, wz, wx, wy, wz)


@numba.njit(cache=True, nogil=True)
def _seg_band_hit(cx, cy, cz, dx, dy, dz, ax, ay, az, bx, by, bz, r):
    """Whether the segment from ``c`` to ``c + d`` has a point inside the band round ``a``-``b``
    of radius ``r`` (:func:`starforge.geometry.distance.ray_enters_band`, for one segment: the
    stretch of the segment between the end planes, then the least distance from the axis on it)."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    L = math.sqrt(ux * ux + uy * uy + uz * uz)
    if L > 0.0:
        ux, uy, uz = ux / L, uy / L, uz / L
    rx, ry, rz = cx - ax, cy - ay, cz - az
    t0 = rx * ux + ry * uy + rz * uz
    du = dx * ux + dy * uy + dz * uz
    lo, hi = 0.0, 1.0
    if abs(du) <= 1e-300:
        if t0 < 0.0 or t0 > L:
            return False
    else:
        sa, sb = -t0 / du, (L - t0) / du
        lo, hi = max(min(sa, sb), 0.0), min(max(sa, sb), 1.0)
        if lo > hi:
            return False
    w0x, w0y, w0z = rx - t0 * ux, ry - t0 * uy, rz - t0 * uz
    wdx, wdy, wdz = dx - du * ux, dy - du * uy, dz - du * uz
    ww = wdx * wdx + wdy * wdy + wdz * wdz
    s = lo
    if ww > 1e-300:
        s = min(max(-(w0x * wdx + w0y * wdy + w0z * wdz) / ww, lo), hi)
    ex, ey, ez = w0x + s * wdx, w0y + s * wdy, w0z + s * wdz
    return ex * ex + ey * ey + ez * ez <= r * r


@numba.njit(cache=True, nogil=True, parallel=True)
def _view_masks(centres, normals, q, axes, tans, cos_lim, caps, cap_start, pose_grip, min_cams):
    """(s, P) uint64 camera bits: camera c (position ``q[k, c]`` and axes ``axes[k, c]`` in the
    prop frame at pose k) has site i's ball centre in its field of view, faces it within the
    grazing limit, and the segment between them misses every capsule (or band) of the pose's
    grip: rows ``cap_start[g]:cap_start[g + 1]`` of ``caps`` (h, 8,
    :func:`starforge.props.hand.capsule_arrays`) for ``g = pose_grip[k]``.  Masks
    with fewer than ``min_cams`` bits are cleared.  The prop itself is tested afterwards.

    Scalar arithmetic throughout (no temporary arrays), with the dot products summed as BLAS
    sums them on an FMA machine (:func:`_dot3`): the same masks, bit for bit, as the array
    expressions (``axes[k, c, 2] @ (centres[i] - q[k, c])``, ...) it replaces, and 26 x less
    CPU on the hammer's table (0.119 -> 0.0046 s)."""
    S = centres.shape[0]
    P, C = q.shape[0], q.shape[1]
    H = caps.shape[0]
    out = np.zeros((S, P), dtype=np.uint64)
    # each capsule's bounding sphere: a segment farther than its radius from the centre misses
    # the capsule (the capsule's points are within half its length plus its radius of it), so
    # the exact segment-segment test runs only for the segments that pass near; the 1e-6 m
    # margin keeps rounding on the safe side, so the masks are the same bit for bit
    mid = np.empty((H, 3))
    reach2 = np.empty(H)
    for h in range(H):
        ax, ay, az = caps[h, 3] - caps[h, 0], caps[h, 4] - caps[h, 1], caps[h, 5] - caps[h, 2]
        mid[h, 0], mid[h, 1], mid[h, 2] = caps[h, 0] + 0.5 * ax, caps[h, 1] + 0.5 * ay, caps[h, 2] + 0.5 * az
        r = 0.5 * math.sqrt(ax * ax + ay * ay + az * az) + caps[h, 6] + 1e-6
        reach2[h] = r * r
    for k in numba.prange(P):
        h0, h1 = cap_start[pose_grip[k]], cap_start[pose_grip[k] + 1]
        for i in range(S):
            cx, cy, cz = centres[i, 0], centres[i, 1], centres[i, 2]
            m = np.uint64(0)
            cnt = 0
            for c in range(C):
                qx, qy, qz = q[k, c, 0], q[k, c, 1], q[k, c, 2]
                dx, dy, dz = cx - qx, cy - qy, cz - qz
                z = _dot3(axes[k, c, 2, 0], axes[k, c, 2, 1], axes[k, c, 2, 2], dx, dy, dz)
                if z <= 0.0:
                    continue
                if abs(_dot3(axes[k, c, 0, 0], axes[k, c, 0, 1], axes[k, c, 0, 2], dx, dy, dz)) > tans[c, 0] * z:
                    continue
                if abs(_dot3(axes[k, c, 1, 0], axes[k, c, 1, 1], axes[k, c, 1, 2], dx, dy, dz)) > tans[c, 1] * z:
                    continue
                dist = math.sqrt(_dot3(dx, dy, dz, dx, dy, dz))
                if -_dot3(dx, dy, dz, normals[i, 0], normals[i, 1], normals[i, 2]) < cos_lim * dist:
                    continue
                hidden = False
                for h in range(h0, h1):
                    # the point of the segment centre -> camera nearest the sphere's centre
                    mx, my, mz = mid[h, 0] - cx, mid[h, 1] - cy, mid[h, 2] - cz
                    t = -(mx * dx + my * dy + mz * dz) / (dist * dist)  # (m - c) . (q - c) / |q - c|^2
                    t = min(max(t, 0.0), 1.0)
                    ex, ey, ez = mx + t * dx, my + t * dy, mz + t * dz
                    if ex * ex + ey * ey + ez * ez > reach2[h]:
                        continue
                    if caps[h, 7] != 0.0:
                        if _seg_band_hit(
                            cx, cy, cz, -dx, -dy, -dz, caps[h, 0], caps[h, 1], caps[h, 2], caps[h, 3], caps[h, 4], caps[h, 5], caps[h, 6]
                        ):
                            hidden = True
                            break
                        continue
                    d2 = _seg_seg_dist2(
                        cx, cy, cz, qx, qy, qz, caps[h, 0], caps[h, 1], caps[h, 2], caps[h, 3], caps[h, 4], caps[h, 5]
                    )
                    if d2 <= caps[h, 6] * caps[h, 6]:
                        hidden = True
                        break
                if hidden:
                    continue
                m |= np.uint64(1) << np.uint64(c)
                cnt += 1
            if cnt >= min_cams:
                out[i, k] = m
    return out


def compute_table(
    mesh,
    points,
    normals,
    rig,
    poses,
    grazing_limit_deg: float = 80.0,
    max_batch: int = 2_000_000,
    progress=None,
    radius_m: float = 0.0,
    occlusion: bool = True,
    centre_m: float | None = None,
    occluders: np.ndarray | None = None,
    occluder_starts: np.ndarray | None = None,
    pose_grip: np.ndarray | None = None,
    post_m: float = 0.0,
) -> VisibilityTable:
    """Build the (sites x poses) camera-mask table.

    Parameters
    ----------
    mesh : PropMesh or trimesh.Trimesh
        The prop, metres, normals outward (its rays: :func:`starforge.props.rays.ray_scene`).
    points, normals : (s, 3) float
        Sites on the surface (m) and their outward unit normals, prop frame.
    rig : Rig
    poses : Poses
    grazing_limit_deg : float
        Largest angle between the normal and the direction to a camera that still counts as seen,
        degrees in (0, 180].
    max_batch : int
        Occlusion rays per embree call (bounds memory).
    progress : callable, optional
        Called as ``progress(done, total)``.
    radius_m : float
        Marker ball radius, m.
    occlusion : bool
        Test the segments against the prop (False: field of view and facing only, a model that
        lets a camera see through the prop; for comparison with published figures).
    centre_m : float, optional
        Height of the ball's centre above the site along the normal, m (default ``radius_m``: a
        ball resting on the surface; a marker on a base sits higher).
    occluders : (k, 8) float, optional
        Capsules and bands that move with the prop (the hand, :func:`starforge.props.hand.capsule_arrays`),
        all of them at every pose unless grouped by grip.
    occluder_starts : (g + 1,) int, optional
        The capsules of grip g are rows ``occluder_starts[g]:occluder_starts[g + 1]``
        (:func:`starforge.props.grips.grip_arrays`).
    pose_grip : (p,) int, optional
        The grip each pose is held in (:func:`starforge.props.grips.assign_grips`; default 0).
    post_m : float
        Length of a stand-off post under each marker's base, m (0: none).  With a post, a marker
        whose post (the site to the ball's centre) passes through the hand of a pose's grip is
        hidden at that pose (:func:`starforge.props.hand.posts_in_hands`).  A marker stuck on the
        prop is tested by its ball's centre alone.

    Notes
    -----
    Field of view, facing and the capsules are tested in compiled code for every (site, pose,
    camera); a ray is cast against the prop only where the site passed those tests for at least
    two cameras at that pose (one camera alone cannot triangulate it).
    """
    grazing = in_range("grazing_limit_deg", grazing_limit_deg, 1e-6, 180.0)
    cos_lim = math.cos(math.radians(grazing))
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=float).reshape(-1, 3)
    cam_pos, basis, tans = camera_arrays(rig)
    if len(cam_pos) > 64:
        raise StarforgeError(f"a rig has at most 64 cameras, this one {len(cam_pos)}")
    pairs = np.array(rig.pairs, dtype=np.int64).reshape(-1, 2)
    R, T, pivot = poses.rotations, poses.translations, poses.pivot
    check_rig_sees_volume(rig, T)
    h = radius_m if centre_m is None else centre_m
    centres = pts + h * nrm  # field of view, facing and rays from the ball's centre
    # cameras in the prop frame: q = R^T (cam - t) + pivot; camera axes: rows of basis @ R
    q = np.einsum("kji,kcj->kci", R, cam_pos[None] - T[:, None]) + pivot
    axes = np.einsum("cij,kjl->kcil", basis, R)
    caps = np.zeros((0, CAPSULE_COLUMNS)) if occluders is None else np.asarray(occluders, float).reshape(-1, CAPSULE_COLUMNS)
    starts = np.array([0, len(caps)], np.int64) if occluder_starts is None else np.asarray(occluder_starts, np.int64)
    grip = np.zeros(len(R), np.int64) if pose_grip is None else np.ascontiguousarray(pose_grip, dtype=np.int64)
    if len(grip) != len(R) or (len(grip) and (grip.min() < 0 or grip.max() >= len(starts) - 1)):
        raise StarforgeError(f"pose_grip must give each of the {len(R)} poses a grip in [0, {len(starts) - 2}]")
    with threads_for_work(len(centres) * len(R) * len(cam_pos)):
        masks = _view_masks(
            centres, nrm, np.ascontiguousarray(q), np.ascontiguousarray(axes), tans, cos_lim,
            np.ascontiguousarray(caps, dtype=float), starts, grip, 2,
        )  # fmt: skip
    if post_m > 0 and len(caps):
        held = posts_in_hands(pts, centres, caps, starts)  # (s, g)
        masks[held[:, grip]] = 0
    rays = 0
    if occlusion and masks.any():
        si, ki = np.nonzero(masks)
        m = masks[si, ki]
        C = len(cam_pos)
        bits = ((m[:, None] >> np.arange(C, dtype=np.uint64)[None]) & np.uint64(1)).astype(bool)
        row, cc = np.nonzero(bits)
        ss, kk = si[row], ki[row]
        origins = centres + ray_offset(mesh) * nrm
        blocked = np.zeros(len(row), dtype=bool)
        for a in range(0, len(row), max_batch):
            b = min(len(row), a + max_batch)
            blocked[a:b] = segment_occluded(mesh, origins[ss[a:b]], q[kk[a:b], cc[a:b]])
            if progress is not None:
                progress(b, len(row))
        rays = len(row)
        clear = np.zeros(len(m), dtype=np.uint64)
        np.bitwise_or.at(clear, row[blocked], np.uint64(1) << cc[blocked].astype(np.uint64))
        m = m & ~clear
        m[np.bitwise_count(m) < 2] = 0
        masks[si, ki] = m
    elif progress is not None:
        progress(1, 1)
    return VisibilityTable(masks, pairs, rays)


def first_hits(mesh, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m, inf for a miss) to the first face each ray hits, and that face (-1).

    The face is the scene's first hit (:func:`starforge.props.rays.ray_scene`, the embree scene
    trimesh builds) and the distance is where the ray meets that face's plane, computed as
    trimesh's ``intersects_id(multiple_hits=False, return_locations=True)`` computes it, so that
    the answer is trimesh's to the bit without trimesh building a second scene of the mesh."""
    import trimesh

    origins = np.asarray(origins, float)
    dirs = np.asarray(dirs, float)
    dist = np.full(len(origins), np.inf)
    face = np.full(len(origins), -1, dtype=np.int64)
    if not len(origins):
        return dist, face
    unit = trimesh.util.unitize(np.array(dirs, dtype=np.float64))
    tri = ray_scene(mesh).first(origins, unit)
    hit = np.flatnonzero(tri != -1)
    if len(hit):
        loc, valid = trimesh.intersections.planes_lines(
            plane_origins=np.asarray(mesh.triangles)[tri[hit], 0],
            plane_normals=np.asarray(mesh.face_normals)[tri[hit]],
            line_origins=origins[hit],
            line_directions=unit[hit],
        )
        ray = hit[valid]
        dist[ray] = np.einsum("ij,ij->i", np.asarray(loc) - origins[ray], dirs[ray])
        face[ray] = tri[ray]
    return dist, face
    tri, ray, loc = mesh.ray.intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    if len(ray):
        d = np.einsum("ij,ij->i", np.asarray(loc) - origins[ray], dirs[ray])
        dist[ray] = d
        face[ray] = tri
    return dist, face
