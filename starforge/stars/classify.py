"""The compiled classification of labelled candidates, the enumeration's inner loop.

Each admissible 6-subset of the edge pool is put on the tetrahedron in its 30 labellings, and
each labelled candidate gets an outcome code (:data:`STAGES`): realisable, deep enough, the
necessary fit conditions, then the fit decision (the face table's quick no-fit proof, then the
search) or the paper's covariance box; see :mod:`starforge.stars.enumerate` for the pipeline.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.geometry.faces import face_table
from starforge.geometry.fit import SLACK_MM
from starforge.geometry.sym3 import sym3_eigvals
from starforge.geometry.tetra import canonical_assignments
from starforge.runtime.kernels import numba
from starforge.stars.spec import StarSpec
from starforge.tol import tol

#: outcome codes per labelled candidate (int8)
UNREALISABLE, TOO_THIN, TOO_WIDE, KY_FAN, NO_FIT, UNDECIDED, FIT, NECESSARY_OK = 0, 1, 2, 3, 4, 5, 6, 7
STAGES = ("unrealisable", "too_thin", "too_wide", "ky_fan", "no_fit", "undecided", "fit")
#: subsets per compiled batch (bounds the working memory: 30 codes + 30 volumes each)
BATCH_SUBSETS = 1 << 17
#: float noise of a length (mm) and a generic zero, frozen into the kernels as constants
_EPS = tol.length_mm
_ZERO = tol.zero


def assignment_table() -> np.ndarray:
    """The 30 labellings (:func:`~starforge.geometry.tetra.canonical_assignments`, worked out
    once per process there) as int64, the kernels' type: a fresh array of 180 numbers."""
    return canonical_assignments().astype(np.int64)


def edge_pool(spec: StarSpec) -> np.ndarray:
    """The pool of edge lengths, mm: ``l_min + k * delta`` up to ``l_max``."""
    lo, _ = spec.pool_bounds_mm
    return lo + spec.delta_mm * np.arange(spec.pool_size)


@numba.njit(cache=True, no_cfunc_wrapper=True)
def subsets_from(n: int, m: int, start: np.ndarray, count: int) -> np.ndarray:
    """``count`` admissible 6-subsets of range(n) (elements >= m apart) in lexicographic order,
    starting from ``start`` (6,); the last row returned is followed by ``start`` updated in place."""
    out = np.empty((count, 6), dtype=np.int16)
    c = start.copy()
    got = 0
    while got < count:
        if c[0] < 0:
            break
        for j in range(6):
            out[got, j] = c[j]
        got += 1
        # next admissible combination: bump the rightmost element that can move
        i = 5
        while i >= 0 and c[i] >= n - 1 - (5 - i) * m:
            i -= 1
        if i < 0:
            c[0] = -1
            break
        c[i] += 1
        for j in range(i + 1, 6):
            c[j] = c[j - 1] + m
    for j in range(6):
        start[j] = c[j]
    return out[:got]


@numba.njit(nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)  # only classify_range calls it (its cache entry holds it)
def _width(L0, L1, L2, L3, L4, L5, vol6):
    """Tetrahedron width from lengths (u, U, v, V, w, W) and 6 x volume: the smallest of the four
    vertex-face heights and the three opposite-edge distances."""
    d01, d23, d12, d03, d02, d13 = L0 * L0, L1 * L1, L2 * L2, L3 * L3, L4 * L4, L5 * L5
    w = 1e300
    for a, b, c in ((d01, d12, d02), (d01, d13, d03), (d02, d23, d03), (d12, d23, d13)):
        area4sq = 4 * a * b - (a + b - c) ** 2  # (4 * area)^2 (Heron on squared sides)
        w = min(w, 2 * vol6 / math.sqrt(max(area4sq, _ZERO)))
    for dd, p1, p2 in (
        (0.5 * (d03 + d12 - d02 - d13), d01, d23),
        (0.5 * (d01 + d23 - d02 - d13), d12, d03),
        (0.5 * (d01 + d23 - d03 - d12), d02, d13),
    ):
        cross2 = p1 * p2 - dd * dd
        w = min(w, vol6 / math.sqrt(max(cross2, _ZERO)))
    return w


#: subsets per thread task of :func:`classify`
THREAD_SUBSETS = 2048


