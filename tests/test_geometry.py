"""Tetrahedra from lengths and back, canonical forms, widths and boxes: invariants + brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from starforge.geometry.obb import apply_transform, covariance_box, min_volume_box, placement_transform
from starforge.geometry.tetra import (
    RELABELLINGS,
    canonical_assignments,
    canonical_lengths,
    cayley_menger_volume2,
    is_realisable,
    lengths_from_vertices,
    realisability,
    tetra_width,
    vertices_from_lengths,
)

# Coordinates in mm.  Subnormal floats (below 2.2e-308 mm) are not physical lengths; LAPACK's LU
# divides by such pivots and warns, so they are left out of the strategy.
coords = arrays(
    np.float64, (4, 3), elements=st.floats(-30, 30, allow_nan=False, allow_subnormal=False, width=64)
)


def _triple_volume(P: np.ndarray) -> float:
    """|det([B-A, C-A, D-A])| / 6 as a triple product: no division, exact for any float input."""
    a, b, c = P[1] - P[0], P[2] - P[0], P[3] - P[0]
    return abs(float(np.dot(a, np.cross(b, c)))) / 6


def _well_shaped(P: np.ndarray) -> bool:
    L = lengths_from_vertices(P)
    vol = _triple_volume(P)
    return L.min() > 0.5 and vol > 0.05 * L.max() ** 3 / 100


@settings(max_examples=200, deadline=None)
@given(coords)
def test_trilateration_reproduces_all_six_lengths(P):
    if not _well_shaped(P):
        return
    L = lengths_from_vertices(P)
    Q = vertices_from_lengths(L)
    assert np.abs(lengths_from_vertices(Q) - L).max() < 1e-9
    # the paper's construction: A at the origin, B on +x, C in the xy-plane, D above it
    assert np.allclose(Q[0], 0) and abs(Q[1, 1]) < 1e-12 and abs(Q[1, 2]) < 1e-12
    assert abs(Q[2, 2]) < 1e-12 and Q[2, 1] > 0 and Q[3, 2] > 0


@settings(max_examples=200, deadline=None)
@given(coords)
def test_cayley_menger_matches_triple_product(P):
    L = lengths_from_vertices(P)
    vol = _triple_volume(P)
    assert cayley_menger_volume2(L) == pytest.approx(vol**2, rel=1e-6, abs=1e-6 * max(1.0, L.max() ** 6))


@settings(max_examples=100, deadline=None)
@given(coords, st.permutations(range(4)))
def test_canonical_form_is_invariant_under_relabelling_and_mirroring(P, perm):
    if not _well_shaped(P):
        return
    L = lengths_from_vertices(P)
    relabelled = lengths_from_vertices(P[list(perm)])
    mirrored = lengths_from_vertices(P * np.array([-1.0, 1.0, 1.0]))
    c = canonical_lengths(L)
    assert np.allclose(canonical_lengths(relabelled), c, atol=1e-9)
    assert np.allclose(canonical_lengths(mirrored), c, atol=1e-9)


def test_relabellings_are_the_24_vertex_permutations():
    assert len({tuple(r) for r in RELABELLINGS}) == 24
    rng = np.random.default_rng(0)
    P = rng.normal(size=(4, 3))
    L = lengths_from_vertices(P)
    by_perm = {tuple(np.round(lengths_from_vertices(P[list(p)]), 12)) for p in itertools.permutations(range(4))}
    by_table = {tuple(np.round(L[r], 12)) for r in RELABELLINGS}
    assert by_perm == by_table


def test_thirty_canonical_assignments_cover_every_labelling_once():
    ca = canonical_assignments()
    assert ca.shape == (30, 6)
    # every one of the 720 assignments of six distinct values is a relabelling of exactly one row
    values = np.array([1.0, 2.0, 3.5, 5.0, 7.0, 11.0])
    classes = {tuple(canonical_lengths(values[row])) for row in ca}
    assert len(classes) == 30
    for perm in itertools.permutations(range(6)):
        assert tuple(canonical_lengths(values[list(perm)])) in classes


def test_realisability_names_the_reason():
    r = realisability(np.array([[10, 10, 10, 10, 10, 10], [1, 1, 1, 1, 1, 5], [10, 10, 10, 10, 10, 19.99], [0, 1, 1, 1, 1, 1]]))
    assert r[0] == ""
    assert "triangle inequality" in r[1]
    assert "Cayley-Menger" in r[2]
    assert "not positive" in r[3]
    assert is_realisable(np.array([[10, 10, 10, 10, 10, 10]]))[0]


def test_width_is_the_brute_force_minimum_extent():
    rng = np.random.default_rng(3)
    P = rng.normal(size=(20, 4, 3)) * [2, 5, 9]
    w = tetra_width(lengths_from_vertices(P))
    dirs = rng.normal(size=(100000, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    from scipy.optimize import minimize

    def extent(x, Pi):
        n = np.array([np.sin(x[0]) * np.cos(x[1]), np.sin(x[0]) * np.sin(x[1]), np.cos(x[0])])
        return np.ptp(Pi @ n)

    for i in range(20):
        spread = np.ptp(P[i] @ dirs.T, axis=0)
        assert w[i] <= spread.min() + 1e-9  # no sampled direction is thinner than the width
        best = np.inf
        for d in dirs[np.argsort(spread)[:5]]:  # polish the thinnest sampled directions
            x0 = [np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])]
            best = min(best, minimize(extent, x0, args=(P[i],), method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-13}).fun)
        assert w[i] <= best + 1e-9
        assert best <= w[i] * (1 + 1e-6)  # and the width is attained


def _brute_force_min_volume(P, starts=30, seed=0):
    from scipy.optimize import minimize
    from scipy.spatial.transform import Rotation

    def vol(x):
        return float(np.prod(np.ptp(P @ Rotation.from_rotvec(x).as_matrix(), axis=0)))

    x0s = Rotation.random(starts, random_state=seed).as_rotvec()
    opts = {"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000}
    return min(minimize(vol, x0, method="Nelder-Mead", options=opts).fun for x0 in x0s)


@pytest.mark.slow
def test_min_volume_box_contains_points_is_proper_and_minimal():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(8, 4, 3)) * np.array([1, 3, 8])
    R, c, e = min_volume_box(P)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(np.einsum("nij,nik->njk", R, R), np.eye(3), atol=1e-12)
    local = np.einsum("nkj,nji->nki", P - c[:, None], R)
    assert (np.abs(local) <= e[:, None] / 2 + 1e-9).all()
    _, _, ec = covariance_box(P)
    assert (np.prod(e, axis=1) <= np.prod(ec, axis=1) * (1 + 1e-9)).all()
    for i in range(8):
        assert np.prod(e[i]) <= _brute_force_min_volume(P[i], starts=12) * (1 + 1e-6)


def test_min_volume_box_frames_and_volumes_are_the_numpy_floats_bit_for_bit():
    """The edge-pair family's frames and box volumes, built component by component for speed,
    are the floats np.cross, np.linalg.norm, einsum and np.prod give (the boxes, and so every
    family file, do not change with the speed-up)."""
    from starforge.geometry.frames import perpendicular_basis
    from starforge.geometry.obb import _box_volumes, _family_frames, _points_first, _stack_frames

    rng = np.random.default_rng(3)
    P = rng.normal(size=(40, 4, 3)) * np.array([1, 3, 8])
    e1 = rng.normal(size=(40, 5, 3))
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = rng.normal(size=(40, 5, 3))
    e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
    theta = rng.uniform(0, np.pi, size=(40, 5, 7))
    p, q = perpendicular_basis(e1)
    axes, ok = _family_frames(p, q, e2, theta)
    A = _stack_frames(axes)
    # the same frames with numpy's vector functions
    n1 = np.cos(theta)[..., None] * p[:, :, None] + np.sin(theta)[..., None] * q[:, :, None]
    m = np.cross(e2[:, :, None], n1)
    norm = np.linalg.norm(m, axis=-1, keepdims=True)
    n2 = m / np.where(norm > 1e-12, norm, 1.0)
    ref = np.stack([n1, n2, np.cross(n1, n2)], axis=-2)
    assert A.tobytes() == ref.tobytes() and (ok == (norm[..., 0] > 1e-12)).all()
    proj = np.einsum("nkj,nfsaj->nfska", P, A)
    vol = np.prod(proj.max(axis=3) - proj.min(axis=3), axis=-1)
    assert _box_volumes(_points_first(P), axes).tobytes() == vol.tobytes()


def test_placement_transform_is_the_papers_frame():
    rng = np.random.default_rng(2)
    for _ in range(20):
        P = rng.normal(size=(4, 3)) * [1, 3, 8]
        R, c, e = min_volume_box(P)
        T, ext = placement_transform(P, R, c, e)
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) and np.isclose(np.linalg.det(T[:3, :3]), 1)
        Q = apply_transform(T, P)
        assert np.allclose(lengths_from_vertices(Q), lengths_from_vertices(P))
        # z along the longest side, y along the shortest, origin at the bottom-face centre
        assert ext[2] >= ext[0] >= ext[1]
        assert np.allclose(np.sort(ext), np.sort(e))
        lo, hi = Q.min(axis=0), Q.max(axis=0)
        assert np.allclose(hi - lo, ext, atol=1e-9)
        assert np.isclose(lo[2], 0, atol=1e-9) and np.allclose(lo[:2] + hi[:2], 0, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6), st.integers(0, 3))
def test_closed_form_sym3_eigenvalues_match_lapack(entries, degenerate):
    from starforge.geometry.sym3 import sym3_eigvals

    a, b, c, d, e, f = entries
    if degenerate == 1:  # a repeated eigenvalue
        d = e = f = 0.0
        b = a
    elif degenerate == 2:  # rank one
        v = np.array([a, b, c])
        m = np.outer(v, v)
        a, b, c, d, e, f = m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[1, 2], m[0, 2]
    m = np.array([[a, d, f], [d, b, e], [f, e, c]])
    ours = np.array(sym3_eigvals(a, b, c, d, e, f))
    scale = max(1.0, np.abs(m).max())
    assert np.allclose(ours, np.linalg.eigvalsh(m), atol=1e-6 * scale)


def test_line_spread_from_running_sums_matches_the_point_set():
    from starforge.geometry.sym3 import line_spread2_many, moments

    rng = np.random.default_rng(3)
    sets = [rng.normal(size=(n, 3)) * rng.uniform(0.1, 10, 3) for n in (1, 2, 3, 5, 40)]
    sets.append(np.outer(np.linspace(0, 1, 6), [1.0, 2.0, -1.0]) + 5.0)  # collinear: spread 0
    cnt = np.array([len(p) for p in sets], dtype=float)
    s1 = np.array([p.sum(axis=0) for p in sets])
    s2 = np.array([moments(p).sum(axis=0) for p in sets])
    got = line_spread2_many(cnt, s1, s2)
    for g, p in zip(got, sets, strict=True):
        # independent: mean squared distance from the principal line through the centroid
        q = p - p.mean(axis=0)
        axis = np.linalg.svd(q, full_matrices=False)[2][0] if len(p) > 1 else np.array([1.0, 0, 0])
        want = np.mean(np.sum((q - np.outer(q @ axis, axis)) ** 2, axis=1))
        assert g == pytest.approx(want, abs=1e-9)


def test_line_spread_at_least_is_the_comparison_bit_for_bit():
    """The bounded test answers exactly ``line_spread2(...) >= limit``, limits placed at, just
    beside and far from each set's own spread (where the bounds cannot decide and where they do)."""
    from starforge.geometry.sym3 import line_spread2_at_least_many, line_spread2_many, moments

    rng = np.random.default_rng(4)
    sets = [rng.normal(size=(int(rng.integers(0, 9)), 3)) * rng.uniform(0.001, 1, 3) for _ in range(3000)]
    sets += [np.outer(np.linspace(0, 1, 5), [1.0, 2.0, -1.0]) + 0.3, np.ones((4, 3))]  # a line, one point
    cnt = np.array([len(p) for p in sets], dtype=float)
    s1 = np.array([p.sum(axis=0) if len(p) else np.zeros(3) for p in sets])
    s2 = np.array([moments(p).sum(axis=0) if len(p) else np.zeros(6) for p in sets])
    d2 = line_spread2_many(cnt, s1, s2)
    for limit in (d2, np.nextafter(d2, np.inf), np.nextafter(d2, -np.inf), d2 * 0.5, d2 * 0.9, d2 * 1.5, d2 * 3):
        for lim in (np.full_like(d2, 1e-4), limit):
            got = np.array([line_spread2_at_least_many(cnt[i : i + 1], s1[i : i + 1], s2[i : i + 1], lim[i])[0] for i in range(len(d2))])
            assert np.array_equal(got, d2 >= lim)


