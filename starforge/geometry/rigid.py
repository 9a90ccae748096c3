"""Rigid fits and their accuracy: Kabsch, and the expected errors of a fitted marker body.

Accuracy under isotropic Gaussian marker noise (sigma per axis, FLE^2 = 3 sigma^2), first
order (Fitzpatrick, West & Maurer 1998, *Predicting error in rigid-body point-based
registration*, IEEE TMI 17(5)):

    TRE^2(r) ~ FLE^2 / N * (1 + 1/3 * sum_k d_k^2 / f_k^2)

N markers, d_k the distance of the target r from the k-th principal axis of the marker set
(through its centroid), f_k the RMS distance of the markers from that axis.  The rotation
estimate's covariance is sigma^2 M^-1 with M = sum_i (|p_i|^2 I - p_i p_i^T) the markers'
inertia tensor about their centroid, so the RMS rotation error is sigma * sqrt(trace M^-1)
(radians).  Both are checked against a Monte Carlo Kabsch fit in the tests.

Every function takes one body ``(n, 3)`` or a batch ``(s, n, 3)``; lengths in any unit
(mm for stars), results in the same unit (angles in degrees).  NaN rows are hidden markers.
"""

from __future__ import annotations

import numpy as np

from starforge.spec import non_negative


def kabsch(model: np.ndarray, observed: np.ndarray, weight: np.ndarray | None = None, reflect: bool = False):
    """Least-squares rigid motion taking ``model`` onto ``observed``, batched.

    Parameters
    ----------
    model, observed : (H, k, 3) float
        Corresponding points; rows with weight 0 are ignored (they may be NaN).
    weight : (H, k) float or None
        0/1 (or positive) weights; None weighs every point 1.
    reflect : bool
        Allow an improper rotation (a mirror) when it fits better.

    Returns
    -------
    R : (H, 3, 3) float
        Proper rotations unless ``reflect``.
    t : (H, 3) float
        Translations, so that ``observed ~ model @ R.T + t``.
    """
    model = np.asarray(model, dtype=float)
    observed = np.asarray(observed, dtype=float)
    if weight is None:
        weight = np.ones(model.shape[:2])
    w = np.asarray(weight, dtype=float)[..., None]
    m = np.where(w > 0, model, 0.0)
    o = np.where(w > 0, observed, 0.0)
    ws = w.sum(axis=1)
    mc = (m * w).sum(axis=1) / ws
    oc = (o * w).sum(axis=1) / ws
    X = (m - mc[:, None]) * w
    Y = (o - oc[:, None]) * w
    Hm = np.einsum("hki,hkj->hij", X, Y)
    U, _, Vt = np.linalg.svd(Hm)
    V = np.swapaxes(Vt, 1, 2)
    Ut = np.swapaxes(U, 1, 2)
    if not reflect:
        d = np.sign(np.linalg.det(V @ Ut))
        d[d == 0] = 1.0
        V = V.copy()
        V[:, :, 2] *= d[:, None]
    R = V @ Ut
    t = oc - np.einsum("hij,hj->hi", R, mc)
    return R, t


def default_tip_mm(limit_mm) -> np.ndarray:
    """The default target point of a star, in its placement frame (mm).

    On the star's long axis (placement z), one limit length below the bottom face of the box,
    where the mount is: the tip of a tool as long again as the star, or a joint under a
    finger star.  ``limit_mm`` is the size limit (any order); the long side sets the distance.
    """
    return np.array([0.0, 0.0, -float(max(limit_mm))])


def fle_from_sigma(sigma: float) -> float:
    """RMS 3D localisation error for isotropic noise of ``sigma`` per axis."""
    return float(np.sqrt(3.0) * non_negative("noise", sigma))


def _batch(points) -> tuple[np.ndarray, bool]:
    P = np.asarray(points, dtype=float)
    single = P.ndim == 2
    if single:
        P = P[None]
    if P.ndim != 3 or P.shape[2] != 3:
        raise ValueError(f"points must be (n, 3) or (s, n, 3), got shape {P.shape}")
    return P, single


