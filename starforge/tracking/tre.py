"""Expected target registration error (Fitzpatrick, West & Maurer 1998).

    TRE^2(r) ~ FLE^2 / N * (1 + 1/3 * sum_k d_k^2 / f_k^2)

N markers, FLE the RMS (3D) marker localisation error, d_k the distance of the target r from
the k-th principal axis of the marker set (through its centroid), f_k the RMS distance of the
markers from that axis.  With isotropic Gaussian noise of sigma per axis, FLE^2 = 3 sigma^2.
"""

from __future__ import annotations

import numpy as np

from starforge.spec import non_negative, require


def fle_from_sigma(sigma_mm: float) -> float:
    """RMS 3D localisation error for isotropic noise of ``sigma_mm`` per axis, mm."""
    return float(np.sqrt(3.0) * non_negative("noise", sigma_mm))


def tre_rms(points_mm: np.ndarray, target_mm, fle_mm: float) -> float:
    """Expected RMS TRE at ``target_mm`` (3,) for markers ``points_mm`` (N, 3), mm."""
    P = np.asarray(points_mm, dtype=float)
    require(P.ndim == 2 and P.shape[1] == 3 and len(P) >= 3, "points_mm must be (N >= 3, 3)")
    r = np.asarray(target_mm, dtype=float).reshape(3)
    c = P.mean(axis=0)
    X = P - c
    _, _, Vt = np.linalg.svd(X, full_matrices=False)  # rows: principal axes
    y = r - c
    total = 0.0
    for k in range(3):
        a = Vt[k]
        dk2 = float(y @ y - (y @ a) ** 2)  # squared distance of the target from axis k
        fk2 = float(np.mean((X * X).sum(axis=1) - (X @ a) ** 2))  # mean squared marker distance
        if fk2 <= 0:
            return float("inf")  # collinear markers: rotation about the line is undetermined
        total += dk2 / fk2
    return float(np.sqrt(fle_mm**2 / len(P) * (1.0 + total / 3.0)))


def tre_monte_carlo(points_mm, target_mm, sigma_mm: float, n: int, rng: np.random.Generator) -> float:
    """RMS TRE by simulation: fit noisy markers back to the model, measure the target's error."""
    from starforge.tracking.identify import kabsch

    P = np.asarray(points_mm, dtype=float)
    r = np.asarray(target_mm, dtype=float).reshape(3)
    noisy = P[None] + rng.normal(0.0, sigma_mm, size=(n, *P.shape))
    R, t = kabsch(np.broadcast_to(P, noisy.shape), noisy)
    err = np.einsum("hij,j->hi", R, r) + t - r
    return float(np.sqrt((err**2).sum(axis=1).mean()))
