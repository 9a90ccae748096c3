"""Does a small point set fit a box of given sides in some orientation?  Decided by
branch-and-bound over directions, sound always and complete up to a stated slack.

The question.  Points ``P`` (k, 3) and a limit ``l_1 <= l_2 <= l_3``: is there a rotation whose
axis-aligned box around the rotated points has sides ``<= l`` (sorted against sorted)?  That is
the same as an orthonormal right-handed frame ``(a_1, a_2, a_3)`` with ``w(a_k) <= l_k``, where
``w(a) = max_ij |(p_i - p_j) . a|`` is the width of the set along a.  (If the sorted sides fit,
the frame in sorted order does; the converse is immediate.)

The search is over the direction ``a_1`` of the shortest side only, up to sign (cube-map cells
on the faces +x, +y, +z); for each ``a_1`` the other two axes are found **exactly**:

*Inner problem.*  In the plane orthogonal to ``a_1`` with basis (u, v), put
``a_2 = cos(psi) u + sin(psi) v`` and ``a_3 = a_1 x a_2``.  For a pair vector d with in-plane
coordinates ``(x, y) = A (cos phi, sin phi)``, ``d . a_2 = A cos(psi - phi)`` and
``d . a_3 = A sin(phi - psi)``; ``|d . a_2| <= L`` allows ``psi - phi`` (mod pi) on the interval
``[acos(L/A), pi - acos(L/A)]``, ``|d . a_3| <= L`` on ``[-asin(L/A), asin(L/A)]``.  A non-empty
intersection of such sets is the whole circle or begins at one of these endpoints, so testing
``psi = 0`` and every endpoint decides the 1-D problem exactly (to ``1e-9`` mm of float noise).
The endpoints are computed algebraically (no trigonometry).

*Cells.*  A spherical square of angular radius theta (its centre-to-corner angle: it is convex,
so the corners are the farthest points) around ``a_1`` is

* **pruned** when no direction in it is thin enough: for each pair d at angle ``psi_d <= pi/2``
  (modulo sign) from ``a_1``, every direction in the cell has ``|d . a| >= |d| cos(min(psi_d +
  theta, pi/2))``, and the largest of these exceeds ``l_1``; or when the inner problem at the
  centre has no solution even with each pair's limits raised by
  ``s_d = sin(theta) |d . a_1| + (1 - cos(theta)) |d_perp|``.  Why that suffices: if a frame
  ``(a_1', a_2', a_3')`` with ``a_1'`` in the cell fits, let Q be the smallest rotation taking
  ``a_1`` to ``a_1'`` (angle <= theta, about an axis n orthogonal to both).  ``b = Q^T a_2'`` is
  orthogonal to ``a_1``, and ``b - a_2'`` only involves the component of ``a_2'`` along
  ``m' = Q (n x a_1)`` (``a_2'`` has none along ``a_1'``), giving
  ``|d . b - d . a_2'| <= sin(theta) |d . a_1| + (1 - cos(theta)) |d . m| <= s_d``; the same holds
  for ``a_3'``.  So ``(a_1, Q^T a_2', Q^T a_3')`` solves the relaxed inner problem.
* **pruned**, before those two tests, when the corners show that no direction in it is thin
  enough (:func:`corners_exclude`): the square on the cube face is the union of two triangles
  (cut along either diagonal), so every direction of the cell is ``q / |q|`` with q in a flat
  triangle ``conv(c_i, c_j, c_k)`` of its unit corners, and ``|q| <= 1``.  If some pair has
  ``d . c > l`` at the three corners of a triangle, then ``d . q > l`` and ``d . (q / |q|) >=
  d . q > l`` (likewise below ``-l``).  When each of the two triangles (of one of the two
  diagonal cuts) is excluded this way, with ``l = l_1 + slack`` (plus ``1e-9`` relative and
  ``1e-9`` mm of float noise), no direction in the cell is thin enough for ``lim + slack``.
  Widened by the slack, this test never prunes a cell that holds a centre the search would
  accept, nor one holding the centre of a cell the search leaves open at the smallest size
  (that centre fits ``lim + slack``: its width is within ``D theta <= slack`` of the cell's
  lower bound, and ``s_d <= |d| theta <= slack``).  So the search visits the same cells in the
  same order less whole subtrees that hold neither: the same outcome and the same frame, with
  less work (a set that ran into ``max_cells`` or the stack may now finish).
* **accepted** when ``a_1`` at its centre is thin enough and the exact inner problem has a
  solution: that frame is returned (sound; callers re-check it).  The relaxed problem above is
  tried first: its limits are the exact ones plus ``s_d >= 0``, so an angle that solves the
  exact problem solves it too, and the inner solver, exact up to its ``1e-9`` mm, finds one;
  without a relaxed solution the cell is pruned and the exact problem need not be tried.
  (The same cells, answers and frames as testing the exact problem first, with fewer calls:
  checked on the 398,234 finger-default sets that reach the search.)
* otherwise split into four.

*Completeness up to ``slack``.*  Refinement stops once ``D theta <= slack`` (D: the diameter).
If a frame fits with ``slack`` to spare in every side and its ``a_1'`` lies in such a cell, the
centre is thin enough (``w`` is D-Lipschitz) and the turned frame above fits exactly (``s_d <=
|d| theta <= slack``), so the cell is accepted.  A set whose cells are all pruned **provably does
not fit**; a set left with open cells at that size is **undecided**: it fits, if at all, with
less than ``slack`` to spare.  Families use only sets that fit; certified upper bounds count the
undecided ones too.

Before the search, the seven directions where the width of a tetrahedron has its local minima
(the four face normals and the three common normals of opposite edges) are tried as ``a_1``:
most sets that fit are accepted there.  Callers deciding many sets may run a quick no-fit
proof first (:func:`starforge.geometry.faces.face_table`, widened by the slack so that it
never rejects a set the search would leave undecided).

The kernel is compiled with numba (serial, GIL released; :func:`decide_fit` spreads sets over
threads, each set independent, so results do not depend on the thread count).
"""

