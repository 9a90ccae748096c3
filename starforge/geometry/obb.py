"""Oriented bounding boxes of small point sets, and the paper's placement transform.

Two boxes, both vectorised over a leading axis ``points : (n, k, 3)``:

* :func:`covariance_box`: the paper's method (Gottschalk): axes from the eigenvectors of the
  covariance of the points.  Cheap, not minimal.
* :func:`min_volume_box`: the minimum-volume box.  By O'Rourke's theorem the optimal box
  either has a face flush with a hull face, or two adjacent faces each flush with a hull
  edge.  The first case is enumerated exactly (face normal x projected hull edge, the 2-D
  rotating-calipers candidates); the second is a one-parameter family per edge pair, which is
  sampled densely and then refined by golden-section search.  Every candidate is a valid
  enclosing box, so the result always contains the points and is within ``1e-9`` relative of
  the optimum for tetrahedra (checked against brute force in the tests).

Boxes are returned as ``(R, center, extents)``: ``R : (n, 3, 3)`` with the box axes as
*columns* (a rotation, det = +1), ``center : (n, 3)`` and full side lengths ``extents : (n, 3)``.
"""

from __future__ import annotations

import itertools

import numpy as np

from starforge.geometry.frames import perpendicular_basis
from starforge.tol import tol

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n[..., 0] > tol.zero
    return v / np.where(n > tol.zero, n, 1.0), ok


def _box_from_axes(P: np.ndarray, A: np.ndarray):
    """Extents of point sets in candidate frames.

    P : (n, k, 3); A : (n, m, 3, 3) with axes as rows.  Returns lo, hi : (n, m, 3).
    """
    proj = np.einsum("nkj,nmaj->nmka", P, A)
    return proj.min(axis=2), proj.max(axis=2)


def _rows_to_result(P, A, lo, hi):
    ext = hi - lo
    c_local = 0.5 * (lo + hi)
    R = np.swapaxes(A, -1, -2)  # axes as columns
    center = np.einsum("nij,nj->ni", R, c_local)
    # make each frame right-handed
    flip = np.linalg.det(R) < 0
    R[flip, :, 2] *= -1
    return R, center, ext


def covariance_box(points: np.ndarray):
    """The paper's OBB: covariance eigenvectors as axes.

    Parameters
    ----------
    points : (k, 3) or (n, k, 3) float, mm

    Returns
    -------
    R : (3, 3) or (n, 3, 3)   axes as columns, det = +1
    center : (3,) or (n, 3)   box centre, mm
    extents : (3,) or (n, 3)  full side lengths along the columns of R, mm
    """
    P = np.asarray(points, dtype=float)
    single = P.ndim == 2
    P = P[None] if single else P
    X = P - P.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", X, X) / P.shape[1]
    _, vec = np.linalg.eigh(cov)  # columns = axes, ascending variance
    A = np.swapaxes(vec, -1, -2)[:, None]  # (n, 1, 3, 3) rows
    lo, hi = _box_from_axes(P, A)
    R, center, ext = _rows_to_result(P, A[:, 0], lo[:, 0], hi[:, 0])
    if single:
        return R[0], center[0], ext[0]
    return R, center, ext


def _hull_edges_faces(k: int):
    """Edges and faces to try for k points (all pairs / triples: exact for k = 4)."""
    edges = np.array(list(itertools.combinations(range(k), 2)), dtype=np.intp)
    faces = np.array(list(itertools.combinations(range(k), 3)), dtype=np.intp)
    return edges, faces


