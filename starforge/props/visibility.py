"""The visibility table: which camera pair sees which candidate site at which pose.

Computed once, so that every optimizer step is a table lookup rather than a render.

A camera sees a site at a pose when (all in the prop frame, where the prop is fixed and the
cameras move): the site is inside the camera's field of view (in front of it, within the
horizontal and vertical half-angles), the surface faces the camera within the grazing-angle
limit (angle between the outward normal and the direction to the camera at most
``grazing_limit_deg``), and the segment from the site to the camera hits no part of the prop
(one embree occlusion query per segment, through trimesh's embreex scene; the segment starts a
hair above the surface to step off its own triangle).  A pair sees the site when both cameras do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from starforge.errors import StarforgeError
from starforge.spec import in_range

# rays start this far (fraction of the prop's bounding-box diagonal, clipped) above the surface
RAY_OFFSET_FRACTION = 1e-4
RAY_OFFSET_MAX_M = 1e-4
RAY_OFFSET_MIN_M = 1e-7


@dataclass(frozen=True)
class VisibilityTable:
    """Pair visibility of every site at every pose.

    Attributes
    ----------
    seen : (s, p, c) bool
        ``seen[i, k, j]``: site ``i`` at pose ``k`` is seen by both cameras of pair ``j``.
    rays : int
        Occlusion rays cast (segments that passed the field-of-view and facing tests).
    """

    seen: np.ndarray = field(repr=False)
    rays: int = 0

    @property
    def site_visibility(self) -> np.ndarray:
        """(s,) float in [0, 1]: fraction of (pose, pair) combinations that see each site."""
        s = self.seen.shape[0]
        return self.seen.reshape(s, -1).mean(axis=1)


def ray_offset(mesh) -> float:
    """Distance (m) rays start above the surface for a mesh of this size."""
    return float(np.clip(RAY_OFFSET_FRACTION * float(mesh.scale), RAY_OFFSET_MIN_M, RAY_OFFSET_MAX_M))


def segment_occluded(mesh, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(n,) bool: the segment from each origin to its target crosses the mesh.

    Uses embree (``trimesh.ray.ray_pyembree``, occlusion query with a finite ray length) when
    available, else trimesh's pure-numpy ray tracer.
    """
    import trimesh

    origins = np.asarray(origins, dtype=float)
    vec = np.asarray(targets, dtype=float) - origins
    dist = np.linalg.norm(vec, axis=1)
    if len(origins) == 0:
        return np.zeros(0, dtype=bool)
    dirs = vec / np.where(dist > 0, dist, 1.0)[:, None]
    # trimesh's scaled embreex scene (private attribute; float32 coordinates scaled to ~100 units)
    scene = getattr(mesh.ray, "_scene", None) if trimesh.ray.has_embree else None
    if scene is not None and hasattr(scene, "scale"):
        hit = scene.run(origins, dirs, dists=(dist * scene.scale).astype(np.float32), query="OCCLUDED")
        return np.asarray(hit) != -1
    # fallback: first hit along the ray, compared with the segment length
    from trimesh.ray.ray_triangle import RayMeshIntersector

    _, ray_idx, loc = RayMeshIntersector(mesh).intersects_id(
        origins, dirs, multiple_hits=True, return_locations=True
    )
    out = np.zeros(len(origins), dtype=bool)
    if len(ray_idx):
        d = np.einsum("ij,ij->i", loc - origins[ray_idx], dirs[ray_idx])
        ok = (d > 0) & (d < dist[ray_idx])
        out[ray_idx[ok]] = True
    return out


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


def compute_table(
    mesh,
    points,
    normals,
    rig,
    poses,
    grazing_limit_deg: float = 80.0,
    max_batch: int = 1_000_000,
    progress=None,
    radius_m: float = 0.0,
    occlusion: bool = True,
) -> VisibilityTable:
    """Build the (sites x poses x pairs) visibility table.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The prop, metres, normals outward (the only occluder).
    points, normals : (s, 3) float
        Sites on the surface (m) and their outward unit normals, prop frame.
    rig : Rig
    poses : Poses
    grazing_limit_deg : float
        Largest angle between the normal and the direction to a camera that still counts as seen,
        degrees in (0, 180].
    max_batch : int
        Camera-site tests per batch (bounds memory).
    progress : callable, optional
        Called as ``progress(done_poses, total_poses)``.
    radius_m : float
        Marker ball radius: a marker is seen when the segment from its centre (``radius_m`` off
        the surface along the normal) to the camera misses the prop.
    occlusion : bool
        Test the segments against the prop (False: field of view and facing only, a model that
        lets a camera see through the prop; for comparison with published figures).
    """
    grazing = in_range("grazing_limit_deg", grazing_limit_deg, 1e-6, 180.0)
    cos_lim = math.cos(math.radians(grazing))
    pts = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    s = len(pts)
    cam_pos, basis, tans = camera_arrays(rig)
    c = len(cam_pos)
    pairs = np.array(rig.pairs)
    P = len(poses)
    R, T, pivot = poses.rotations, poses.translations, poses.pivot
    check_rig_sees_volume(rig, T)
    offset = ray_offset(mesh)
    origins_all = pts + (radius_m + offset) * nrm
    pts = pts + radius_m * nrm  # field of view and facing are tested at the ball's centre
    seen = np.zeros((s, P, len(pairs)), dtype=bool)
    step = max(1, int(max_batch // max(1, s * c)))
    rays = 0
    for k0 in range(0, P, step):
        k1 = min(P, k0 + step)
        Rk, Tk = R[k0:k1], T[k0:k1]
        # cameras in the prop frame: q = R^T (cam - t) + pivot; camera axes: rows of basis @ R
        q = np.einsum("kji,kcj->kci", Rk, cam_pos[None] - Tk[:, None]) + pivot
        axes = np.einsum("cij,kjl->kcil", basis, Rk)  # (k, c, 3, 3)
        d = pts[None, None] - q[:, :, None]  # (k, c, s, 3) camera -> site
        local = np.einsum("kcij,kcsj->kcsi", axes, d)
        z = local[..., 2]
        ok = (z > 0) & (np.abs(local[..., 0]) <= tans[None, :, 0, None] * z)
        ok &= np.abs(local[..., 1]) <= tans[None, :, 1, None] * z
        dist = np.linalg.norm(d, axis=-1)
        facing = -np.einsum("kcsj,sj->kcs", d, nrm) >= cos_lim * dist
        ok &= facing
        idx = np.nonzero(ok)
        if occlusion and len(idx[0]):
            kk, cc, ss = idx
            blocked = segment_occluded(mesh, origins_all[ss], q[kk, cc])
            ok[kk[blocked], cc[blocked], ss[blocked]] = False
            rays += len(ss)
        cam_seen = np.transpose(ok, (2, 0, 1))  # (s, k, c)
        seen[:, k0:k1] = cam_seen[:, :, pairs[:, 0]] & cam_seen[:, :, pairs[:, 1]]
        if progress is not None:
            progress(k1, P)
    return VisibilityTable(seen, rays)
