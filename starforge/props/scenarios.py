"""Scenarios of camera loss: every pose met several times, each with its own random set of
lost cameras (the tracked objective scores a layout over them)."""

from __future__ import annotations

import numpy as np

#: the camera losses of the searched scenarios come from seed + this (so that ``place score``
#: meets the same scenarios as the placement it re-scores)
LOSS_SEED_OFFSET = 3_000_017


def alive_masks(n_cams: int, lost_fraction: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count,) uint64: random sets of surviving cameras, ``round(lost_fraction * n_cams)`` lost
    in each (a uniformly random subset per entry)."""
    lost = int(round(lost_fraction * n_cams))
    keep = n_cams - lost
    order = np.argsort(rng.random((count, n_cams)), axis=1)[:, :keep]
    bits = np.uint64(1) << order.astype(np.uint64)
    return np.bitwise_or.reduce(bits, axis=1) if keep else np.zeros(count, np.uint64)


def loss_scenarios(masks: np.ndarray, n_cams: int, lost_fraction: float, patterns: int, rng: np.random.Generator):
    """Scenarios of camera loss: every pose ``patterns`` times, each with its own random set of
    lost cameras (one when none are lost).  A marker is seen in a scenario when at least two of
    the surviving cameras see it (any two can triangulate it).

    Returns
    -------
    seen : (s, P * patterns) bool
    alive : (P * patterns,) uint64, the surviving cameras of each scenario
    """
    P = masks.shape[1]
    L = patterns if int(round(lost_fraction * n_cams)) > 0 else 1
    alive = alive_masks(n_cams, lost_fraction, P * L, rng)
    seen = np.bitwise_count(masks[:, np.repeat(np.arange(P), L)] & alive[None]) >= 2
    return seen, alive
