"""A scanned prop's noise: how large it is, and a surface with it smoothed away.

A mesh from a 3D scanner carries noise of 0.05-0.2 mm on triangles about 1 mm across.  A base
7 mm across rests on such a surface as on a smooth one, but every test that reads the mesh
triangle by triangle (a base's contact within 0.3 mm of its plane, with the faces' normals
within 15 degrees of its own; sharp edges where two faces bend by 30 degrees) sees it as
rough all over: on a scanned bottle with 0.1 mm of noise no site seats a marker.

The noise is measured (:func:`surface_noise`) as the residual of a quadric fitted round a
sample of vertices by weighted least squares (a paraboloid over the local tangent plane, over
the vertices within :data:`RADIUS_EDGES` edges, weighted by a Gaussian of half that radius and
kept to those whose normals face the same way, so that the far side of a thin wall is not
taken for the near side).  A quadric follows a curved surface, so a finely tessellated CAD
body measures near zero (its vertices lie on the surface) while a scan measures about its
noise.  Above :data:`NOISE_M` and a share of the edges (:func:`noisy`) the surface is
smoothed (:func:`smooth_scan`): every vertex moves onto its own fitted quadric (a
moving-least-squares projection, :data:`ITERATIONS` times), which removes the noise and keeps the shape, its curvature included, to within a few
hundredths of a millimetre; a crease the scanner rounded stays rounded.  The faces are not
changed.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.geometry.sym3 import sym3_eigvals
from starforge.runtime.kernels import numba

#: a mesh is smoothed when its noise (RMS, m) is above NOISE_M, 10 micrometres (over ten times
#: what a finely tessellated CAD surface measures, well under a scanner's noise), and above
#: NOISE_SHARE of its median edge (a vertex 1 % of an edge off tilts its faces by about a
#: degree; a coarse CAD body whose quadrics fit its curves a little less well is left alone)
NOISE_M = 1e-5
NOISE_SHARE = 0.01
#: the neighbourhood: this many median edge lengths
RADIUS_EDGES = 4.0
#: at most this many nearest vertices within it
NEIGHBOURS = 60
#: a fit needs at least this many (a vertex with fewer, in a coarse region, is left)
MIN_NEIGHBOURS = 12
#: neighbours whose normals are more than about 60 degrees from the vertex's are left out
SAME_SIDE = 0.5
#: the noise is measured where the normals round a vertex stay within this (degrees) of the
#: plane fitted to them, but for FEATURE_SHARE of them: away from the edges and corners of a
#: CAD body, whose fit measures its shape, not noise (next to a right-angled edge about half of
#: them lean 45 degrees; noise of a fifth of an edge tilts a vertex's normal by up to about 30)
FEATURE_DEG = 40.0
FEATURE_SHARE = 0.1
#: vertices whose noise :func:`surface_noise` measures
NOISE_SAMPLES = 2000
#: projections :func:`smooth_scan` makes (a second takes the noise of a scanned bottle from
#: about a fifth of what it was to an eighth, and seats few more sites)
ITERATIONS = 1
#: vertices fitted at once (a chunk holds about 60 MB of work arrays)
_CHUNK = 20_000


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(v, 3) unit normals: the area-weighted sum of the normals of the faces round each vertex."""
    from starforge.meshfiles import face_cross

    cross = face_cross(vertices, faces)  # twice the area along the normal
    corner = np.asarray(faces, np.int64).ravel()
    out = np.column_stack([np.bincount(corner, np.repeat(cross[:, j], 3), minlength=len(vertices)) for j in range(3)])
    return out / np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]


#: the median edge is read off at most this many faces (every k-th)
EDGE_FACES = 50_000


def median_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The median length of the faces' edges (each shared edge counted twice; of every k-th
    face, at most :data:`EDGE_FACES`), m."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    f = f[:: max(1, len(f) // EDGE_FACES)]
    edges = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)
    return float(np.median(edges)) if edges.size else 0.0


