"""The labels of a drawn view as a reader meets them: every visible label's box (its circle's,
for a framed number) and every symbol the view draws (the markers' dots from the scatter's
sizes, the landmarks' triangles from their line markers), read off the figure's artists rather
than from the list of obstacles the drawing code kept; and the clashes between them."""

from __future__ import annotations

import itertools

import numpy as np

from starforge.render._mpl import boxes_overlap as overlap


def view_parts(ax) -> tuple[list, list]:
    """(labels: [(text, display Bbox)], symbols: [display Bbox]) of the axes ``ax``, drawn."""
    from matplotlib.collections import PathCollection

    from starforge.render._mpl import label_box
    from starforge.render.prop_views import symbol_box

    fig = ax.figure
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    labels = [(t.get_text(), label_box(t, r)) for t in ax.texts if t.get_visible() and t.get_text().strip()]
    symbols = []
    for c in ax.collections:
        if isinstance(c, PathCollection) and len(c.get_offsets()):
            d = float(np.sqrt(c.get_sizes()[0]))
            symbols += [symbol_box(ax, xy, d) for xy in np.asarray(c.get_offsets())]
    for line in ax.lines:
        if line.get_marker() == "^":
            symbols += [symbol_box(ax, xy, line.get_markersize()) for xy in line.get_xydata()]
    return labels, symbols


def clashes(ax) -> list[tuple[str, str]]:
    """Every pair of labels of ``ax`` that overlap, and every label over a symbol ("a symbol")."""
    labels, symbols = view_parts(ax)
    out = [(a, b) for (a, p), (b, q) in itertools.combinations(labels, 2) if overlap(p, q)]
    return out + [(a, "a symbol") for a, p in labels if any(overlap(p, s) for s in symbols)]


def guide_view_report(page, views, named) -> dict:
    """The guide's first page: the clashes in its ``views`` (titles) and which of the landmarks
    ``named`` no view labels."""
    axes = [ax for ax in page.axes if ax.get_title() in views]
    found = [c for ax in axes for c in clashes(ax)]
    shown = {n for ax in axes for t in ax.texts if t.get_visible() and not t.get_text().isdigit() for n in t.get_text().split("/")}
    return {"views": len(axes), "clashes": found, "unlabelled": sorted(set(named) - shown)}
