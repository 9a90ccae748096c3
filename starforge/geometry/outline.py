"""Outlines in the plane (pure numpy): the union of axis-aligned rectangles as closed polygons,
and a convex polygon swept along a segment.

The rectangles' outline cuts an engraving made of many touching rectangles (the pixel-font id)
as one prism:
OpenCascade's boolean is several times slower with a stack of touching boxes (every shared face
is a coplanar face pair it has to resolve) than with one solid of the same shape.

The rectangles are laid on the grid of their own edge coordinates, so nothing is rounded: every
corner of the outline is one of the input coordinates, exactly.
"""

from __future__ import annotations

import numpy as np


def rect_union_outlines(rects) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """The union of rectangles ``(u0, u1, v0, v1)`` as polygons with holes.

    Parameters
    ----------
    rects : (n, 4) float, ``u0 < u1``, ``v0 < v1`` (any length unit)

    Returns
    -------
    list of (outer, holes): ``outer`` (k, 2) the corners of one connected piece's boundary,
    counter-clockwise in (u, v); ``holes`` a list of (m, 2) corner arrays, clockwise.  No two
    consecutive edges are collinear.  Pieces that touch only at a corner are separate pieces.
    """
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    if len(r) == 0:
        return []
    if not ((r[:, 0] < r[:, 1]) & (r[:, 2] < r[:, 3])).all():
        raise ValueError("rects must have u0 < u1 and v0 < v1")
    us = np.unique(r[:, :2])
    vs = np.unique(r[:, 2:])
    cover = np.zeros((len(vs) + 1, len(us) + 1), dtype=bool)  # a margin of empty cells round it
    for u0, u1, v0, v1 in r:
        j0, j1 = np.searchsorted(us, [u0, u1])
        i0, i1 = np.searchsorted(vs, [v0, v1])
        cover[i0 + 1 : i1 + 1, j0 + 1 : j1 + 1] = True
    # directed boundary edges, the covered side on the left (outer loops CCW, holes CW); a grid
    # point (i, j) is (vs[i], us[j]); cell (i + 1, j + 1) spans grid points i..i+1, j..j+1
    edges: dict[tuple[int, int], list[tuple[int, int]]] = {}

    def add(a, b) -> None:
        edges.setdefault(a, []).append(b)

    for i, j in zip(*np.nonzero(cover), strict=True):
        gi, gj = i - 1, j - 1
        if not cover[i - 1, j]:
            add((gi, gj), (gi, gj + 1))  # bottom, +u
        if not cover[i, j + 1]:
            add((gi, gj + 1), (gi + 1, gj + 1))  # right, +v
        if not cover[i + 1, j]:
            add((gi + 1, gj + 1), (gi + 1, gj))  # top, -u
        if not cover[i, j - 1]:
            add((gi + 1, gj), (gi, gj))  # left, -v
    loops = []
    while edges:
        start = min(edges)
        loop = [start]
        prev, cur = start, edges[start].pop()
        if not edges[start]:
            del edges[start]
        while cur != start:
            outs = edges[cur]
            if len(outs) > 1:  # two pieces touch at this corner: turn left, keep them apart
                d_in = (cur[1] - prev[1], cur[0] - prev[0])  # (du, dv) in grid steps
                outs.sort(key=lambda q: -_cross(d_in, (q[1] - cur[1], q[0] - cur[0])))
            nxt = outs.pop(0)
            if not outs:
                del edges[cur]
            loop.append(cur)
            prev, cur = cur, nxt
        loops.append(_corners(np.array([(us[j], vs[i]) for i, j in loop])))
    outers = [lp for lp in loops if _area(lp) > 0]
    holes = [lp for lp in loops if _area(lp) < 0]
    out: list[tuple[np.ndarray, list[np.ndarray]]] = [(o, []) for o in outers]
    for h in holes:
        # the smallest outer loop around the hole (a point just inside the hole's first edge)
        p = _inside_point(h)
        owners = [k for k, o in enumerate(outers) if _contains(o, p)]
        k = min(owners, key=lambda k: _area(outers[k]))
        out[k][1].append(h)
    return out


def sweep_outline(polygon: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The outline of a convex polygon swept along ``d``: the convex hull of ``polygon`` and of
    ``polygon + d`` (their Minkowski sum with the segment from 0 to ``d``), as a closed ring.

    Walking the polygon counter-clockwise, each edge whose outward normal points along ``d``
    is taken from the moved copy; where that changes, the ring steps along ``d`` (the hull's two
    straight sides).  Every corner appears twice (once as each of its edges takes it), which
    draws the same outline.

    Parameters
    ----------
    polygon : (..., n, 2) float
        The corners of a convex polygon (or of a stack of them), in either turning direction.
    d : (..., 2) float
        The sweep (of each polygon).

    Returns
    -------
    (..., 2 n + 1, 2) float, the first point repeated at the end.

    >>> sweep_outline(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([2.0, 0.0])).tolist()
    [[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [2.0, 1.0], [0.0, 1.0], [0.0, 0.0]]
    """
    p = np.asarray(polygon, float)
    d = np.asarray(d, float)[..., None, :]
    x, y = p[..., 0], p[..., 1]
    clockwise = (x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(axis=-1) < 0
    p = np.where(clockwise[..., None, None], p[..., ::-1, :], p)
    e = np.roll(p, -1, axis=-2) - p
    ahead = (e[..., 1:] * d[..., :1] - e[..., :1] * d[..., 1:] > 0)  # edge i's outward normal along d
    ring = np.stack([p + np.roll(ahead, 1, axis=-2) * d, p + ahead * d], axis=-2)
    ring = ring.reshape(*p.shape[:-2], -1, 2)
    return np.concatenate([ring, ring[..., :1, :]], axis=-2)


def _cross(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _area(loop: np.ndarray) -> float:
    """Signed area (positive counter-clockwise)."""
    u, v = loop[:, 0], loop[:, 1]
    return float((u * np.roll(v, -1) - np.roll(u, -1) * v).sum() / 2)


def _corners(loop: np.ndarray) -> np.ndarray:
    """Drop the points between two collinear edges."""
    prev, nxt = np.roll(loop, 1, axis=0), np.roll(loop, -1, axis=0)
    d1, d2 = loop - prev, nxt - loop
    turn = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    return loop[turn != 0]


def _inside_point(hole: np.ndarray) -> np.ndarray:
    """A point just off the middle of the hole's first edge, on its empty side (the right of a
    clockwise hole edge is inside the hole)."""
    a, b = hole[0], hole[1]
    d = b - a
    right = np.array([d[1], -d[0]]) / np.linalg.norm(d)
    return (a + b) / 2 + right * 1e-6 * np.linalg.norm(d)


def _contains(loop: np.ndarray, p) -> bool:
    """Even-odd point-in-polygon test."""
    u, v = loop[:, 0], loop[:, 1]
    u2, v2 = np.roll(u, -1), np.roll(v, -1)
    crosses = (v > p[1]) != (v2 > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = u + (p[1] - v) * (u2 - u) / (v2 - v)
    return bool((crosses & (p[0] < x)).sum() % 2)