from __future__ import annotations

import math

import numpy as np

from starforge.tol import tol

FIT, NO_FIT, UNDECIDED = 1, 0, -1

#: default completeness slack, mm
SLACK_MM = 0.01
#: cells a single set may use before it is reported undecided (a work cap, never a silent drop)
MAX_CELLS = 100_000
#: float noise of a length (mm) and a generic zero, frozen into the kernels as constants
_EPS = tol.length_mm
_ZERO = tol.zero


from starforge.runtime.kernels import numba  # noqa: E402  (compiled kernels; this module is imported only where fits are decided)

_jit = numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
#: the small kernels only ever called from other kernels: no Python wrapper and no cache entry
#: of their own (each is compiled into its callers, whose cache entries hold it; a warm run
#: loads those and compiles nothing).  A wrapper or a cache write costs a first run tens of
#: milliseconds per kernel.
_inner = numba.njit(nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)
#: the fit decision's per-set search and its corner test: called from Python only by tests (and
#: in the package only from kernels), so no cache entry of their own: a first run compiles them
#: into decide_range, whose entry holds them (entries of their own would cost a first run their writing)
_uncached = numba.njit(nogil=True, no_cfunc_wrapper=True)


# The kernels below pass floats, not array views, between functions in their inner loops:
# every array a compiled function receives or slices is reference-counted by numba's runtime
# with an atomic instruction, and with two threads on shared arrays those atomics took about
# half of the fit decision's time.  The arithmetic is the same, operation for operation.


#: rows of the per-pair table ``W`` (6, npair) of :func:`decide_ws`: |d|, the in-plane
#: coordinates (x, y) of d, the limits of the two other axes for d, and |d . a1|
_DN, _X, _Y, _L2, _L3, _PA = 0, 1, 2, 3, 4, 5