#: the empty face table: no face proof (mode 1, and pools past the table's size)
NO_FACES = np.zeros((0, 0, 0), dtype=np.int8)


#: face tables of this process (:func:`spec_faces`), by pool, tolerance steps and limit
_FACES: dict = {}


def spec_faces(spec: StarSpec, threads: int | None = None) -> np.ndarray:
    """The face table of ``spec``'s exact fit decision (:func:`~starforge.geometry.faces.face_table`
    of its pool, tolerance in pool steps, centre limit and :data:`SLACK_MM`); the empty table
    for ``box_method = "covariance"``.  Computed once per process and kept (the last four): on
    the finger box it costs 0.005 CPU s at the default ``delta_mm = 1.5``, 0.02 at 1.0 and 0.16
    at 0.5 (about n^3 / 6 triangles for n pool lengths), where an enumeration chunk, its own task
    (:func:`starforge.stars.enumerate.enumerate_chunk`), takes one to two.  A pure function of the spec, so results do not
    depend on where it was computed."""
    if spec.box_method != "exact":
        return NO_FACES
    pool = edge_pool(spec)
    limit = tuple(sorted(float(x) for x in spec.centre_limit_mm))
    key = (len(pool), float(pool[0]), float(spec.delta_mm), int(spec.grid_steps), limit)
    if key not in _FACES:
        while len(_FACES) >= 4:
            _FACES.pop(next(iter(_FACES)))
        _FACES[key] = face_table(pool, spec.grid_steps, limit, SLACK_MM, threads)
    return _FACES[key]


#: sets handed to the fit decision at once (bounds its working memory: points, rotations)
DECIDE_SETS = 1 << 16


def classify(
    subsets,
    assign,
    lo,
    step,
    lim,
    min_depth,
    slack,
    max_cells,
    mode,
    codes,
    volumes,
    threads=None,
    chunk=THREAD_SUBSETS,
    faces=None,
):
    """Outcome code and fitting-box volume of every labelled candidate of ``subsets`` (s, 6),
    written into ``codes`` (s, 30) int8 and ``volumes`` (s, 30), on up to ``threads`` threads
    (:func:`starforge.runtime.threads.over_ranges`; each candidate independent, so the result does not
    depend on the thread count).

    Two passes: the serial kernel :func:`classify_range` runs the necessary tests (and in mode 0 the
    quick no-fit proofs: the face table ``faces``, :func:`spec_faces` of the same spec, or None
    for none) over ranges of ``chunk`` subsets; the candidates left
    (``NECESSARY_OK``) then go, :data:`DECIDE_SETS` at a time, to the fit decision's one compiled
    entry (:func:`starforge.geometry.fit.decide_range`, shared with ``decide_fit``, so a first
    run compiles that code once).

    mode 0: the exact fit decision; mode 1: stop after the necessary tests (NECESSARY_OK).
    """
    first_pass(subsets, assign, lo, step, lim, min_depth, mode, codes, threads, chunk, faces)
    volumes[:] = np.nan
    if mode == 1:
        return
    left, status, vol = decide_left(subsets, assign, lo, step, lim, slack, max_cells, codes, threads)
    s, a = np.divmod(left, codes.shape[1])
    codes[s, a] = np.where(status == 1, FIT, np.where(status == 0, NO_FIT, UNDECIDED))
    fit = status == 1
    volumes[s[fit], a[fit]] = vol


def first_pass(
    subsets, assign, lo, step, lim, min_depth, mode, codes, threads=None, chunk=THREAD_SUBSETS, faces=None
):
    """The first pass of :func:`classify` (:func:`classify_range` over ranges of ``chunk`` subsets on
    up to ``threads`` threads): ``codes`` (s, 30) gets every code but the fit decision's, and
    ``NECESSARY_OK`` for the candidates left to it."""
    from starforge.runtime.threads import over_ranges

    if faces is None:
        faces = NO_FACES
    args = (subsets, assign, float(lo), float(step), lim, float(min_depth), int(mode), faces)

    def run(i0, i1):
        classify_range(*args, codes, i0, i1)

    over_ranges(run, len(subsets), chunk, threads)


