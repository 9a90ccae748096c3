"""Symmetric 3 x 3 eigenvalues in closed form (numba kernels), and the spread of a point set
across its best-fit line from running sums, the quantity a tracker needs to tell a triangle from
a line.

Closed form: Smith (1961), "Eigenvalues of a symmetric 3 x 3 matrix", Comm. ACM 4(4), 168.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.runtime.kernels import numba


@numba.njit(cache=True, nogil=True, inline="always")
def _mean_and_spread(a, b, c, d, e, f):
    """Smith's ``q`` (the mean eigenvalue) and ``p`` (the eigenvalues' spread about it) of
    [[a, d, f], [d, b, e], [f, e, c]]."""
    q = (a + b + c) / 3
    p1 = d * d + e * e + f * f
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2 * p1
    return q, math.sqrt(p2 / 6)


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def sym3_eigvals(a, b, c, d, e, f):
    """Ascending eigenvalues of [[a, d, f], [d, b, e], [f, e, c]]."""
    q, p = _mean_and_spread(a, b, c, d, e, f)
    if p <= 0:
        return q, q, q
    A, B, C = (a - q) / p, (b - q) / p, (c - q) / p
    D, E, F = d / p, e / p, f / p
    detB = A * (B * C - E * E) - D * (D * C - E * F) + F * (D * E - B * F)
    phi = math.acos(min(1.0, max(-1.0, detB / 2))) / 3
    l3 = q + 2 * p * math.cos(phi)
    l1 = q + 2 * p * math.cos(phi + 2 * math.pi / 3)
    return l1, 3 * q - l1 - l3, l3


@numba.njit(cache=True, nogil=True, inline="always")
def _covariance(n, x, y, z, xx, yy, zz, xy, yz, xz):
    """The covariance entries (xx, yy, zz, xy, yz, xz) of ``n`` > 0 points from their sums."""
    mx, my, mz = x / n, y / n, z / n
    return xx / n - mx * mx, yy / n - my * my, zz / n - mz * mz, xy / n - mx * my, yz / n - my * mz, xz / n - mx * mz


@numba.njit(cache=True, nogil=True)
def line_spread2(n, x, y, z, xx, yy, zz, xy, yz, xz):
    """Mean squared distance of ``n`` points from their best-fit line, from the sums of their
    coordinates (x, y, z) and of their products (xx, ..., xz): the covariance's trace minus its
    largest eigenvalue (>= 0)."""
    if n <= 0:
        return 0.0
    cxx, cyy, czz, cxy, cyz, cxz = _covariance(n, x, y, z, xx, yy, zz, xy, yz, xz)
    _, _, top = sym3_eigvals(cxx, cyy, czz, cxy, cyz, cxz)
    return max(cxx + cyy + czz - top, 0.0)


@numba.njit(cache=True, nogil=True)
def line_spread2_at_least(n, x, y, z, xx, yy, zz, xy, yz, xz, limit):
    """``line_spread2(n, ...) >= limit``, the same answer bit for bit, mostly without its
    arccosine and cosine.

    :func:`sym3_eigvals` returns the largest eigenvalue as ``q + (2 p) cos(phi)`` with
    ``0 <= phi <= pi / 3``, so ``q <= top <= q + 2 p`` holds for the rounded values too (a
    rounded product or sum never crosses a bound its exact value respects, and 0 < cos(phi) <= 1):
    the spread lies between ``trace - (q + 2 p)`` and ``trace - q``, computed with the same
    operations.  Only where ``limit`` falls between the two is the eigenvalue computed."""
    if n <= 0:
        return 0.0 >= limit
    a, b, c, d, e, f = _covariance(n, x, y, z, xx, yy, zz, xy, yz, xz)
    trace = a + b + c
    q, p = _mean_and_spread(a, b, c, d, e, f)
    if max(trace - q, 0.0) < limit:
        return False
    if max(trace - (q + 2 * p), 0.0) >= limit:
        return True
    return line_spread2(n, x, y, z, xx, yy, zz, xy, yz, xz) >= limit


@numba.njit(cache=True, nogil=True)
def line_spread2_many(cnt, s1, s2):
    """(m,) :func:`line_spread2` of m point sets given their counts (m,), coordinate sums (m, 3)
    and product sums (m, 6: xx, yy, zz, xy, yz, xz)."""
    out = np.empty(cnt.shape[0])
    for i in range(cnt.shape[0]):
        out[i] = line_spread2(
            cnt[i], s1[i, 0], s1[i, 1], s1[i, 2], s2[i, 0], s2[i, 1], s2[i, 2], s2[i, 3], s2[i, 4], s2[i, 5]
        )
    return out



@numba.njit(cache=True, nogil=True)
def line_spread2_at_least_many(cnt, s1, s2, limit):
    """(m,) bool :func:`line_spread2_at_least` of m point sets (counts, sums as in
    :func:`line_spread2_many`)."""
    out = np.empty(cnt.shape[0], dtype=np.bool_)
    for i in range(cnt.shape[0]):
        out[i] = line_spread2_at_least(
            cnt[i], s1[i, 0], s1[i, 1], s1[i, 2], s2[i, 0], s2[i, 1], s2[i, 2], s2[i, 3], s2[i, 4], s2[i, 5], limit
        )
    return out

def moments(x: np.ndarray) -> np.ndarray:
    """(n, 6) products xx, yy, zz, xy, yz, xz of points (n, 3), the order the kernels take."""
    x = np.asarray(x, dtype=float)
    return np.column_stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, x[:, 0] * x[:, 1], x[:, 1] * x[:, 2], x[:, 0] * x[:, 2]])
