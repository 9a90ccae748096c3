"""Accuracy predictions of a rigid marker body against a Monte Carlo Kabsch fit."""

from __future__ import annotations

import numpy as np
import pytest

from starforge.geometry.rigid import (
    fle_from_sigma,
    rotation_error_deg,
    rotation_error_hidden_deg,
    simulate_fit_errors,
    tre_hidden,
    tre_rms,
)

ASYM = np.array([[0.0, 0.0, 0.0], [41.0, 0.0, 0.0], [13.0, 29.0, 0.0], [9.0, 11.0, 23.0]])
FLAT = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [11.0, 19.0, 0.0], [20.0, 7.0, 0.3]])


@pytest.mark.parametrize("body", [ASYM, FLAT], ids=["tetra", "flat"])
@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (10.0, -5.0, 120.0)])
def test_predictions_match_monte_carlo(body, offset):
    sigma = 0.2
    target = body.mean(axis=0) + np.array(offset)
    tre_sim, rot_sim = simulate_fit_errors(body, target, sigma, 40_000, np.random.default_rng(0))
    assert tre_rms(body, target, fle_from_sigma(sigma)) == pytest.approx(tre_sim, rel=0.05)
    assert rotation_error_deg(body, sigma) == pytest.approx(rot_sim, rel=0.05)
    if offset == (0.0, 0.0, 0.0):  # at the centroid TRE is FLE / sqrt(N), whatever the shape
        assert tre_rms(body, target, fle_from_sigma(sigma)) == pytest.approx(np.sqrt(3) * sigma / 2)


def test_hidden_marker_predictions_match_monte_carlo():
    sigma, tip = 0.2, np.array([5.0, 5.0, 80.0])
    pred = tre_hidden(ASYM, tip, fle_from_sigma(sigma))
    rot = rotation_error_hidden_deg(ASYM, sigma)
    for i in range(4):
        Q = ASYM.copy()
        Q[i] = np.nan
        tre_sim, rot_sim = simulate_fit_errors(Q, tip, sigma, 30_000, np.random.default_rng(i))
        assert pred[i] == pytest.approx(tre_sim, rel=0.06)
        assert rot[i] == pytest.approx(rot_sim, rel=0.06)
    assert pred.max() > tre_rms(ASYM, tip, fle_from_sigma(sigma))


def test_batches_equal_single_bodies_and_degenerate_sets_are_infinite():
    batch = np.stack([ASYM, FLAT, ASYM * 2])
    tip = np.array([1.0, 2.0, 50.0])
    fle = fle_from_sigma(0.1)
    assert np.allclose(tre_rms(batch, tip, fle), [tre_rms(b, tip, fle) for b in batch])
    assert np.allclose(rotation_error_deg(batch, 0.1), [rotation_error_deg(b, 0.1) for b in batch])
    line = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    assert np.isinf(tre_rms(line, tip, fle)) and np.isinf(rotation_error_deg(line, 0.1))
    two = ASYM.copy()
    two[:2] = np.nan
    assert np.isinf(tre_rms(two, tip, fle))
    # a flat star turns worse than a real tetrahedron of the same size
    assert rotation_error_deg(FLAT, 0.2) > rotation_error_deg(ASYM * 30 / 41, 0.2)
