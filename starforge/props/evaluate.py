"""An independent check of layouts on poses the optimizer never saw.

Fresh poses: uniformly random rotations (normalised Gaussian quaternions) at uniformly random
positions of the capture volume, drawn from their own generator (``seed + seed_offset``); in
each pose a random ``cameras_lost`` fraction of the rig's cameras is lost, and the hand holds
the prop.  A marker is seen by a camera when its ball centre is in the camera's field of view,
faces it within the grazing limit, the sight line misses the hand (the ray-segment distance of
:mod:`starforge.cad.primitives`, not the compiled kernel's) and misses the prop (one occlusion query per sight line); it is
reconstructed when two surviving cameras see it.  A pose is tracked when at least three
markers are reconstructed and they span a triangle ``min_height_mm`` high (RMS distance from
their best-fit line, from the eigenvalues of their covariance).

None of this goes through the optimizer's table or its compiled kernel: the geometry is
recomputed here for the markers alone, so the check shares with the optimization only the
prop's occlusion query (embree, :mod:`starforge.props.rays`).
"""

from __future__ import annotations

import math

import numpy as np

from starforge.props.grips import GRIP_SEED_OFFSET, assign_grips
from starforge.props.scenarios import alive_masks
from starforge.props.tracked import TRIANGLE_SPREAD