@_inner
def project(D, W, npair, a0, a1, a2):
    """The plane basis (u, v) orthogonal to a = (a0, a1, a2), returned as six floats, and the
    pair vectors' coordinates in it, written to ``W[_X]`` and ``W[_Y]``.  (The basis is worked
    out here, its one caller: a kernel of its own was one more to compile on a first run.)"""
    # u orthogonal to a (crossed with the least aligned axis), v = a x u
    ax, ay, az = abs(a0), abs(a1), abs(a2)
    if ax <= ay and ax <= az:
        u0, u1, u2 = 0.0, a2, -a1
    elif ay <= az:
        u0, u1, u2 = -a2, 0.0, a0
    else:
        u0, u1, u2 = a1, -a0, 0.0
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0 = u0 / nu
    u1 = u1 / nu
    u2 = u2 / nu
    v0, v1, v2 = a1 * u2 - a2 * u1, a2 * u0 - a0 * u2, a0 * u1 - a1 * u0
    for j in range(npair):
        W[_X, j] = D[j, 0] * u0 + D[j, 1] * u1 + D[j, 2] * u2
        W[_Y, j] = D[j, 0] * v0 + D[j, 1] * v1 + D[j, 2] * v2
    return u0, u1, u2, v0, v1, v2


@_inner
def _keeps(W, npair, c, s):
    """psi with (cos, sin) = (c, s) keeps every pair within its limits (1e-9 mm of noise)."""
    for i in range(npair):
        x, y = W[_X, i], W[_Y, i]
        if abs(x * c + y * s) > W[_L2, i] + _EPS or abs(y * c - x * s) > W[_L3, i] + _EPS:
            return False
    return True


@_inner
def _pair_candidates(W, npair, cf, sf, co, si, sign):
    """:func:`inner_xy`'s two candidates of one pair: psi = phi + t, then psi = phi - t
    (``sign`` 1) or its opposite phi + pi - t (``sign`` -1), with (cos t, sin t) = (co, si)."""
    c, s = cf * co - sf * si, sf * co + cf * si
    if _keeps(W, npair, c, s):
        return True, c, s
    c, s = cf * co + sf * si, sf * co - cf * si
    if sign < 0:
        c, s = -c, -s
    if _keeps(W, npair, c, s):
        return True, c, s
    return False, 0.0, 0.0


@_inner
def inner_xy(W, npair):
    """The exact inner problem on coordinates already projected (:func:`project`), with the
    limits ``W[_L2]``, ``W[_L3]``: (True, cos psi, sin psi) for the first candidate that
    solves it, else (False, 0, 0).  The candidates, in order: psi = 0, then for each pair
    psi = phi + alpha, phi + pi - alpha (when A > L2) and phi + beta, phi - beta (when
    A > L3); each must keep ``|x c + y s| <= L2 + 1e-9`` and ``|y c - x s| <= L3 + 1e-9``
    for every pair (:func:`_keeps`).  (Each pair's alpha and beta are worked out once for
    its two candidates.)"""
    if _keeps(W, npair, 1.0, 0.0):
        return True, 1.0, 0.0
    for j in range(npair):
        xj, yj = W[_X, j], W[_Y, j]
        A = math.sqrt(xj * xj + yj * yj)
        if A <= 1e-300:
            continue
        cf, sf = xj / A, yj / A
        if A > W[_L2, j]:
            ca = W[_L2, j] / A
            # psi = phi + alpha and psi = phi + pi - alpha
            ok, c, s = _pair_candidates(W, npair, cf, sf, ca, math.sqrt(max(0.0, 1.0 - ca * ca)), -1.0)
            if ok:
                return True, c, s
        if A > W[_L3, j]:
            sb = W[_L3, j] / A
            # psi = phi + beta and psi = phi - beta
            ok, c, s = _pair_candidates(W, npair, cf, sf, math.sqrt(max(0.0, 1.0 - sb * sb)), sb, 1.0)
            if ok:
                return True, c, s
    return False, 0.0, 0.0


