"""The enumeration's chunk order: a permutation whose every prefix is spread over the range."""

from __future__ import annotations

import numpy as np
import pytest

from starforge.stars.enumerate import spread_order


@pytest.mark.parametrize("n", range(1, 70))
def test_spread_order_is_a_permutation_with_spread_prefixes(n):
    order = spread_order(n)
    assert sorted(order.tolist()) == list(range(n))
    # each prefix of k leaves no gap in the range wider than about 2 n / k (brute force over k)
    for k in range(1, n + 1):
        seen = np.sort(order[:k])
        gaps = np.diff(np.concatenate([seen, [n]]))
        assert gaps.max() <= 2 * n / k + 1, (n, k, seen)
