"""How far points are from a prop's surface, exactly, fast on fine meshes (the seat rules,
:mod:`starforge.props.seat`, and the clamps, :mod:`starforge.props.clamp`)."""

from __future__ import annotations

import numpy as np

from starforge.tol import tol

#: pairs (point, candidate face) measured at once by :func:`surface_distance`
_PAIR_CHUNK = 200_000


def surface_distance(mesh, points: np.ndarray, reach: float | np.ndarray = np.inf) -> np.ndarray:
    """(p,) m: exact distance from each of ``points`` (p, 3) m to the surface of ``mesh``, up to
    ``reach`` (one for all, or (p,) one each; a point farther off gets ``inf``: a test against a threshold needs no more, and
    a point far off a fine mesh would otherwise measure every face round it).

    Without a tree of the faces' boxes (whose build dominates on a fine mesh): the faces are
    grouped by their size (the farthest corner from the centroid, ``r``; within a group ``r``
    varies at most twofold) and each group's centroids go in a k-d tree.  A face's distance is at
    most its centroid's, so the nearest centroid of any group bounds the answer ``u``; a face
    nearer than ``u`` has its centroid within ``u + r``, and only those faces are measured."""
    import trimesh
    from scipy.spatial import cKDTree

    pts = np.asarray(points, float).reshape(-1, 3)
    tri = np.asarray(mesh.triangles, float)
    out = np.full(len(pts), np.inf)
    if not len(pts) or not len(tri):
        return out
    cen = tri.mean(axis=1)
    rad = np.linalg.norm(tri - cen[:, None], axis=2).max(axis=1)
    level = np.floor(np.log2(np.maximum(rad, tol.zero) / max(float(rad.max()), tol.zero))).astype(np.int64)
    groups = [np.flatnonzero(level == k) for k in np.unique(level)]
    trees = [cKDTree(cen[g]) for g in groups]
    bound = np.minimum(np.min([t.query(pts)[0] for t in trees], axis=0), reach)
    for g, tree in zip(groups, trees, strict=True):
        near = tree.query_ball_point(pts, bound + float(rad[g].max()), return_sorted=False)
        cnt = np.fromiter(map(len, near), np.int64, len(near))
        if not cnt.sum():
            continue
        face = g[np.concatenate([np.asarray(x, np.int64) for x in near if x])]
        site = np.repeat(np.arange(len(pts)), cnt)
        for a in range(0, len(face), _PAIR_CHUNK):
            f, q = face[a : a + _PAIR_CHUNK], pts[site[a : a + _PAIR_CHUNK]]
            d = np.linalg.norm(trimesh.triangles.closest_point(tri[f], q) - q, axis=1)
            np.minimum.at(out, site[a : a + _PAIR_CHUNK], d)
    out[out > reach] = np.inf
    return out
