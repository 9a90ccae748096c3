"""The best any layout can do on a scenario sample, by exhaustion: an exact ceiling.

When the chosen layout is tracked in fewer scenarios than the target, the question a prop team
asks is whether a better layout exists or the prop, marker and hand cannot do it.  Markers closer
than the spacing merge in the cameras' images, so a usable layout is a set of sites pairwise at
least the spacing apart: a clique of the "far enough" graph.  On small props those cliques are
few (the 84 mm metal handle: 423 of 3 to 5 markers), so every one of them is scored on the same
scenarios and with the same rule as the objective (at least 3 markers seen, not in a line: their
mean squared distance from their best-fit line at least ``min_spread2``).  The best score is then
a ceiling, not an estimate: no layout of spaced markers on these sites is tracked in more of
these scenarios.  The count is bounded before any scoring; past the bound nothing is claimed.
"""

from __future__ import annotations

import numpy as np

from starforge.geometry.sym3 import line_spread2_at_least, moments
from starforge.runtime.kernels import numba

#: the most spaced layouts enumerated (beyond it no ceiling is claimed)
MAX_LAYOUTS = 200_000
#: the most (layout, scenario) pairs scored
MAX_WORK = 400_000_000


@numba.njit(cache=True, nogil=True)
def _cliques(far, max_k, out):
    """Sets of 3..max_k indices pairwise ``far`` (ascending, depth first), written into ``out``
    (cap, max_k; -1 padded).  Returns the count, or -1 past ``out``'s rows."""
    n = far.shape[0]
    cur = np.empty(max_k, np.int64)
    nxt = np.zeros(max_k + 1, np.int64)
    depth, count = 0, 0
    while True:
        if nxt[depth] >= n:
            if depth == 0:
                return count
            depth -= 1
            nxt[depth] += 1
            continue
        v = nxt[depth]
        ok = True
        for j in range(depth):
            if not far[cur[j], v]:
                ok = False
                break
        if not ok:
            nxt[depth] += 1
            continue
        cur[depth] = v
        k = depth + 1
        if k >= 3:
            if count >= out.shape[0]:
                return -1
            for j in range(max_k):
                out[count, j] = cur[j] if j < k else -1
            count += 1
        if k < max_k:
            depth += 1
            nxt[depth] = v + 1
        else:
            nxt[depth] += 1


@numba.njit(cache=True, nogil=True)
def _score(layouts, seen, P, M, min_spread2):
    """(m,) scenarios tracked by each layout (rows of site indices, -1 padded)."""
    m, S = layouts.shape[0], seen.shape[1]
    out = np.zeros(m, np.int64)
    for r in range(m):
        good = 0
        for s in range(S):
            c = 0.0
            x = y = z = xx = yy = zz = xy = yz = xz = 0.0
            for j in range(layouts.shape[1]):
                i = layouts[r, j]
                if i < 0:
                    break
                if seen[i, s]:
                    c += 1.0
                    x += P[i, 0]
                    y += P[i, 1]
                    z += P[i, 2]
                    xx += M[i, 0]
                    yy += M[i, 1]
                    zz += M[i, 2]
                    xy += M[i, 3]
                    yz += M[i, 4]
                    xz += M[i, 5]
            if c >= 3 and line_spread2_at_least(c, x, y, z, xx, yy, zz, xy, yz, xz, min_spread2):
                good += 1
        out[r] = good
    return out


def spaced_layouts(points: np.ndarray, spacing: float, max_markers: int, cap: int | None = None) -> np.ndarray | None:
    """Every set of 3..``max_markers`` of ``points`` (s, 3) pairwise at least ``spacing`` apart,
    as rows of indices padded with -1; None when there are more than ``cap`` (default
    :data:`MAX_LAYOUTS`)."""
    cap = MAX_LAYOUTS if cap is None else int(cap)
    P = np.asarray(points, float)
    k = int(max(3, max_markers))
    far = np.linalg.norm(P[:, None] - P[None], axis=2) >= spacing
    out = np.empty((cap, k), np.int64)  # at most 11 MB at the default cap of 7 markers
    n = _cliques(far, k, out)
    return None if n < 0 else out[:n].copy()


def tracked_ceiling(points, seen, spacing: float, min_spread2: float, max_markers: int) -> dict | None:
    """The exact best tracked fraction of any layout of 3..``max_markers`` sites pairwise at
    least ``spacing`` apart, on the scenarios of ``seen`` ((s, S) bool: site seen by two cameras
    in scenario j), or None when the layouts are too many to score (:data:`MAX_LAYOUTS`,
    :data:`MAX_WORK`).  ``seen`` may be a callable returning that table, so that it is only
    built when the count allows."""
    P = np.asarray(points, float)
    lay = spaced_layouts(P, spacing, max_markers)
    if lay is None:
        return None
    if not len(lay):
        return {"ceiling": 0.0, "layouts": 0, "best": [], "max_markers_spaced": 0}
    table = seen() if callable(seen) else seen
    if len(lay) * table.shape[1] > MAX_WORK:
        return None
    good = _score(lay, np.ascontiguousarray(table, dtype=np.bool_), P, moments(P), float(min_spread2))
    b = int(np.argmax(good))  # the first best in enumeration order: the same on every run
    return {
        "ceiling": float(good[b] / table.shape[1]),
        "layouts": int(len(lay)),
        "best": [int(i) for i in lay[b] if i >= 0],
        "max_markers_spaced": int((lay >= 0).sum(axis=1).max()),
        "scenarios": int(table.shape[1]),
    }
