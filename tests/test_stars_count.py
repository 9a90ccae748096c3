"""``--count N``: its accuracy order is each star's own, scored in blocks of any size, and its
selection never holds more memory than selecting the whole family among the same candidates."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest

import starforge.stars.family as fam
from starforge.geometry.rigid import rotation_error_hidden_deg
from starforge.geometry.tetra import vertices_from_lengths
from starforge.stars.bounds import block_bound
from starforge.stars.enumerate import enumerate_candidates
from starforge.stars.spec import StarSpec


@pytest.fixture(scope="module")
def small():
    """A small box's spec and candidates (a few hundred stars)."""
    spec = StarSpec(box_mm=(16, 12, 24), delta_mm=2.0)
    return spec, enumerate_candidates(spec)


def test_count_order_is_each_stars_own_in_any_blocks(small, monkeypatch):
    """The order equals a star-by-star ranking (each star scored alone, then sorted by score and
    pool indices in Python), whatever the block size, down to one star per block."""
    spec, c = small
    index, pool = c.index, c.pool_mm
    alone = [
        rotation_error_hidden_deg(vertices_from_lengths(pool[row][None])[0], spec.noise_mm).max()
        for row in index
    ]
    score = np.round(np.array(alone), 9)
    want = sorted(range(len(index)), key=lambda i: (score[i], *index[i].tolist()))
    for block in (1, 7, 64, 1 << 20):
        monkeypatch.setattr(fam, "COUNT_BLOCK", block)
        assert fam._count_order(index, pool, spec.noise_mm).tolist() == want


#: Python objects (dicts of counts, small lists) that differ between the two paths
SLACK_BYTES = 64 * 1024


def _peak_bytes(c, spec: StarSpec, work: int = 2_000):
    """Peak traced bytes (numpy's arrays) of selecting among ``c`` under ``spec``, and the choice."""
    und = c.undecided
    bound = block_bound(np.concatenate([c.index, und]), spec.grid_steps)
    tracemalloc.start()
    try:
        sel, _ = fam._choose(c.index, c.box_volume, und, bound, spec, c.pool_mm, work)
        return tracemalloc.get_traced_memory()[1], sel
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def finger():
    """The finger box's spec and candidates (tens of thousands: more than a block of the order)."""
    spec = StarSpec(box_mm=(20.8, 12.6, 48.3), delta_mm=1.5)
    return spec, enumerate_candidates(spec)


@pytest.mark.slow
@pytest.mark.parametrize("count", [5, None])
def test_count_needs_no_more_memory_than_the_whole_family(finger, count):
    """The ``--count`` selection peaks no higher than the whole family's among the same
    candidates, whether its most accurate greedy pick suffices (5) or it falls back to the
    largest family (its size)."""
    spec, c = finger
    assert len(c.index) > fam.COUNT_BLOCK
    whole, best = _peak_bytes(c, spec)
    n = count if count is not None else len(best.chosen)
    peak, sel = _peak_bytes(c, dataclasses.replace(spec, count=n))
    assert len(sel.chosen) == n
    assert peak <= whole + SLACK_BYTES