def random_poses(volume, count: int, pivot, rng: np.random.Generator):
    """:class:`starforge.props.rig.Poses`: ``count`` uniform random rotations at uniform random
    positions of ``volume``."""
    from starforge.props.rig import Poses, quaternion_matrices

    q = rng.normal(size=(count, 4))
    R = quaternion_matrices(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    lo = np.asarray(volume.center) - np.asarray(volume.size) / 2
    T = lo + rng.random((count, 3)) * np.asarray(volume.size)
    return Poses(R, T, np.asarray(pivot, float))


def camera_hits(mesh, centres, normals, rig, poses, capsules=(), grazing_limit_deg: float = 180.0, pose_grip=None):
    """(P, m, C) bool: camera c sees marker i (ball centre ``centres[i]``, prop frame) at pose k.

    ``capsules``: the hand's capsules and bands at every pose; with ``pose_grip`` (P,) int, a sequence of
    grips instead (each a sequence of capsules), pose k held in grip ``pose_grip[k]``."""
    from starforge.props.visibility import camera_arrays, ray_offset, segment_occluded

    cam, basis, tans = camera_arrays(rig)
    R, T, piv = poses.rotations, poses.translations, poses.pivot
    w = np.einsum("kij,mj->kmi", R, centres - piv) + T[:, None]  # (P, m, 3) world
    wn = np.einsum("kij,mj->kmi", R, normals)
    d = w[:, :, None] - cam[None, None]  # (P, m, C, 3) camera -> marker
    loc = np.einsum("cij,kmcj->kmci", basis, d)
    z = loc[..., 2]
    ok = (z > 0) & (np.abs(loc[..., 0]) <= tans[:, 0] * z) & (np.abs(loc[..., 1]) <= tans[:, 1] * z)
    dist = np.linalg.norm(d, axis=-1)
    ok &= -np.einsum("kmcj,kmj->kmc", d, wn) >= math.cos(math.radians(grazing_limit_deg)) * dist
    if len(capsules):
        # in the prop frame, where the hand is fixed: rays from the ball centres to the cameras
        # (the hand is within the prop's reach, the cameras metres away: a ray is the segment)
        qk = np.einsum("kji,kcj->kci", R, cam[None] - T[:, None]) + piv  # (P, C, 3)
        rays = qk[:, None, :, :] - centres[None, :, None, :]  # (P, m, C, 3)
        grip = np.zeros(len(R), np.int64) if pose_grip is None else np.asarray(pose_grip, np.int64)
        for g, caps in enumerate([capsules] if pose_grip is None else capsules):
            rows = np.flatnonzero(grip == g)
            if not len(rows) or not len(caps):
                continue
            r = rays[rows]
            org = np.broadcast_to(centres[None, :, None, :], r.shape).reshape(-1, 3)
            dirs = (r / np.linalg.norm(r, axis=-1, keepdims=True)).reshape(-1, 3)
            for cap in caps:
                ok[rows] &= ~cap.meets(org, dirs).reshape(r.shape[:3])
    kk, mm, cc = np.nonzero(ok)
    if len(kk):
        # the sight line in the prop frame: camera -> prop frame is R^T (x - t) + pivot
        qc = np.einsum("kji,kj->ki", R[kk], cam[cc] - T[kk]) + piv
        org = centres[mm] + ray_offset(mesh) * normals[mm]
        ok[kk, mm, cc] = ~segment_occluded(mesh, org, qc)
    return ok


def reconstructed(hits: np.ndarray, alive: np.ndarray) -> np.ndarray:
    """(P, m) bool: marker seen by at least two of the pose's surviving cameras."""
    C = hits.shape[2]
    live = ((alive[:, None] >> np.arange(C, dtype=np.uint64)) & np.uint64(1)).astype(bool)  # (P, C)
    return (hits & live[:, None, :]).sum(axis=2) >= 2


def tracked_poses(hits: np.ndarray, alive: np.ndarray, centres: np.ndarray, min_height_mm: float) -> np.ndarray:
    """(P,) bool: >= 3 markers reconstructed (two surviving cameras each), not in a line."""
    rec = reconstructed(hits, alive)
    n = rec.sum(axis=1)
    w = rec.astype(float)
    mean = (w @ centres) / np.maximum(n, 1)[:, None]
    dev = centres[None] - mean[:, None]
    cov = np.einsum("km,kmi,kmj->kij", w, dev, dev) / np.maximum(n, 1)[:, None, None]
    ev = np.linalg.eigvalsh(cov)  # ascending
    spread2 = ev[:, 0] + ev[:, 1]
    return (n >= 3) & (spread2 >= (TRIANGLE_SPREAD * min_height_mm / 1000.0) ** 2)


def evaluate_layouts(mesh, layouts: dict, rig, pivot, settings, seed: int, min_height_mm: float,
                     grips=(), grazing_limit_deg: float = 180.0) -> dict:
    """Each layout (name -> (centres (m, 3), normals (m, 3)), prop frame, m) on ``mesh`` (a
    PropMesh or a ``trimesh.Trimesh``) on the same fresh
    poses and camera losses, each pose held in a grip of ``grips`` (:class:`starforge.props.grips.Grip`,
    the same number of poses each, in an order of their own seed): ``{name: {"tracked": fraction under loss and the hand,
    "tracked_all_cameras": fraction with every camera, "markers_reconstructed": mean fraction of
    the markers seen by two surviving cameras}}``, plus ``"_poses"``, the count."""
    rng = np.random.default_rng(seed + settings.seed_offset)
    poses = random_poses(rig.volume, settings.poses, pivot, rng)
    C = len(rig.cameras)
    alive = alive_masks(C, settings.cameras_lost, len(poses), rng)
    pose_grip = assign_grips(len(poses), grips, np.random.default_rng(seed + settings.seed_offset + GRIP_SEED_OFFSET))
    held = [g.capsules for g in grips]
    every = np.full(len(poses), np.uint64((1 << C) - 1) if C < 64 else np.uint64(2**64 - 1))
    out = {"_poses": len(poses), "_cameras_lost": int(round(settings.cameras_lost * C))}
    per_pose = {}
    # a marker's hits depend on that marker alone: the layouts' markers (they share most) are
    # looked at once, each distinct (centre, normal) row one column of the table
    rows = [np.hstack([np.asarray(c, float).reshape(-1, 3), np.asarray(n, float).reshape(-1, 3)]) for c, n in layouts.values()]
    union, at = np.unique(np.vstack(rows), axis=0, return_inverse=True) if rows else (np.zeros((0, 6)), None)
    table = camera_hits(mesh, union[:, :3], union[:, 3:], rig, poses, held, grazing_limit_deg, pose_grip) if len(poses) and len(union) else None
    start = np.cumsum([0] + [len(r) for r in rows])
    for k, (name, (c, n)) in enumerate(layouts.items()):
        c, n = np.asarray(c, float), np.asarray(n, float)
        if not len(poses) or not len(c):
            out[name] = {"tracked": 0.0, "tracked_all_cameras": 0.0, "markers_reconstructed": 0.0}
            per_pose[name] = np.zeros(len(poses), bool)
            continue
        hits = table[:, np.ravel(at)[start[k] : start[k + 1]]]
        per_pose[name] = tracked_poses(hits, alive, c, min_height_mm)
        out[name] = {
            "tracked": float(per_pose[name].mean()),
            "tracked_all_cameras": float(tracked_poses(hits, every, c, min_height_mm).mean()),
            "markers_reconstructed": float(reconstructed(hits, alive).mean()),
        }
    if "default" in per_pose:  # each other layout against the default, pose by pose
        for name, t in per_pose.items():
            if name != "default":
                out[name].update(paired(per_pose["default"], t))
    return out


def paired(default: np.ndarray, other: np.ndarray) -> dict:
    """The two layouts on the same poses: the poses only ``other`` tracks, those only
    ``default`` tracks, and the exact two-sided McNemar p-value (a binomial test of the
    discordant poses against an even split: the chance of a split at least this uneven when
    neither layout is better)."""
    only_other = int(np.sum(other & ~default))
    only_default = int(np.sum(default & ~other))
    return {
        "poses_only_it_tracks": only_other,
        "poses_only_default_tracks": only_default,
        "paired_p_value": mcnemar_exact(only_other, only_default),
    }


def mcnemar_exact(b: int, c: int) -> float:
    """Exact two-sided McNemar p-value of ``b`` against ``c`` discordant pairs (1 when none):
    ``min(1, 2 P(X <= min(b, c)))`` for ``X ~ Binomial(b + c, 1/2)``."""
    n = b + c
    if n == 0:
        return 1.0
    k = min(b, c)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)