def _cross3(a, b) -> list:
    """Cross product of vectors given as three component arrays each (any broadcastable
    shapes), as ``np.cross`` takes it operation for operation (the same floats)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _family_frames(p: np.ndarray, q: np.ndarray, e2: np.ndarray, theta: np.ndarray):
    """Frames with n1 perpendicular to e1 (angle theta about e1, from its basis p, q of
    :func:`~starforge.geometry.frames.perpendicular_basis`) and n2 perpendicular to e2 and n1.

    p, q, e2 : (n, f, 3) unit; theta : (n, f, s).  Returns the three axes, each a list of its
    three components (n, f, s), and the ok mask (n, f, s).  Component arrays instead of
    (..., 3) vectors: the sums and products of ``np.cross`` and ``np.linalg.norm`` in the same
    order (the same floats), without their per-call overhead and strided temporaries; this
    loop runs once per refinement step.
    """
    c, s = np.cos(theta), np.sin(theta)
    n1 = [c * p[:, :, None, j] + s * q[:, :, None, j] for j in range(3)]
    m = _cross3([e2[:, :, None, j] for j in range(3)], n1)
    norm = np.sqrt((m[0] * m[0] + m[1] * m[1]) + m[2] * m[2])
    ok = norm > tol.zero
    d = np.where(ok, norm, 1.0)
    n2 = [x / d for x in m]
    return [n1, n2, _cross3(n1, n2)], ok


def _stack_frames(axes: list) -> np.ndarray:
    """Rows-as-axes frames (..., 3, 3) from :func:`_family_frames`' component lists."""
    return np.stack([np.stack(a, axis=-1) for a in axes], axis=-2)


def _box_volumes(X: list, axes: list) -> np.ndarray:
    """Volumes of the boxes of point sets along frames: (n, f, s).

    ``X``: the points' coordinates as three arrays (k, n, 1, 1), point first (:func:`_points_first`);
    ``axes``: three axes, each a list of three component arrays (n, f, s) (:func:`_family_frames`).
    Axis by axis on (k, n, f, s) arrays, reduced over the leading point axis (a reduction over
    a trailing axis of 4, or one einsum over (n, f, s, k, 3), is several times slower); the sums
    are taken in the order ``einsum`` takes them here ((x0 a0 + x2 a2) + x1 a1) and the product
    as ``np.prod`` does, so the volumes are the same floats (checked bit for bit)."""
    ext = []
    for a0, a1, a2 in axes:
        p = (X[0] * a0 + X[2] * a2) + X[1] * a1
        ext.append(p.max(axis=0) - p.min(axis=0))
    return ext[0] * ext[1] * ext[2]


def _points_first(P: np.ndarray) -> list:
    """Coordinates of point sets P (n, k, 3) as three arrays (k, n, 1, 1) for :func:`_box_volumes`."""
    return [np.ascontiguousarray(P[:, :, j].T)[:, :, None, None] for j in range(3)]


