"""Outlines in the plane: rect_union_outlines checked against the pixels, sweep_outline against Qhull."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from starforge.geometry.outline import _area, _contains, rect_union_outlines, sweep_outline


def _covered(rects, p) -> bool:
    return any(u0 < p[0] < u1 and v0 < p[1] < v1 for u0, u1, v0, v1 in rects)


def _inside(pieces, p) -> bool:
    return any(_contains(o, p) and not any(_contains(h, p) for h in hs) for o, hs in pieces)


def _union_area(rects, step) -> float:
    """Brute force on the grid the rectangles live on (cell centres)."""
    r = np.asarray(rects)
    us = np.arange(r[:, 0].min(), r[:, 1].max(), step) + step / 2
    vs = np.arange(r[:, 2].min(), r[:, 3].max(), step) + step / 2
    return sum(_covered(rects, (u, v)) for u in us for v in vs) * step * step


@given(
    st.lists(
        st.tuples(st.integers(0, 6), st.integers(1, 3), st.integers(0, 6), st.integers(1, 3)),
        min_size=1,
        max_size=8,
    )
)
def test_outline_matches_the_pixels(cells):
    step = 0.25  # exact in binary: the outline's corners are the input coordinates
    rects = [(u * step, (u + w) * step, v * step, (v + h) * step) for u, w, v, h in cells]
    pieces = rect_union_outlines(rects)
    total = sum(_area(o) + sum(_area(h) for h in hs) for o, hs in pieces)
    assert total == pytest.approx(_union_area(rects, step), abs=1e-9)
    for o, hs in pieces:
        assert _area(o) > 0 and all(_area(h) < 0 for h in hs)
        for lp in (o, *hs):
            d = np.diff(np.vstack([lp, lp[:1]]), axis=0)
            assert ((d[:, 0] == 0) != (d[:, 1] == 0)).all()  # axis-aligned, no zero-length edge
            assert (d[:, 0] * np.roll(d[:, 1], -1) - d[:, 1] * np.roll(d[:, 0], -1) != 0).all()  # corners only
            assert set(lp[:, 0]) <= {x for r in rects for x in r[:2]}
            assert set(lp[:, 1]) <= {x for r in rects for x in r[2:]}
    rng = np.random.default_rng(0)
    for p in rng.uniform(-0.1, 2.6, size=(60, 2)) // (step / 2) * (step / 2) + step / 4:  # off the grid lines
        assert _inside(pieces, p) == _covered(rects, p)


def test_a_ring_has_one_hole_and_corner_contacts_stay_apart():
    ring = [(0, 3, 0, 1), (0, 3, 2, 3), (0, 1, 1, 2), (2, 3, 1, 2)]
    (outer, holes), = rect_union_outlines(ring)
    assert _area(outer) == 9 and len(holes) == 1 and _area(holes[0]) == -1
    pinch = [(0, 1, 0, 1), (1, 2, 1, 2)]  # touching at one corner only
    pieces = rect_union_outlines(pinch)
    assert len(pieces) == 2 and all(len(o) == 4 and not hs for o, hs in pieces)


@given(
    st.integers(3, 40),
    st.floats(0.05, 5.0),
    st.floats(-3.0, 3.0),
    st.floats(0.0, 6.3),
    st.floats(-4.0, 4.0),
    st.floats(-4.0, 4.0),
    st.booleans(),
)
def test_sweep_outline_is_the_hull_of_the_polygon_and_its_moved_copy(n, squash, shear, turn, dx, dy, flip):
    """A regular polygon sheared into any convex one, swept along d: the ring's corners are input
    points, it contains every input point, and it encloses exactly the convex hull's area
    (scipy's Qhull, an independent check)."""
    from scipy.spatial import ConvexHull

    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + turn
    poly = np.column_stack([np.cos(t), np.sin(t)]) @ np.array([[1.0, shear], [0.0, squash]]).T
    if flip:  # clockwise
        poly = poly[::-1]
    d = np.array([dx, dy])
    ring = sweep_outline(poly, d)
    pts = np.vstack([poly, poly + d])
    assert len(ring) == 2 * n + 1 and np.array_equal(ring[0], ring[-1])
    assert all(np.abs(pts - q).max(axis=1).min() == 0 for q in ring)  # every corner is an input point
    size = float(np.abs(pts).max())
    for a, b in zip(ring[:-1], ring[1:], strict=True):  # every point on the inner side of every edge
        if np.any(a != b):
            e = b - a
            assert ((e[0] * (pts[:, 1] - a[1]) - e[1] * (pts[:, 0] - a[0])) >= -1e-9 * size**2).all()
    x, y = ring[:, 0], ring[:, 1]
    area = float((x[:-1] * y[1:] - x[1:] * y[:-1]).sum() / 2)
    assert area == pytest.approx(ConvexHull(pts).volume, rel=1e-9, abs=1e-12 * size**2)


def test_sweep_outline_of_a_stack_is_each_polygons_outline():
    """A stack of polygons (some clockwise) and sweeps gives, row by row, the single polygons' rings."""
    rng = np.random.default_rng(3)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    polys = np.stack([np.column_stack([np.cos(t), np.sin(t)]) @ rng.normal(size=(2, 2)) for _ in range(6)])
    d = rng.normal(size=(6, 2))
    rings = sweep_outline(polys, d)
    assert rings.shape == (6, 25, 2)
    for k in range(6):
        assert np.array_equal(rings[k], sweep_outline(polys[k], d[k]))