def noisy(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    """``(noise, radius)``, m: the mesh's noise (:func:`surface_noise`) when it is to be
    smoothed (above :data:`NOISE_M` and :data:`NOISE_SHARE` of the median edge), else 0, and the
    fitting radius (:data:`RADIUS_EDGES` median edges) to smooth it with."""
    edge = median_edge(vertices, faces)
    noise = surface_noise(vertices, faces, RADIUS_EDGES * edge)
    return (noise if noise > max(NOISE_M, NOISE_SHARE * edge) else 0.0), RADIUS_EDGES * edge


def _fit(v: np.ndarray, normals: np.ndarray, idx: np.ndarray, radius: float, tree) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For the vertices ``idx``: where each lies on its fitted quadric (k, 3), the fit's
    weighted RMS residual (k,), m, whether it had :data:`MIN_NEIGHBOURS` to fit (k,), and
    whether its neighbourhood is free of features (k,): the neighbours' normals within
    :data:`FEATURE_DEG` of the fitted patch's (but for :data:`FEATURE_SHARE` of them), no edge
    or corner of a CAD body in reach."""
    idx = np.ascontiguousarray(idx, np.int64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    d, nb = tree.query(v[idx], k=min(NEIGHBOURS, len(v)), distance_upper_bound=radius)
    d = np.ascontiguousarray(np.asarray(d, float).reshape(len(idx), -1))
    nb = np.ascontiguousarray(np.where(np.isfinite(d), np.asarray(nb).reshape(len(idx), -1), 0).astype(np.int64))
    placed = np.empty((len(idx), 3))
    residual = np.zeros(len(idx))
    count = np.zeros(len(idx), np.int64)
    plain = np.ones(len(idx), np.bool_)
    _quadric_fits(v, normals, idx, nb, d, float(radius), SAME_SIDE, float(np.cos(np.radians(FEATURE_DEG))),
                  placed, residual, count, plain)  # fmt: skip
    return placed, residual, count >= MIN_NEIGHBOURS, plain


@numba.njit(cache=True, nogil=True, inline="always")
def _smallest_axis(a, b, c, d, e, f):
    """The unit eigenvector of the smallest eigenvalue of [[a, d, f], [d, b, e], [f, e, c]]
    (:func:`starforge.geometry.sym3.sym3_eigvals`): the largest cross product of two rows of
    the matrix less that eigenvalue (the rows span the plane square to it)."""
    low = sym3_eigvals(a, b, c, d, e, f)[0]
    r0 = (a - low, d, f)
    r1 = (d, b - low, e)
    r2 = (f, e, c - low)
    best, bx, by, bz = -1.0, 0.0, 0.0, 1.0
    for u, w in ((r0, r1), (r0, r2), (r1, r2)):
        x = u[1] * w[2] - u[2] * w[1]
        y = u[2] * w[0] - u[0] * w[2]
        z = u[0] * w[1] - u[1] * w[0]
        size = x * x + y * y + z * z
        if size > best:
            best, bx, by, bz = size, x, y, z
    size = math.sqrt(best) if best > 0.0 else 1.0
    return bx / size, by / size, bz / size


@numba.njit(cache=True, nogil=True, inline="always")
def _cholesky_solve(m, rhs, n):
    """Solve ``m x = rhs`` (n x n, symmetric positive definite) in place by Cholesky: ``rhs``
    holds x after; False when ``m`` is not positive definite (a degenerate neighbourhood)."""
    for j in range(n):
        s = m[j, j]
        for k in range(j):
            s -= m[j, k] * m[j, k]
        if s <= 0.0:
            return False
        m[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = m[i, j]
            for k in range(j):
                s -= m[i, k] * m[j, k]
            m[i, j] = s / m[j, j]
    for i in range(n):
        s = rhs[i]
        for k in range(i):
            s -= m[i, k] * rhs[k]
        rhs[i] = s / m[i, i]
    for i in range(n - 1, -1, -1):
        s = rhs[i]
        for k in range(i + 1, n):
            s -= m[k, i] * rhs[k]
        rhs[i] = s / m[i, i]
    return True


@numba.njit(cache=True, nogil=True)
def _quadric_fits(v, normals, idx, nb, d, radius, same_side, cos_feature, placed, residual, count, plain):
    """For each vertex ``idx[i]`` with neighbours ``nb[i]`` at distances ``d[i]`` (inf: none):
    the weighted quadric fit of :func:`_fit` (weights ``exp(-(d / (radius / 2))**2)`` over
    the neighbours facing within ``same_side`` (a cosine) of it; coordinates in units of
    ``radius``, so the normal equations are well scaled), into ``placed[i]``, ``residual[i]``
    and ``count[i]`` (the neighbours used); ``plain[i]`` false when more than
    :data:`FEATURE_SHARE` of them face farther than ``cos_feature`` from the fitted patch's
    normal (an edge or a corner in reach).  A vertex with fewer than 6 neighbours to fit, or a
    degenerate neighbourhood, stays where it is."""
    k = nb.shape[1]
    h = 0.5 * radius
    w = np.empty(k)
    loc = np.empty((k, 3))
    terms = np.empty(6)
    lhs = np.empty((6, 6))
    rhs = np.empty(6)
    for i in range(idx.shape[0]):
        c = idx[i]
        nx, ny, nz = normals[c, 0], normals[c, 1], normals[c, 2]
        placed[i, 0], placed[i, 1], placed[i, 2] = v[c, 0], v[c, 1], v[c, 2]
        total = mx = my = mz = 0.0
        used = 0
        for j in range(k):
            w[j] = 0.0
            if not np.isfinite(d[i, j]):
                continue
            o = nb[i, j]
            facing = normals[o, 0] * nx + normals[o, 1] * ny + normals[o, 2] * nz
            if facing < same_side:
                continue
            w[j] = math.exp(-((d[i, j] / h) ** 2))
            total += w[j]
            mx += w[j] * v[o, 0]
            my += w[j] * v[o, 1]
            mz += w[j] * v[o, 2]
            used += 1
        count[i] = used
        if used < 6 or total <= 0.0:
            continue
        mx, my, mz = mx / total, my / total, mz / total
        sxx = syy = szz = sxy = syz = sxz = 0.0
        for j in range(k):
            if w[j] == 0.0:
                continue
            o = nb[i, j]
            x, y, z = (v[o, 0] - mx) / radius, (v[o, 1] - my) / radius, (v[o, 2] - mz) / radius
            loc[j, 0], loc[j, 1], loc[j, 2] = x, y, z
            sxx += w[j] * x * x
            syy += w[j] * y * y
            szz += w[j] * z * z
            sxy += w[j] * x * y
            syz += w[j] * y * z
            sxz += w[j] * x * z
        ax, ay, az = _smallest_axis(sxx, syy, szz, sxy, syz, sxz)  # the patch's normal
        if ax * nx + ay * ny + az * nz < 0.0:
            ax, ay, az = -ax, -ay, -az
        off = 0
        for j in range(k):  # neighbours whose own normals leave the patch's: an edge in reach
            if w[j] != 0.0:
                o = nb[i, j]
                off += normals[o, 0] * ax + normals[o, 1] * ay + normals[o, 2] * az < cos_feature
        plain[i] = off <= FEATURE_SHARE * used
        if ax * ax >= 0.81:  # two tangents square to it: the axis crossed with y, else with x (as frames.perpendicular_basis)
            ux, uy, uz = -az, 0.0, ax
        else:
            ux, uy, uz = 0.0, az, -ay
        size = math.sqrt(ux * ux + uy * uy + uz * uz)
        ux, uy, uz = ux / size, uy / size, uz / size
        tx, ty, tz = ay * uz - az * uy, az * ux - ax * uz, ax * uy - ay * ux
        lhs[:, :] = 0.0
        rhs[:] = 0.0
        for j in range(k):
            if w[j] == 0.0:
                continue
            x = loc[j, 0] * ux + loc[j, 1] * uy + loc[j, 2] * uz
            y = loc[j, 0] * tx + loc[j, 1] * ty + loc[j, 2] * tz
            z = loc[j, 0] * ax + loc[j, 1] * ay + loc[j, 2] * az
            loc[j, 0], loc[j, 1], loc[j, 2] = x, y, z  # in the patch's frame from here on
            terms[0], terms[1], terms[2], terms[3], terms[4], terms[5] = x * x, x * y, y * y, x, y, 1.0
            for a in range(6):
                rhs[a] += w[j] * terms[a] * z
                for b in range(a + 1):
                    lhs[a, b] += w[j] * terms[a] * terms[b]
        for a in range(6):
            lhs[a, a] += 1e-12
            for b in range(a):
                lhs[b, a] = lhs[a, b]
        if not _cholesky_solve(lhs, rhs, 6):
            continue
        err = 0.0
        for j in range(k):
            if w[j] == 0.0:
                continue
            x, y, z = loc[j, 0], loc[j, 1], loc[j, 2]
            fit = rhs[0] * x * x + rhs[1] * x * y + rhs[2] * y * y + rhs[3] * x + rhs[4] * y + rhs[5]
            err += w[j] * (z - fit) ** 2
        residual[i] = radius * math.sqrt(err / total)
        ox, oy, oz = (v[c, 0] - mx) / radius, (v[c, 1] - my) / radius, (v[c, 2] - mz) / radius
        x0 = ox * ux + oy * uy + oz * uz
        y0 = ox * tx + oy * ty + oz * tz
        z0 = rhs[0] * x0 * x0 + rhs[1] * x0 * y0 + rhs[2] * y0 * y0 + rhs[3] * x0 + rhs[4] * y0 + rhs[5]
        placed[i, 0] = mx + radius * (x0 * ux + y0 * tx + z0 * ax)
        placed[i, 1] = my + radius * (x0 * uy + y0 * ty + z0 * ay)
        placed[i, 2] = mz + radius * (x0 * uz + y0 * tz + z0 * az)


def surface_noise(vertices: np.ndarray, faces: np.ndarray, radius: float | None = None) -> float:
    """The mesh's noise, m: the median fit residual over :data:`NOISE_SAMPLES` vertices (drawn
    with a fixed seed) that have enough neighbours, none across a feature; 0 when fewer than a
    quarter have (a coarse mesh, whose noise, if any, tilts its large faces too little to
    matter, or a CAD body of edges and corners).  ``radius``: the fitting radius (default
    :data:`RADIUS_EDGES` median edges)."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, float)
    radius = RADIUS_EDGES * median_edge(v, faces) if radius is None else radius
    if len(v) < MIN_NEIGHBOURS or radius <= 0.0:
        return 0.0
    idx = np.sort(np.random.default_rng(0).choice(len(v), min(NOISE_SAMPLES, len(v)), replace=False))
    _, residual, ok, plain = _fit(v, vertex_normals(v, faces), idx, radius, cKDTree(v))
    ok &= plain
    return float(np.median(residual[ok])) if ok.sum() * 4 >= len(idx) else 0.0


def smooth_scan(vertices: np.ndarray, faces: np.ndarray, iterations: int = ITERATIONS, radius: float | None = None) -> np.ndarray:
    """(v, 3) m: every vertex with enough neighbours moved onto the quadric fitted round it
    (within ``radius``, default :data:`RADIUS_EDGES` median edges), ``iterations`` times (the
    normals and the neighbourhoods found again each time).  The
    vertices are fitted in ranges on every core (:func:`starforge.runtime.threads.over_ranges`;
    each vertex's fit reads only the previous positions, so the result does not depend on the
    thread count)."""
    from scipy.spatial import cKDTree

    from starforge.runtime.threads import over_ranges

    v = np.asarray(vertices, float).copy()
    radius = RADIUS_EDGES * median_edge(v, faces) if radius is None else radius
    for _ in range(iterations):
        tree, normals = cKDTree(v), vertex_normals(v, faces)
        out = v.copy()

        def fit_range(lo: int, hi: int, v=v, normals=normals, tree=tree, out=out) -> None:
            idx = np.arange(lo, hi)
            placed, _, ok, _ = _fit(v, normals, idx, radius, tree)
            out[idx[ok]] = placed[ok]

        over_ranges(fit_range, len(v), _CHUNK)
        v = out
    return v