def _inertia(P: np.ndarray):
    """Centroids (s, 3), marker counts (s,) and inertia tensors (s, 3, 3) of the visible rows."""
    vis = np.isfinite(P).all(axis=2)
    n = vis.sum(axis=1)
    Z = np.where(vis[..., None], P, 0.0)
    c = Z.sum(axis=1) / np.maximum(n, 1)[:, None]
    X = np.where(vis[..., None], P - c[:, None], 0.0)
    r2 = (X * X).sum(axis=2).sum(axis=1)
    M = r2[:, None, None] * np.eye(3) - np.einsum("ski,skj->sij", X, X)
    return c, n, M


def _inverse_or_inf(M: np.ndarray, n: np.ndarray) -> np.ndarray:
    """M^-1 per body; inf where fewer than 3 markers or they are (nearly) collinear."""
    w = np.linalg.eigvalsh(M)
    scale = np.maximum(w[:, -1], np.finfo(float).tiny)
    ok = (n >= 3) & (w[:, 0] > 1e-12 * scale)
    inv = np.full_like(M, np.inf)
    if ok.any():
        inv[ok] = np.linalg.inv(M[ok])
    return inv


def rotation_error_deg(points, sigma: float) -> np.ndarray | float:
    """Expected RMS rotation error of a Kabsch fit, degrees.

    points : (n, 3) or (s, n, 3); NaN rows are hidden markers.  sigma : noise per axis.
    """
    P, single = _batch(points)
    _, n, M = _inertia(P)
    inv = _inverse_or_inf(M, n)
    out = np.degrees(sigma * np.sqrt(np.trace(inv, axis1=1, axis2=2)))
    return float(out[0]) if single else out


def tre_rms(points, target, fle: float) -> np.ndarray | float:
    """Expected RMS target registration error at ``target``.

    points : (n, 3) or (s, n, 3) (NaN rows hidden); target : (3,) or (s, 3), same frame;
    fle : RMS 3D marker localisation error (:func:`fle_from_sigma`).
    """
    P, single = _batch(points)
    r = np.broadcast_to(np.asarray(target, dtype=float), (len(P), 3))
    c, n, M = _inertia(P)
    inv = _inverse_or_inf(M, n)
    y = r - c
    # E|theta x y|^2 with cov(theta) = sigma^2 M^-1 and sigma^2 = FLE^2 / 3:
    # sigma^2 * (|y|^2 tr(M^-1) - y^T M^-1 y)
    tr = np.trace(inv, axis1=1, axis2=2)
    with np.errstate(invalid="ignore"):
        rot = (y * y).sum(axis=1) * tr - np.einsum("si,sij,sj->s", y, inv, y)
        rot = np.where(np.isfinite(tr), rot, np.inf)
    out = np.sqrt(fle**2 / np.maximum(n, 1) + fle**2 / 3.0 * rot)
    return float(out[0]) if single else out


def tre_hidden(points, target, fle: float) -> np.ndarray:
    """TRE with each marker hidden in turn: (n,) for one body, (s, n) for a batch."""
    P, single = _batch(points)
    out = np.empty(P.shape[:2])
    for i in range(P.shape[1]):
        Q = P.copy()
        Q[:, i] = np.nan
        out[:, i] = tre_rms(Q, target, fle)
    return out[0] if single else out


def rotation_error_hidden_deg(points, sigma: float) -> np.ndarray:
    """Rotation error with each marker hidden in turn: (n,) or (s, n), degrees."""
    P, single = _batch(points)
    out = np.empty(P.shape[:2])
    for i in range(P.shape[1]):
        Q = P.copy()
        Q[:, i] = np.nan
        out[:, i] = rotation_error_deg(Q, sigma)
    return out[0] if single else out


def simulate_fit_errors(points, target, sigma: float, n: int, rng: np.random.Generator):
    """Monte Carlo check of the predictions: fit ``n`` noisy copies of one body back to it.

    Returns (RMS TRE at ``target``, RMS rotation angle in degrees).  NaN rows are hidden.
    """
    P = np.asarray(points, dtype=float)
    vis = np.isfinite(P).all(axis=1)
    P = P[vis]
    r = np.asarray(target, dtype=float).reshape(3)
    noisy = P[None] + rng.normal(0.0, sigma, size=(n, *P.shape))
    R, t = kabsch(np.broadcast_to(P, noisy.shape), noisy)
    err = np.einsum("hij,j->hi", R, r) + t - r
    cosang = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    ang = np.degrees(np.arccos(cosang))
    return float(np.sqrt((err**2).sum(axis=1).mean())), float(np.sqrt((ang**2).mean()))
