"""Identification simulation: rates on a real face-rule family, hand-built symmetric bodies
and congruent faces, Kabsch and conflict-resolution invariants, TRE against Monte Carlo."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from starforge.geometry.rigid import kabsch
from starforge.tracking import identify as ident
from starforge.tracking import library
from starforge.tracking.bodies import load_bodies
from starforge.tracking.check import closest_triangles

# an asymmetric 4-marker body and a deliberately symmetric one (C2 about z: A<->B, C<->D)
ASYM = np.array([[0.0, 0.0, 0.0], [41.0, 0.0, 0.0], [13.0, 29.0, 0.0], [9.0, 11.0, 23.0]])
SYM = np.array([[30.0, 0.0, 5.0], [-30.0, 0.0, 5.0], [0.0, 20.0, -5.0], [0.0, -20.0, -5.0]])


@pytest.fixture(scope="module")
def family_lib(small_family):
    out, _ = small_family
    bs = load_bodies(out / "family.json")
    assert bs.kind == "family" and bs.tolerance_mm > 0
    return bs, ident.build_library([b.points_mm for b in bs.bodies], bs.names)


def test_face_rule_family_drop1_identifies_999(family_lib):
    bs, lib = family_lib
    tol = bs.tolerance_mm
    rng = np.random.default_rng(7)
    # a window as wide as the margin lets wrong faces through the gate: the best fit decides
    t = ident.run(lib, 1500, 0.1 * tol, 1, 0, rng, match_mm=tol, residual_mm=tol / 2, drop_exact=True)
    r = t.rates()
    assert t.instances == 1500 * len(bs.bodies)
    # every instance is exactly one of correct / flip / wrong body / missed
    assert t.correct + t.mislabels + t.flips.sum() + t.missed.sum() == t.instances
    assert r["identification_rate"] >= 0.999


def test_noise_free_full_view_is_perfect(family_lib):
    bs, lib = family_lib
    t = ident.run(lib, 200, 0.0, 0, 0, np.random.default_rng(1), bs.tolerance_mm, bs.tolerance_mm / 2)
    assert t.correct == t.instances


def test_withholding_ambiguous_matches_cuts_ghost_confusions(family_lib):
    """One marker hidden and 2 ghosts inside every body's sphere: a ghost and two real markers
    can form another star's face.  The default tracker reports a match only when it is
    AMBIGUITY times as likely as every rival; on the same frames it makes at most a quarter of
    the wrong bodies and poses of a tracker that always reports the best match, and everything
    it withholds is a missed frame, never a different label."""
    bs, lib = family_lib
    tol = bs.tolerance_mm
    noise = 0.2 * tol / 1.5
    runs = {}
    for amb in (1.0, ident.AMBIGUITY):
        runs[amb] = ident.run(
            lib, 300, noise, 1, 2, np.random.default_rng(11), tol / 2, tol / 3, drop_exact=True, ambiguity=amb
        )
    best, safe = runs[1.0], runs[ident.AMBIGUITY]
    assert best.withheld == 0 and safe.withheld > 0
    wrong = {k: t.mislabels + int(t.flips.sum()) for k, t in runs.items()}
    assert wrong[1.0] > 0  # the ghosts do make confusions for a best-match tracker
    assert 4 * wrong[ident.AMBIGUITY] <= wrong[1.0]
    # withholding only turns reports into misses: no frame gains a report
    assert safe.correct + wrong[ident.AMBIGUITY] + int(safe.missed.sum()) == safe.instances


def test_symmetric_body_is_reported_as_flipping():
    # the symmetry is real: a half turn about z maps the body onto itself, permuted
    Rz = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    assert np.allclose(SYM @ Rz.T, SYM[[1, 0, 3, 2]])
    lib = ident.build_library([ASYM, SYM], ["asym", "sym"])
    t = ident.run(lib, 600, 0.05, 0, 0, np.random.default_rng(3), match_mm=1.0, residual_mm=0.5)
    assert t.flips[1] > 0.2 * 600  # the two fits tie: a large share flips
    assert t.flips[0] == 0
    # a tracker that withholds ambiguous matches misses those frames instead of flipping
    w = ident.run(lib, 600, 0.05, 0, 0, np.random.default_rng(3), 1.0, 0.5, ambiguity=ident.AMBIGUITY)
    assert w.flips[1] < 0.02 * 600 and w.missed[1] > 0.9 * 600 and w.flips[0] == 0
    flips = ident.self_matches(SYM, 1.0, 0.5)
    assert flips and flips[0][0] < 1e-6
    assert any(np.array_equal(a, [1, 0, 3, 2]) for _, a in flips)
    assert ident.self_matches(ASYM, 1.0, 0.5) == []


def test_congruent_faces_are_reported_as_confused():
    # body b shares face ABC of body a exactly; their fourth markers differ
    a = ASYM
    b = ASYM.copy()
    b[3] = [25.0, 5.0, -17.0]
    d = np.linalg.norm(a[:3, None] - a[None, :3], axis=2)
    assert np.allclose(d, np.linalg.norm(b[:3, None] - b[None, :3], axis=2))
    lib = ident.build_library([a, b], ["a", "b"])
    t = ident.run(lib, 800, 0.05, 1, 0, np.random.default_rng(5), 1.0, 0.5, drop_exact=True)
    # a quarter of the frames hide the fourth marker: ABC alone is ambiguous
    assert t.confusion[0, 1] + t.confusion[1, 0] > 0.05 * 1600
    rows = closest_triangles(lib, 2.0)
    assert rows[0]["margin_mm"] < 1e-9 and {rows[0]["a"], rows[0]["b"]} == {"a", "b"}
    # with every marker seen they are told apart
    t0 = ident.run(lib, 200, 0.05, 0, 0, np.random.default_rng(5), 1.0, 0.5)
    assert t0.correct == t0.instances


@pytest.mark.slow
def test_resolution_equals_sequential_greedy(family_lib):
    _, lib = family_lib
    sc = ident.simulate(lib, 40, 0.3, 1, 3, np.random.default_rng(2), match_mm=2.0)
    h = ident.hypotheses(lib, sc.pts, 2.0, 1.0)
    chosen = ident.resolve(h, sc.frame, sc.pts.shape[1], lib.n_bodies)
    # the reference: plain sequential greedy over (more markers, lower RMS)
    used_pts, used_labels, ref = set(), set(), []
    for i in sorted(range(len(h.scene)), key=lambda i: (-h.n[i], h.rms[i])):
        mine = {(int(h.scene[i]), int(a)) for a in h.assign[i] if a >= 0}
        label = (int(sc.frame[h.scene[i]]), int(h.body[i]))
        if mine & used_pts or label in used_labels:
            continue
        used_pts |= mine
        used_labels.add(label)
        ref.append(i)
    assert sorted(ref) == sorted(chosen.tolist())
    assert len(ref) > 0


def test_simulation_hides_and_adds_what_was_asked(family_lib):
    _, lib = family_lib
    sc = ident.simulate(lib, 100, 0.0, 1, 2, np.random.default_rng(4), drop_exact=True)
    assert ((sc.label >= 0).sum(axis=1) == 3).all()
    assert ((sc.label == -1).sum(axis=1) == 2).all()
    # noise-free visible markers keep the body's distances
    s = 17
    idx = np.flatnonzero(sc.label[s] >= 0)
    P = sc.pts[s, idx]
    M = lib.points[sc.body[s], sc.label[s, idx]]
    for i, j in itertools.combinations(range(3), 2):
        assert np.isclose(np.linalg.norm(P[i] - P[j]), np.linalg.norm(M[i] - M[j]))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(3, 7))
def test_kabsch_recovers_a_rigid_motion(seed, n):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-50, 50, size=(n, 3))
    R0 = Rotation.random(random_state=rng).as_matrix()
    t0 = rng.uniform(-500, 500, size=3)
    Q = P @ R0.T + t0
    R, t = kabsch(P[None], Q[None])
    assert np.isclose(np.linalg.det(R[0]), 1.0)
    assert np.allclose(P @ R[0].T + t[0], Q, atol=1e-8)


def test_kabsch_mirror_only_with_reflect():
    M = ASYM - ASYM.mean(axis=0)
    Q = M * np.array([-1.0, 1.0, 1.0])  # mirror image
    R, t = kabsch(M[None], Q[None])
    assert np.linalg.norm(M @ R[0].T + t[0] - Q) > 1.0
    R, t = kabsch(M[None], Q[None], reflect=True)
    assert np.allclose(M @ R[0].T + t[0], Q, atol=1e-9)


def test_settings_are_validated():
    lib = ident.build_library([ASYM], ["a"])
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="noise must be >= 0"):
        ident.run(lib, 10, -0.1, 0, 0, rng, 1.0, 0.5)
    with pytest.raises(ValueError, match="drop must be <= markers - 3"):
        ident.run(lib, 10, 0.1, 2, 0, rng, 1.0, 0.5)
    with pytest.raises(ValueError, match="ghosts"):
        ident.run(lib, 10, 0.1, 0, -1, rng, 1.0, 0.5)
    with pytest.raises(ValueError, match="at least 3"):
        ident.build_library([ASYM[:2]])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), bodies=st.integers(1, 4), n=st.integers(3, 6))
def test_close_pairs_and_margin_match_brute_force(seed, bodies, n):
    rng = np.random.default_rng(seed)
    pts = [np.round(rng.uniform(-30, 30, size=(n, 3)), 1) for _ in range(bodies)]
    lib = ident.build_library(pts)
    S = lib.tri_sorted
    D = np.abs(S[:, None] - S[None]).max(axis=2)
    for window in (0.5, 3.0):
        i, j, d = library.close_triangle_pairs(lib, window, chunk=7)
        want = {(a, b) for a, b in zip(*np.nonzero(D < window), strict=True) if a < b}
        assert set(zip(i.tolist(), j.tolist(), strict=True)) == want
        assert np.allclose(d, D[i, j])
    np.fill_diagonal(D, np.inf)
    assert library.drop1_margin_mm(lib) == pytest.approx(min(D.min(), np.diff(S, axis=1).min()))