@_inner
def unit3(f, s, t):
    """The unit direction of point (s, t) of cube face f (0: +x, 1: +y, 2: +z), as floats."""
    if f == 0:
        a0, a1, a2 = 1.0, s, t
    elif f == 1:
        a0, a1, a2 = t, 1.0, s
    else:
        a0, a1, a2 = s, t, 1.0
    n = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    return a0 / n, a1 / n, a2 / n


@_inner
def frame_rows(R, a0, a1, a2, u0, u1, u2, v0, v1, v2, c, s):
    """R's rows: a, b = cos psi u + sin psi v, a x b (``c, s`` = cos psi, sin psi)."""
    R[0, 0], R[0, 1], R[0, 2] = a0, a1, a2
    R[1, 0] = c * u0 + s * v0
    R[1, 1] = c * u1 + s * v1
    R[1, 2] = c * u2 + s * v2
    R[2, 0] = a1 * R[1, 2] - a2 * R[1, 1]
    R[2, 1] = a2 * R[1, 0] - a0 * R[1, 2]
    R[2, 2] = a0 * R[1, 1] - a1 * R[1, 0]


@_uncached
def corners_exclude(D, npair, Cn, l1w):
    """True when no direction of a cube-map cell is thin enough: ``|d . a| > l1w`` for some
    pair d at every direction a of the cell (proof in the module docstring).  ``Cn`` (4, 3): the
    cell's unit corners in the order (-,-), (-,+), (+,-), (+,+)."""
    # bit i of a mask: corner i is beyond the slab on that side; a triangle of corners is
    # excluded when one side of one slab holds all three of its corners
    t013 = t023 = t012 = t123 = False
    for j in range(npair):
        pos = 0
        neg = 0
        for i in range(4):
            g = D[j, 0] * Cn[i, 0] + D[j, 1] * Cn[i, 1] + D[j, 2] * Cn[i, 2]
            if g > l1w:
                pos |= 1 << i
            elif g < -l1w:
                neg |= 1 << i
        for m in (pos, neg):
            t013 = t013 or (m & 11) == 11
            t023 = t023 or (m & 13) == 13
            t012 = t012 or (m & 7) == 7
            t123 = t123 or (m & 14) == 14
        # the square is the union of triangles (0, 1, 3) and (0, 3, 2), and of (0, 1, 2) and
        # (1, 2, 3): once one cut is covered, the other pairs cannot change the answer
        if (t013 and t023) or (t012 and t123):
            return True
    return False


#: stack entries of the branch and bound (12 root cells + 3 per level below, deep enough for
#: any cell size reachable in double precision)
STACK = 64 + 3 * 64


def workspace_size(k: int) -> int:
    """Floats :func:`decide_ws` needs for a set of ``k`` points."""
    npair = k * (k - 1) // 2
    return 9 * npair + 30 + 3 * STACK


