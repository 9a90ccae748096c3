"""Certified upper bounds on a family's size from blocks of face keys.

Face keys in one block of side m (grid steps) conflict pairwise, and a star's four faces lie in
four different blocks, so a family has at most (blocks used) // 4 stars: over the stars that may
fit (:func:`block_bound`) or over every triangle of pool lengths a star could use
(:func:`pool_face_bound`, without enumerating stars).
"""

from __future__ import annotations

import itertools

import numpy as np

from starforge.runtime.kernels import numba
from starforge.stars.rules import key3, key_triples


def count_blocks(faces: np.ndarray, m: int) -> int:
    """Fewest distinct face blocks of side m over the m^3 placements of the block grid.

    ``faces`` (k, 3): non-negative integer face keys of any integer type.  Each block is coded
    as one integer in the narrowest type that holds every code (int32 for the pools stars use),
    column by column: no (k, 3) int64 copy, and half the memory traffic."""
    faces = np.asarray(faces)
    if not len(faces):
        return 0
    top = int(faces.max()) + m  # bounds (x + o) // m + 1 over the placements, and so base
    dt = np.int32 if top**3 < 2**31 else np.int64
    cols = [faces[:, j].astype(dt) for j in range(3)]
    best = None
    for o in np.ndindex(m, m, m):
        # (integer floor division is slow in numpy, and with m = 1 the blocks are the keys)
        f = [(c + oj) // m for c, oj in zip(cols, o, strict=True)] if m > 1 else cols
        base = max(int(x.max()) for x in f) + 1
        code = (f[0] * base + f[1]) * base + f[2]  # one integer per block, < base**3
        if base**3 <= 1 << 26:
            used = np.zeros(base**3, dtype=bool)
            used[code] = True
            blocks = int(np.count_nonzero(used))
        else:
            blocks = len(np.unique(code))
        best = blocks if best is None else min(best, blocks)
    return int(best)


#: stars from which :func:`block_bound` counts blocks in compiled code (``--delta 1.0``'s 5.2 M
#: in 0.1 s instead of numpy's 1.7 s); below, numpy (the finger default's 0.36 M in 0.02 s, and
#: no kernel to compile on a first run)
BLOCK_KERNEL_STARS = 1_000_000


def block_bound(index: np.ndarray, m: int) -> int:
    """Proven upper bound: face keys in one block of side m (grid steps) conflict pairwise and a
    star's four faces lie in four different blocks, so a family has at most blocks // 4 stars.
    Every placement of the block grid gives a bound; the smallest of the m^3 is returned."""
    index = np.asarray(index)
    if not len(index):
        return 0
    if len(index) >= BLOCK_KERNEL_STARS:
        return count_face_blocks_compiled(index, m) // 4
    faces = key_triples(index, "face")[:, :4].reshape(-1, 3)
    return count_blocks(faces, m) // 4


def count_face_blocks_compiled(index: np.ndarray, m: int) -> int:
    """:func:`count_blocks` of the stars' face keys (the same count), straight from their pool
    indices (n, 6) in compiled code: no (4 n, 3) array of keys, one table of blocks."""
    from starforge.geometry.tetra import FACE_EDGES

    index = np.ascontiguousarray(index)
    base = (int(index.max()) + m - 1) // m + 1  # past every block coordinate (x + o) // m
    if base**3 > 1 << 26:  # a table that large: the general count
        return count_blocks(key_triples(index, "face")[:, :4].reshape(-1, 3), m)
    used = np.zeros(base**3, dtype=np.bool_)
    edges = np.ascontiguousarray(FACE_EDGES, dtype=np.int64)
    return min(
        int(_face_blocks(index, edges, int(m), int(a), int(b), int(c), int(base), used))
        for a, b, c in np.ndindex(m, m, m)
    )


@numba.njit(cache=True, nogil=True, no_cfunc_wrapper=True)
def _face_blocks(index, edges, m, o0, o1, o2, base, used):
    """Distinct blocks ``((lo + o0) // m, (mid + o1) // m, (hi + o2) // m)`` of the stars' four
    face keys (each face's three pool indices sorted); ``used`` (base^3 bools) is scratch."""
    used[:] = False
    count = 0
    for i in range(index.shape[0]):
        for f in range(4):
            lo, mid, hi = key3(index, i, edges, f)
            code = (((lo + o0) // m) * base + (mid + o1) // m) * base + (hi + o2) // m
            if not used[code]:
                used[code] = True
                count += 1
    return count


def pool_face_bound(pool_mm: np.ndarray, m: int, diagonal_mm: float) -> int:
    """Certified upper bound without enumerating stars: every face of a star is a triangle of
    pool lengths whose sides differ by >= m steps (the tolerance within a star), obeys the
    triangle inequality and is no longer than the centres' box diagonal; the block bound over all
    such triangles covers every family (it counts what any star could use, not what fits)."""
    n = len(pool_mm)
    i, j, k = np.array(list(itertools.combinations(range(n), 3)), dtype=np.int64).reshape(-1, 3).T
    ok = (
        (j - i >= m)
        & (k - j >= m)
        & (pool_mm[i] + pool_mm[j] > pool_mm[k] + 1e-9)
        & (pool_mm[k] <= diagonal_mm + 1e-9)
    )
    faces = np.stack([i[ok], j[ok], k[ok]], axis=1)
    if not len(faces):
        return 0
    return count_blocks(faces, m) // 4
