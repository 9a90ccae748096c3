"""The basis square to an axis: orthonormal and right-handed for any axis, stacked or single,
and continuous except where the helper axis switches."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from starforge.geometry.frames import NEAR_X, perpendicular_basis

unit = st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3).map(
    lambda v: np.asarray(v) / np.linalg.norm(v)
)


@given(unit)
def test_orthonormal_and_right_handed(u):
    e1, e2 = perpendicular_basis(u)
    frame = np.array([e1, e2, u])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame) > 0.999  # e1 x e2 = u


@given(st.lists(unit, min_size=1, max_size=12))
def test_stacked_rows_are_the_single_ones(axes):
    """A stack gives each row the basis of that row alone (a caller may pass one axis or many)."""
    stack = np.array(axes)
    e1s, e2s = perpendicular_basis(stack.reshape(len(axes), 1, 3))
    for u, e1, e2 in zip(axes, e1s[:, 0], e2s[:, 0], strict=True):
        f1, f2 = perpendicular_basis(u)
        np.testing.assert_allclose(e1, f1, atol=1e-15)
        np.testing.assert_allclose(e2, f2, atol=1e-15)


@given(unit, st.floats(1e-7, 1e-4))
def test_a_small_turn_moves_the_basis_a_little(u, eps):
    """Away from the switch at |u_x| = NEAR_X, turning the axis a little turns the basis a little
    (a circle drawn round it does not jump)."""
    if abs(abs(u[0]) - NEAR_X) < 1e-3:
        return
    w = np.cross(u, [0.3, -0.5, 0.8])
    if np.linalg.norm(w) < 1e-3:
        return
    v = u + eps * w / np.linalg.norm(w)
    v /= np.linalg.norm(v)
    (a1, a2), (b1, b2) = perpendicular_basis(u), perpendicular_basis(v)
    # the helper axis is unit and u is at least 26 degrees from it: |u x h| >= sin(26 deg) > 0.43
    assert np.linalg.norm(a1 - b1) <= 10 * eps and np.linalg.norm(a2 - b2) <= 10 * eps