@_jit
def decide_one(P, lim, slack, start, max_cells, R, prune):
    k = P.shape[0]
    ws = np.empty(9 * (k * (k - 1) // 2) + 30 + 3 * STACK)
    iws = np.empty(STACK, np.int64)
    return decide_ws(P, lim, slack, start, max_cells, R, ws, iws, prune)


@_uncached
def decide_ws(P, lim, slack, start, max_cells, R, ws, iws, prune):
    """:func:`decide_one` with the working memory passed in (``ws``: ``workspace_size(k)``
    floats, ``iws``: ``STACK`` ints), so a caller deciding many sets allocates once."""
    k = P.shape[0]
    npair = k * (k - 1) // 2
    D = ws[: 3 * npair].reshape((npair, 3))
    o = 3 * npair
    W = ws[o : o + 6 * npair].reshape((6, npair))  # rows _DN, _X, _Y, _L2, _L3, _PA
    o += 6 * npair
    kid_w = ws[o + 14 : o + 18]
    Cn = ws[o + 18 : o + 30].reshape((4, 3))  # the cell's unit corners
    o += 30
    Ss = ws[o : o + STACK]
    St = ws[o + STACK : o + 2 * STACK]
    Sh = ws[o + 2 * STACK : o + 3 * STACK]
    Sf = iws
    q = 0
    diam = 0.0
    for i in range(k):
        for j in range(i + 1, k):
            for c in range(3):
                D[q, c] = P[j, c] - P[i, c]
            W[_DN, q] = math.sqrt(D[q, 0] * D[q, 0] + D[q, 1] * D[q, 1] + D[q, 2] * D[q, 2])
            diam = max(diam, W[_DN, q])
            q += 1
    # 1. the critical directions of a tetrahedron's width (face normals, opposite edges)
    if k == 4:
        for f in range(7):
            if f < 4:
                i0, i1, i2 = (
                    (0, 1, 2) if f == 0 else ((0, 1, 3) if f == 1 else ((0, 2, 3) if f == 2 else (1, 2, 3)))
                )
                j0, j1, j2, j3 = i0, i1, i0, i2
            elif f == 4:
                j0, j1, j2, j3 = 0, 1, 2, 3
            elif f == 5:
                j0, j1, j2, j3 = 0, 2, 1, 3
            else:
                j0, j1, j2, j3 = 0, 3, 1, 2
            # e1 = P[j1] - P[j0], e2 = P[j3] - P[j2], a1 = e1 x e2 (scalars: no temporaries)
            e10, e11, e12 = P[j1, 0] - P[j0, 0], P[j1, 1] - P[j0, 1], P[j1, 2] - P[j0, 2]
            e20, e21, e22 = P[j3, 0] - P[j2, 0], P[j3, 1] - P[j2, 1], P[j3, 2] - P[j2, 2]
            a0 = e11 * e22 - e12 * e21
            a1 = e12 * e20 - e10 * e22
            a2 = e10 * e21 - e11 * e20
            nn = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if nn <= _ZERO:
                continue
            a0, a1, a2 = a0 / nn, a1 / nn, a2 / nn
            # accept a as the shortest axis: thin enough, and the exact inner problem solved
            w1 = 0.0
            for j in range(npair):
                w1 = max(w1, abs(D[j, 0] * a0 + D[j, 1] * a1 + D[j, 2] * a2))
            if w1 > lim[0] + _EPS:
                continue
            for j in range(npair):
                W[_L2, j] = lim[1]
                W[_L3, j] = lim[2]
            u0, u1, u2, v0, v1, v2 = project(D, W, npair, a0, a1, a2)
            ok, cc, sc = inner_xy(W, npair)
            if ok:
                frame_rows(R, a0, a1, a2, u0, u1, u2, v0, v1, v2, cc, sc)
                return 1, 7
    theta_min = slack / max(diam, _ZERO)
    l1w = (lim[0] + slack) * (1.0 + _EPS) + _EPS
    # 2. branch and bound over cube-map cells, depth first, best child first
    cap = STACK
    top = 0
    n0 = 2**start
    h0 = 1.0 / n0
    for f in range(3):
        for i in range(n0):
            for j in range(n0):
                Sf[top] = f
                Ss[top] = -1.0 + h0 * (2 * i + 1)
                St[top] = -1.0 + h0 * (2 * j + 1)
                Sh[top] = h0
                top += 1
    cells = 7
    open_small = False
    order = np.empty(4, np.int64)
    kid_s = np.empty(4)
    kid_t = np.empty(4)
    while top > 0:
        top -= 1
        f, s, t, h = Sf[top], Ss[top], St[top], Sh[top]
        cells += 1
        if cells > max_cells:
            return -1, cells
        a10, a11, a12 = unit3(f, s, t)
        cosmin = 1.0
        c = 0
        for dx in (-1.0, 1.0):
            for dy in (-1.0, 1.0):
                c0, c1, c2 = unit3(f, s + dx * h, t + dy * h)
                Cn[c, 0], Cn[c, 1], Cn[c, 2] = c0, c1, c2
                cosmin = min(cosmin, a10 * c0 + a11 * c1 + a12 * c2)
                c += 1
        if prune and corners_exclude(D, npair, Cn, l1w):
            continue
        theta = math.acos(max(-1.0, min(1.0, cosmin)))
        ct, st = math.cos(theta), math.sin(theta)
        # axis 1: lower bound of the width over the cell
        low = 0.0
        w1 = 0.0
        for j in range(npair):
            p = abs(D[j, 0] * a10 + D[j, 1] * a11 + D[j, 2] * a12)
            W[_PA, j] = p
            w1 = max(w1, p)
            dnj = W[_DN, j]
            cp = p / dnj if dnj > 0 else 0.0
            sp = math.sqrt(max(0.0, 1.0 - cp * cp))
            # |d| cos(psi + theta), clipped at 0 when psi + theta >= pi/2
            val = dnj * (cp * ct - sp * st)
            if cp * ct - sp * st > 0 and val > low:
                low = val
        if low > lim[0]:
            continue
        # the relaxed inner problem first: without a solution, the exact one (smaller limits)
        # has none either, and the centre cannot be accepted
        for j in range(npair):
            along = W[_PA, j]
            dnj = W[_DN, j]
            perp = math.sqrt(max(0.0, dnj * dnj - along * along))
            sj = st * along + (1.0 - ct) * perp
            W[_L2, j] = lim[1] + sj
            W[_L3, j] = lim[2] + sj
        u0, u1, u2, v0, v1, v2 = project(D, W, npair, a10, a11, a12)
        if not inner_xy(W, npair)[0]:
            continue
        # accept (as at the critical directions), with the widths and the projection reused
        if w1 <= lim[0] + _EPS:
            for j in range(npair):
                W[_L2, j] = lim[1]
                W[_L3, j] = lim[2]
            ok, cc, sc = inner_xy(W, npair)
            if ok:
                frame_rows(R, a10, a11, a12, u0, u1, u2, v0, v1, v2, cc, sc)
                return 1, cells
        if theta <= theta_min:
            open_small = True
            continue
        hh = h / 2
        for c in range(4):
            kid_s[c] = s + (-hh if c < 2 else hh)
            kid_t[c] = t + (-hh if c % 2 == 0 else hh)
            k0, k1, k2 = unit3(f, kid_s[c], kid_t[c])
            w = 0.0
            for j in range(npair):
                w = max(w, abs(D[j, 0] * k0 + D[j, 1] * k1 + D[j, 2] * k2))
            kid_w[c] = -w
        # push the thinnest last so it is explored first: a stable insertion sort of -width
        # (the order np.argsort gives on 4 values), without allocating
        for c in range(4):
            order[c] = c
        for c in range(1, 4):
            cur = order[c]
            b = c - 1
            while b >= 0 and kid_w[order[b]] > kid_w[cur]:
                order[b + 1] = order[b]
                b -= 1
            order[b + 1] = cur
        if top + 4 > cap:
            return -1, cells
        for c in order:
            Sf[top] = f
            Ss[top] = kid_s[c]
            St[top] = kid_t[c]
            Sh[top] = hh
            top += 1
    return (-1 if open_small else 0), cells


@_jit
def decide_range(P, lim, slack, start, max_cells, status, R, work, i0, i1, prune):
    """:func:`decide_one` for sets i0..i1-1 (serial; callers spread ranges over threads, the GIL
    is released), with the working memory allocated once (``prune``: 1 with
    :func:`corners_exclude`, 0 without).  The one compiled entry to the fit
    decision: :func:`decide_fit` and the enumeration (:mod:`starforge.stars.enumerate`) both
    run it, so its code is compiled (and cached) once.  Not ``parallel=True``: numba's parallel
    compile costs seconds on a cold cache."""
    k = P.shape[1]
    ws = np.empty(9 * (k * (k - 1) // 2) + 30 + 3 * STACK)
    iws = np.empty(STACK, np.int64)
    # this thread's own copies of the limit, the points and the frame: views of the arrays the
    # threads share would have their common reference count updated atomically by every thread
    lim_t = np.empty(3)
    lim_t[0], lim_t[1], lim_t[2] = lim[0], lim[1], lim[2]
    Pt = np.empty((k, 3))
    Rt = np.empty((3, 3))
    for i in range(i0, i1):
        for a in range(k):
            for c in range(3):
                Pt[a, c] = P[i, a, c]
        for a in range(3):
            for c in range(3):
                Rt[a, c] = R[i, a, c]
        st, c = decide_ws(Pt, lim_t, slack, start, max_cells, Rt, ws, iws, prune)
        for a in range(3):
            for b in range(3):
                R[i, a, b] = Rt[a, b]
        status[i] = st
        work[i] = c


#: sets per thread task of :func:`decide_fit` (up to this many, one thread does it all)
CHUNK = 256


def decide_all(P, lim, slack, start, max_cells, status, R, work, threads=None, prune=True) -> None:
    """Every set, over up to ``threads`` threads (default: every core; each set is independent,
    so the result does not depend on the thread count or the chunking).  ``prune``: with the
    corner test (:func:`corners_exclude`; the outcome and frames are the same either way)."""
    from starforge.runtime.threads import over_ranges

    flag = 1 if prune else 0

    def run(i0, i1):
        decide_range(P, lim, slack, start, max_cells, status, R, work, i0, i1, flag)

    over_ranges(run, len(P), CHUNK, threads)


def fits_limit(ext, limit) -> np.ndarray:
    """Box sides (..., 3) within the limit (3,), both compared sorted (float noise allowed:
    1e-9 relative and 1e-9 mm)."""
    ext = np.asarray(ext, dtype=float)
    a, b, c = ext[..., 0], ext[..., 1], ext[..., 2]
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    mid = a + b + c - lo - hi
    lim = np.sort(np.asarray(limit, dtype=float)) * (1 + _EPS) + _EPS
    return (lo <= lim[0]) & (mid <= lim[1]) & (hi <= lim[2])


def decide_fit(
    points, limit, slack: float = SLACK_MM, start: int = 1, max_cells: int = MAX_CELLS, prune: bool = True
):
    """Decide, for each point set, whether some rotation fits it in the box ``limit``.

    Parameters
    ----------
    points : (n, k, 3) float
        Point sets (here: sphere centres of stars), mm; k >= 2.
    limit : (3,) float
        Box sides the points' box must fit, mm (any order; sorted here).
    slack : float
        Completeness slack, mm (see the module docstring).
    max_cells : int
        Work cap per set; past it a set is reported undecided.
    prune : bool
        Prune cells with :func:`corners_exclude` too (default).  The outcome and the frame
        returned are the same without it (the plain search, kept for tests); only the work
        differs.

    Returns
    -------
    status : (n,) int8
        :data:`FIT`, :data:`NO_FIT` or :data:`UNDECIDED`.
    R : (n, 3, 3) float
        For FIT rows, a proper rotation whose rows are the box axes matched to the sorted limit:
        ``points @ R.T`` has extents ``<= sorted(limit)`` column by column.  NaN elsewhere.
    cells : (n,) int
        Directions evaluated per set (the work done).
    """
    P = np.ascontiguousarray(points, dtype=float)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[1] < 2:
        raise ValueError(f"points must be (n, k >= 2, 3), got shape {P.shape}")
    lim = np.sort(np.asarray(limit, dtype=float))
    if not (lim.shape == (3,) and np.isfinite(lim).all() and lim[0] >= 0):
        raise ValueError(f"limit must be 3 finite sizes >= 0, got {limit!r}")
    if not slack > 0:
        raise ValueError(f"slack must be > 0, got {slack}")
    n = len(P)
    status = np.zeros(n, dtype=np.int8)
    R = np.full((n, 3, 3), np.nan)
    work = np.zeros(n, dtype=np.int64)
    if n:
        decide_all(P, lim, float(slack), int(start), int(max_cells), status, R, work, prune=prune)
        R[status != FIT] = np.nan
    return status, R, work


