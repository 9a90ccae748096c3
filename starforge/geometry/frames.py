"""Frames built from one direction: the two unit vectors square to an axis.

Circles round an axis (a cylinder's rings, a band's outline), tangent planes under a marker's
base, the sides of a box round an edge and the wrist angles round a gripped part all start
from the same pair, so one function makes it: the same axis gives the same pair everywhere.
"""

from __future__ import annotations

import numpy as np

#: an axis whose x component is at least this (within about 26 degrees of x) is crossed with
#: the y axis instead of the x axis, so the cross product never nears zero
NEAR_X = 0.9


def perpendicular_basis(axis) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``e1`` and ``e2`` square to each unit ``axis`` and to each other.

    ``e1`` is ``axis`` crossed with the x axis (the y axis where ``|axis_x| >= NEAR_X``),
    normalised, and ``e2 = axis x e1``, so ``(e1, e2, axis)`` is right-handed.

    Parameters
    ----------
    axis : (..., 3) float, unit vectors

    Returns
    -------
    e1, e2 : (..., 3) float each

    >>> e1, e2 = perpendicular_basis([0.0, 0.0, 1.0])
    >>> e1.tolist(), e2.tolist()
    ([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0])
    """
    u = np.asarray(axis, dtype=float)
    helper = np.where(np.abs(u[..., :1]) < NEAR_X, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(u, helper)
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(u, e1)
