"""rect_union_outlines: the outline of a union of rectangles, checked against the pixels."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from starforge.geometry.outline import _area, _contains, rect_union_outlines


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