def decide_left(subsets, assign, lo, step, lim, slack, max_cells, codes, threads=None):
    """The fit decision for the candidates the first pass left (``NECESSARY_OK`` in ``codes``),
    :data:`DECIDE_SETS` at a time.  Returns their flat positions in ``codes`` (row-major order),
    their status (:data:`~starforge.geometry.fit.FIT`, ``NO_FIT``, ``UNDECIDED``) and the box
    volumes of those that fit, in that order; ``codes`` is left as it is (the enumeration counts
    and gathers from these compact arrays instead of scanning ``codes`` again)."""
    from starforge.geometry.fit import decide_all

    left = np.flatnonzero(codes == NECESSARY_OK)
    status = np.zeros(len(left), dtype=np.int8)
    vols = []
    for b in range(0, len(left), DECIDE_SETS):
        s, a = np.divmod(left[b : b + DECIDE_SETS], codes.shape[1])
        L = float(lo) + float(step) * np.take_along_axis(subsets[s], assign[a], axis=1)
        P = _centres(L)
        st = status[b : b + DECIDE_SETS]
        R = np.zeros((len(P), 3, 3))  # rows of sets that do not fit stay 0 (finite)
        work = np.zeros(len(P), dtype=np.int64)
        decide_all(P, lim, float(slack), 1, int(max_cells), st, R, work, threads)
        vols.append(_box_volume(P, R)[st == 1])  # (cheaper than copying the fits out first)
    return left, status, np.concatenate(vols) if vols else np.zeros(0)


def _centres(L: np.ndarray) -> np.ndarray:
    """Sphere centres (n, 4, 3) of realisable stars from lengths (n, 6) (u, U, v, V, w, W), mm:
    the trilateration of :func:`classify_range`, operation for operation, so the floats are the
    ones its tests saw (A at the origin, B on +x, C in the xy-plane, D above it)."""
    u, U, v, V, w, W = np.ascontiguousarray(L.T)  # contiguous columns: the same floats, faster
    cx = (u * u + w * w - v * v) / (2 * u)
    cy = np.sqrt(w * w - cx * cx)
    dx = (u * u + V * V - W * W) / (2 * u)
    dy = (V * V - U * U + w * w - 2 * dx * cx) / (2 * cy)
    dz = np.sqrt(V * V - dx * dx - dy * dy)
    P = np.zeros((len(L), 4, 3))
    P[:, 1, 0] = u
    P[:, 2, 0], P[:, 2, 1] = cx, cy
    P[:, 3, 0], P[:, 3, 1], P[:, 3, 2] = dx, dy, dz
    return P


