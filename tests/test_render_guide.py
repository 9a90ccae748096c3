"""The rigging guide's views read cleanly: no label (a marker's number in its circle, a
landmark's name) covers another label, a marker's dot or a landmark's triangle, and every
landmark the marker table names is labelled in at least one view.  The symbols are found in
the drawn figure (the scatter's offsets, the triangles' line markers), not in the guide's own
list of obstacles."""

from __future__ import annotations

import itertools

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from benchmarks._views import clashes, guide_view_report, overlap
from starforge.render._mpl import label_box
from starforge.render.guide import GUIDE_VIEWS, guide_pages
from starforge.render.prop_views import declutter, plot_data, symbol_box


@pytest.fixture(scope="module", params=["hammer", "box"])
def guide_data(request):
    from starforge.props.placement import run_placement

    res = run_placement(request.param, sites=250, resolution=2, orientations=6)
    return plot_data(res)


def test_no_label_covers_a_label_a_dot_or_a_triangle(guide_data):
    page = guide_pages(guide_data)[0]
    rep = guide_view_report(page, GUIDE_VIEWS, [n for n, _ in guide_data.features])
    assert rep["views"] == len(GUIDE_VIEWS)
    assert rep["clashes"] == []


def test_every_landmark_the_table_names_is_labelled_in_a_view(guide_data):
    page = guide_pages(guide_data)[0]
    rep = guide_view_report(page, GUIDE_VIEWS, [n for n, _ in guide_data.features])
    assert guide_data.features and rep["unlabelled"] == []
    shown = {n for n, _ in guide_data.features}
    for text in guide_data.landmarks:  # each marker's line names landmarks that are drawn
        assert any(n in text for n in shown)


def test_a_framed_label_is_as_large_as_its_frame():
    """label_box of a number in a circle is the circle's box as matplotlib places it."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    t = ax.text(0.5, 0.5, "12", fontsize=8, ha="center", va="center", bbox=dict(boxstyle="circle,pad=0.15"))
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    t.update_bbox_position_size(r)
    drawn = t.get_bbox_patch().get_window_extent(r)
    assert np.allclose(label_box(t, r).extents, drawn.extents, atol=1e-6)
    assert label_box(t, r).width > t.get_window_extent(r).width
    plt.close(fig)


def test_declutter_clears_crowded_labels_off_symbols():
    """Twelve labels and six symbols on one spot: afterwards no visible label overlaps another or
    a symbol; the droppable ones that could not be placed are hidden, the others all shown."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3, 3))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    rng = np.random.default_rng(0)
    pts = 0.5 + 0.02 * rng.standard_normal((6, 2))
    movable = [ax.text(*p, str(k), ha="center", va="center", bbox=dict(boxstyle="circle,pad=0.15")) for k, p in enumerate(pts)]
    drop = [ax.text(*p, f"T{k}", ha="center", va="center", fontsize=6) for k, p in enumerate(pts)]
    obstacles = [(p, 6.0) for p in pts]
    declutter(ax, [], movable, drop, obstacles)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    shown = [t for t in movable + drop if t.get_visible()]
    assert all(t.get_visible() for t in movable)
    boxes = [label_box(t, r) for t in shown]
    symbols = [symbol_box(ax, p, s) for p, s in obstacles]
    for p, q in itertools.combinations(boxes, 2):
        assert not overlap(p, q)
    for p in boxes:
        assert not any(overlap(p, s) for s in symbols)
    plt.close(fig)


def test_layout_png_labels_clear_of_each_other_and_the_dots(guide_data, monkeypatch, tmp_path):
    """layout.png's two views: no number's circle covers another or a marker's dot."""
    import starforge.render.props as pictures

    found = []

    def check(fig, path, dpi=100):
        for ax in fig.axes[:2]:
            assert sum(t.get_visible() for t in ax.texts) == len(guide_data.marker_centres)
            found.extend(clashes(ax))
        return path

    monkeypatch.setattr(pictures, "save_png", check)
    pictures.layout_png(guide_data, tmp_path / "layout.png")
    assert found == []