def min_volume_box(points: np.ndarray, samples: int = 24, refine: int = 40):
    """Minimum-volume oriented box of small point sets (exact in the face-flush case, refined otherwise).

    Parameters
    ----------
    points : (k, 3) or (n, k, 3) float, mm
        Small point sets (k = 4 for marker stars).
    samples : int
        Angular samples per edge-pair family before refinement.
    refine : int
        Golden-section iterations per family.

    Returns
    -------
    R : (3, 3) or (n, 3, 3)   axes as columns, det = +1
    center : (3,) or (n, 3)   box centre, mm
    extents : (3,) or (n, 3)  full side lengths, mm
    """
    P = np.asarray(points, dtype=float)
    single = P.ndim == 2
    P = P[None] if single else P
    n, k, _ = P.shape
    edges, faces = _hull_edges_faces(k)
    E, _ = _normalize(P[:, edges[:, 1]] - P[:, edges[:, 0]])  # (n, ne, 3)
    F, fok = _normalize(
        np.cross(P[:, faces[:, 1]] - P[:, faces[:, 0]], P[:, faces[:, 2]] - P[:, faces[:, 0]])
    )  # (n, nf, 3)

    # (a) a face flush with a hull face; the in-plane axis along a projected edge
    nf, ne = F.shape[1], E.shape[1]
    Fa = np.repeat(F, ne, axis=1)
    Ea = np.tile(E, (1, nf, 1))
    a2, ok2 = _normalize(Ea - np.sum(Ea * Fa, axis=-1, keepdims=True) * Fa)
    a3 = np.cross(Fa, a2)
    A_face = np.stack([Fa, a2, a3], axis=-2)  # (n, nf*ne, 3, 3)
    lo, hi = _box_from_axes(P, A_face)
    vol = np.prod(hi - lo, axis=-1)
    vol[~(ok2 & np.repeat(fok, ne, axis=1))] = np.inf
    best_i = vol.argmin(axis=1)
    best_vol = vol[np.arange(n), best_i]
    best_A = A_face[np.arange(n), best_i]

    # (b) two adjacent faces flush with edges e_i and e_j: sample theta, then golden-section refine
    pairs = np.array([(i, j) for i in range(ne) for j in range(i, ne)], dtype=np.intp)
    e1, e2 = E[:, pairs[:, 0]], E[:, pairs[:, 1]]
    bp, bq = perpendicular_basis(e1)  # the same for every angle: computed once
    X = _points_first(P)
    nfam = len(pairs)
    theta = np.broadcast_to(np.arange(samples) * (np.pi / samples), (n, nfam, samples))

    def volumes(th):
        axes, ok = _family_frames(bp, bq, e2, th)
        return np.where(ok, _box_volumes(X, axes), np.inf), axes

    v, _ = volumes(theta)
    j = v.argmin(axis=2)
    t0 = np.take_along_axis(theta, j[..., None], axis=2)[..., 0]
    h = np.pi / samples
    a, b = t0 - h, t0 + h
    x1 = b - _GOLDEN * (b - a)
    x2 = a + _GOLDEN * (b - a)
    f1 = volumes(x1[..., None])[0][..., 0]
    f2 = volumes(x2[..., None])[0][..., 0]
    for _ in range(refine):
        left = f1 < f2  # the minimum lies in [a, x2]
        a = np.where(left, a, x1)
        b = np.where(left, x2, b)
        nx1 = np.where(left, b - _GOLDEN * (b - a), x2)
        nx2 = np.where(left, x1, a + _GOLDEN * (b - a))
        fe = volumes(np.where(left, nx1, nx2)[..., None])[0][..., 0]
        f1, f2 = np.where(left, fe, f2), np.where(left, f1, fe)
        x1, x2 = nx1, nx2
    cand_t = np.concatenate([t0[..., None], x1[..., None], x2[..., None]], axis=2)
    vc, axes = volumes(cand_t)
    flat = vc.reshape(n, -1)
    fi = flat.argmin(axis=1)
    fam_vol = flat[np.arange(n), fi]
    fam_A = _stack_frames(axes).reshape(n, -1, 3, 3)[np.arange(n), fi]

    use_fam = fam_vol < best_vol
    best_A = np.where(use_fam[:, None, None], fam_A, best_A)
    lo, hi = _box_from_axes(P, best_A[:, None])
    R, center, ext = _rows_to_result(P, best_A, lo[:, 0], hi[:, 0])
    if single:
        return R[0], center[0], ext[0]
    return R, center, ext


def placement_transform(points: np.ndarray, R: np.ndarray, center: np.ndarray, extents: np.ndarray):
    """The paper's placement frame for one box (eq. 1-3).

    z along the longest box edge, y along the shortest, x completing a right-handed frame,
    origin at the centre of the bottom face (the box spans z in [0, longest]).  Remaining sign
    choices are fixed deterministically: the points' centroid lies in the lower half (z) and
    in y >= 0.

    Parameters
    ----------
    points : (k, 3) float, mm  (used only to fix the signs)
    R : (3, 3)  box axes as columns;  center : (3,);  extents : (3,) full sides, mm

    Returns
    -------
    T : (4, 4) float
        Homogeneous transform from the input frame to the placement frame (``OBB_T_0``).
    extents_xyz : (3,) float, mm
        Box sides along the placement x, y, z axes (middle, shortest, longest).
    """
    order = np.argsort(extents, kind="stable")  # shortest, middle, longest
    ny, nx, nz = R[:, order[0]], R[:, order[1]], R[:, order[2]]
    c = np.asarray(points, dtype=float).mean(axis=0)
    if np.dot(c - center, nz) > tol.length_mm:
        nz = -nz
    if np.dot(c - center, ny) < -tol.length_mm:
        ny = -ny
    nx = np.array(_cross3(ny, nz))  # right-handed: x = y cross z (np.cross's floats, less overhead)
    R_obb = np.stack([nx, ny, nz], axis=1)  # columns
    half_long = 0.5 * extents[order[2]]
    T = np.eye(4)
    T[:3, :3] = R_obb.T
    T[:3, 3] = -R_obb.T @ (center - half_long * nz)
    return T, np.array([extents[order[1]], extents[order[0]], extents[order[2]]])


def apply_transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) homogeneous transform to (..., 3) points."""
    P = np.asarray(points, dtype=float)
    return P @ T[:3, :3].T + T[:3, 3]