def _box_volume(P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Volume of the box of each star's centres (n, 4, 3), placed by :func:`_centres` (A at the
    origin, B on +x, C in the xy-plane), along the rows of R (n, 3, 3), mm^3.

    The same floats as the general formula (per axis, each point's ``r0 x + r1 y + r2 z`` left
    to right, the largest less the smallest, the three sides multiplied): the terms left out
    are products with coordinates that are exactly 0 (A's, B's y and z, C's z), which change no
    sum but the sign of a zero, and no side of a realisable star is 0.  Sums and products in a
    fixed order: the same floats whatever the batch."""
    u = P[:, 1, 0]
    cx, cy = P[:, 2, 0], P[:, 2, 1]
    dx, dy, dz = P[:, 3, 0], P[:, 3, 1], P[:, 3, 2]
    vol = None
    for k in range(3):
        r0, r1, r2 = R[:, k, 0], R[:, k, 1], R[:, k, 2]
        # point by point (a reduction over an axis of 4 is slow in numpy); A projects to 0
        pb, pc, pd = r0 * u, r0 * cx + r1 * cy, r0 * dx + r1 * dy + r2 * dz
        hi = np.maximum(np.maximum(np.maximum(pb, 0.0), pc), pd)
        lo = np.minimum(np.minimum(np.minimum(pb, 0.0), pc), pd)
        vol = hi - lo if vol is None else vol * (hi - lo)
    return vol


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)  # nogil: threads run it side by side; Ctrl-C is answered
def classify_range(subsets, assign, lo, step, lim, min_depth, mode, faces, codes, s0, s1):
    """The first pass of :func:`classify` for subsets ``s0 .. s1 - 1``: realisable, deep
    enough, narrow enough, Ky Fan, and in mode 0 the quick no-fit proof (a face in ``faces``,
    :func:`face_table`, when it is not empty); what is left is
    ``NECESSARY_OK`` (serial: numba's ``parallel=True`` costs seconds of compile on a first run)."""
    eps = _EPS
    # allocated once per range (rows of P that no star writes stay 0): an allocation costs
    # atomic updates of numba's runtime counters that the threads contend for
    P = np.zeros((4, 3))
    use_faces = mode == 0 and faces.shape[0] > 0
    Ls = np.empty(6)  # the subset's six lengths, worked out once for its 30 assignments
    for s in range(s0, s1):
        for j in range(6):
            Ls[j] = lo + step * subsets[s, j]
        for a in range(assign.shape[0]):
            u, U, v = Ls[assign[a, 0]], Ls[assign[a, 1]], Ls[assign[a, 2]]
            V, w, W = Ls[assign[a, 3]], Ls[assign[a, 4]], Ls[assign[a, 5]]
            cx = (u * u + w * w - v * v) / (2 * u)
            cy2 = w * w - cx * cx
            if cy2 <= _EPS:
                codes[s, a] = 0
                continue
            cy = math.sqrt(cy2)
            dx = (u * u + V * V - W * W) / (2 * u)
            dy = (V * V - U * U + w * w - 2 * dx * cx) / (2 * cy)
            dz2 = V * V - dx * dx - dy * dy
            if dz2 <= _EPS:
                codes[s, a] = 0
                continue
            dz = math.sqrt(dz2)
            width = _width(u, U, v, V, w, W, u * cy * dz)
            if width < min_depth - eps:
                codes[s, a] = 1
                continue
            if width > lim[0] + eps:
                codes[s, a] = 2
                continue
            # Ky Fan on the covariance (1/4 normalisation) of the four centres
            mx, my, mz = (u + cx + dx) / 4, (cy + dy) / 4, dz / 4
            P[1, 0] = u
            P[2, 0], P[2, 1] = cx, cy
            P[3, 0], P[3, 1], P[3, 2] = dx, dy, dz
            sxx = syy = szz = sxy = syz = sxz = 0.0
            for i in range(4):
                X, Y, Z = P[i, 0] - mx, P[i, 1] - my, P[i, 2] - mz
                sxx += X * X
                syy += Y * Y
                szz += Z * Z
                sxy += X * Y
                syz += Y * Z
                sxz += X * Z
            e1, e2, e3 = sym3_eigvals(sxx / 4, syy / 4, szz / 4, sxy / 4, syz / 4, sxz / 4)
            if (
                e1 > lim[0] ** 2 / 4 + eps
                or e1 + e2 > (lim[0] ** 2 + lim[1] ** 2) / 4 + eps
                or e1 + e2 + e3 > (lim[0] ** 2 + lim[1] ** 2 + lim[2] ** 2) / 4 + eps
            ):
                codes[s, a] = 3
                continue
            # a face that does not fit (faces ACD, BCD, ABD, ABC: the first two catch most)
            if use_faces and (
                faces[subsets[s, assign[a, 4]], subsets[s, assign[a, 3]], subsets[s, assign[a, 1]]]
                or faces[subsets[s, assign[a, 2]], subsets[s, assign[a, 5]], subsets[s, assign[a, 1]]]
                or faces[subsets[s, assign[a, 0]], subsets[s, assign[a, 3]], subsets[s, assign[a, 5]]]
                or faces[subsets[s, assign[a, 0]], subsets[s, assign[a, 2]], subsets[s, assign[a, 4]]]
            ):
                codes[s, a] = 4  # proven not to fit: a face does not fit
                continue
            codes[s, a] = 7


def covariance_fits(P: np.ndarray, limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's test: the covariance box fits (sorted against sorted).  Returns (fits, volume)."""
    from starforge.geometry.obb import covariance_box

    if not len(P):
        return np.zeros(0, dtype=bool), np.zeros(0)
    _, _, ext = covariance_box(P)
    e = np.sort(ext, axis=1)
    lim = np.sort(limit) * (1 + _EPS) + _EPS
    return (e <= lim).all(axis=1), np.prod(ext, axis=1)