def _band_samples_hit(o, d, length, a, b, radius, grow):
    """Brute force: 20,001 points along the ray's stretch, any inside the band grown by ``grow``
    (radius and both ends), from the point's axial coordinate and its distance from the axis."""
    s = np.linspace(0.0, length, 20_001)
    p = o + s[:, None] * d
    L = np.linalg.norm(b - a)
    u = (b - a) / L
    t = (p - a) @ u
    r = np.linalg.norm(p - a - t[:, None] * u, axis=1)
    return bool(((t >= -grow) & (t <= L + grow) & (r <= radius + grow)).any())


@settings(max_examples=150, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
@pytest.mark.slow
def test_a_ray_enters_a_band_exactly_when_points_along_it_do(seed):
    """:func:`ray_enters_band` against dense samples of the ray: a ray it says enters the band has
    samples inside the band grown by a hair, and one it says misses has none inside the band shrunk
    by a hair (rays through, past, along and inside bands of any size and direction)."""
    from starforge.geometry.distance import in_band, ray_enters_band

    rng = np.random.default_rng(seed)
    a = rng.uniform(-1, 1, 3)
    b = a + rng.normal(size=3) * rng.uniform(0.05, 1.0)
    radius = rng.uniform(0.02, 0.5)
    o = rng.uniform(-1.5, 1.5, (8, 3))
    o[0] = (a + b) / 2  # inside
    d = rng.normal(size=(8, 3))
    d[1] = b - a  # along the axis
    d[2] = np.cross(b - a, rng.normal(size=3))  # square to it
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = 3.0
    hit = ray_enters_band(o, d, a, b, radius, length)
    assert hit[0] and in_band(o[:1], a, b, radius)[0]
    for i in range(len(o)):
        if hit[i]:
            assert _band_samples_hit(o[i], d[i], length, a, b, radius, 1e-3)
        else:
            assert not _band_samples_hit(o[i], d[i], length, a, b, radius, -1e-3)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_a_point_is_as_far_from_many_segments_as_from_each_alone(seed):
    """:func:`point_segments_distance` (one point, many segments) against
    :func:`point_segment_distance` (many points, one segment) taken segment by segment, and
    against dense samples of each segment; segments of no length included."""
    from starforge.geometry.distance import point_segment_distance, point_segments_distance

    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, 3)
    a = rng.uniform(-1, 1, (12, 3))
    b = a + rng.normal(size=(12, 3)) * rng.uniform(0, 1, (12, 1))
    b[0] = a[0]
    got = point_segments_distance(p, a, b)
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    for i in range(len(a)):
        assert got[i] == pytest.approx(point_segment_distance(p[None], a[i], b[i])[0], abs=1e-12)
        assert np.linalg.norm(a[i] + t * (b[i] - a[i]) - p, axis=1).min() >= got[i] - 1e-12
