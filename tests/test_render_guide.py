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
from starforge.render.prop_views import VIEWS, declutter, plot_data, symbol_box


@pytest.fixture(scope="module", params=["hammer", pytest.param("box", marks=pytest.mark.slow)])
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


@pytest.mark.parametrize("prop", ["small_box", "hammer", pytest.param("sword", marks=pytest.mark.slow)])
def test_the_template_is_drawn_at_the_scale_its_bar_shows(prop, tmp_path):
    """Page 2 as a technician measures it: the printed distance between two crosshairs is their
    distance on the prop in the template's view over its scale, and so is the scale bar's 50 mm;
    the drawing keeps clear of every text on the page."""
    import trimesh

    from starforge.props.placement import run_placement

    if prop == "small_box":
        path = tmp_path / "small_box.stl"
        trimesh.creation.box(extents=(0.12, 0.06, 0.04)).export(path)
        prop = str(path)
    res = run_placement(prop, sites=150, resolution=1, orientations=6)
    d = plot_data(res)
    fig = guide_pages(d)[1]
    fig.canvas.draw()
    title = next(t.get_text() for t in fig.texts if t.get_text().startswith("Template"))
    view, k = title.split(", ")[1], int(title.split("scale 1:")[1].split(":")[0])
    ax, bar = fig.axes[:2]
    mm = 25.4 / fig.dpi  # printed mm per pixel
    # each crosshair is a horizontal and a vertical stroke; its centre is the stroke's middle
    centres = [ax.transData.transform(line.get_xydata().mean(axis=0)) for line in ax.lines[0::2]]
    assert len(centres) == len(d.marker_points)
    on_prop = d.marker_points @ VIEWS[view][:2].T * 1000.0  # mm, in the view's plane (any turn in it keeps distances)
    for i, j in itertools.combinations(range(len(centres)), 2):
        printed = np.linalg.norm(centres[i] - centres[j]) * mm
        assert printed == pytest.approx(np.linalg.norm(on_prop[i] - on_prop[j]) / k, rel=2e-3, abs=0.05)
    ends = bar.transData.transform([[0.0, 0.0], [50.0, 0.0]])
    assert (ends[1, 0] - ends[0, 0]) * mm == pytest.approx(50.0 / k, rel=1e-3)
    drawing, r = ax.get_window_extent(), fig.canvas.get_renderer()
    page_texts = [t for t in fig.texts if t.get_text().strip()]  # the heading, the note, the bar's caption
    assert len(page_texts) == 3
    for t in page_texts:
        assert not overlap(drawing, t.get_window_extent(r)), t.get_text()


@pytest.mark.slow
def test_the_most_markers_keep_their_tables_on_the_page():
    """12 markers (the most ``place`` puts): the marker table and the 66 caliper pairs stay on
    the page, clear of each other and of the views, which give up height for them."""
    from starforge.props.placement import run_placement
    from starforge.render._mpl import text_boxes
    from starforge.render.guide import overlapping_texts

    res = run_placement("sword", markers=12, sites=300, resolution=1, orientations=12)
    assert len(res.marker_sites) == 12
    page = guide_pages(plot_data(res))[0]
    W, H = page.bbox.width, page.bbox.height
    for t, (x0, y0, x1, y1) in text_boxes(page):
        assert x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H, t
    assert overlapping_texts(page) == []
    r = page.canvas.get_renderer()
    lowest_view = min(ax.get_window_extent(r).y0 for ax in page.axes if ax.get_title() in GUIDE_VIEWS)
    assert all(t.get_window_extent(r).y1 <= lowest_view for t in page.texts if t.get_position()[1] < 0.5)


def _spread_reference(pts, span, rounds=200):
    """spread_labels as array arithmetic, one label at a time against the round's start."""
    n, gap = len(pts), 0.07 * span
    d = pts - pts.mean(axis=0)
    norm = np.linalg.norm(d, axis=1)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    u = np.where(norm[:, None] > 1e-9 * span, d / np.maximum(norm, 1e-300)[:, None], np.column_stack([np.cos(ang), np.sin(ang)]))
    lab = pts + 1.2 * gap * u
    for _ in range(rounds):
        moved, others = False, np.vstack([lab, pts])
        for i in range(n):
            diff = lab[i] - others
            dist = np.linalg.norm(diff, axis=1)
            dist[i] = np.inf
            close = dist < gap
            if close.any():
                push = (diff[close] / np.maximum(dist[close], 1e-9 * span)[:, None] * (gap - dist[close])[:, None]).sum(0)
                lab[i] += 0.5 * (push if np.linalg.norm(push) >= 1e-12 * span else u[i] * gap * 0.1)
                moved = True
            pull = lab[i] - pts[i]
            if np.linalg.norm(pull) > 3 * gap:
                lab[i] = pts[i] + pull / np.linalg.norm(pull) * 3 * gap
        if not moved:
            break
    return lab


@pytest.mark.parametrize("seed", range(40))
def test_spread_labels_is_the_array_arithmetic_and_keeps_its_promises(seed):
    from starforge.render.prop_views import spread_labels

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 13))
    pts = rng.uniform(-0.1, 0.1, (n, 2)) * rng.choice([0.05, 0.3, 1.0])
    if seed % 4 == 0 and n > 2:
        pts[1] = pts[0]  # two markers on one spot
    span = float(rng.uniform(0.1, 0.5))
    lab = spread_labels(pts, span)
    assert lab == pytest.approx(_spread_reference(pts, span), abs=1e-12 * span)
    gap = 0.07 * span
    assert (np.linalg.norm(lab - pts, axis=1) <= 3 * gap * (1 + 1e-12)).all()


@pytest.mark.parametrize(("fists", "covering"), [(120, 120), (120, 60), (18, 3)])
def test_the_hands_shade_is_as_deep_and_as_orange_as_its_share_of_grips(fists, covering):
    """A spot that ``covering`` of ``fists`` grips cover is drawn as the hand's colour laid over
    white at opacity ``1 - (1 - 0.45) ** (covering / fists)``: read off the rendered pixels, so
    the 8-bit blending of many faint layers cannot shift its depth or its hue."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb

    from starforge.render.prop_views import shade_hand

    fig = plt.figure(figsize=(2, 2), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(-1, 1)
    ax.set_ylim(-1, 1)
    ax.axis("off")
    here = [0.0, 0.0, -0.3, 0.0, 0.0, 0.3, 0.2, 0.0]  # a fist round the middle, seen from the front
    elsewhere = [0.7, 0.0, -0.9, 0.7, 0.0, -0.8, 0.05, 0.0]  # the others, away from the middle
    rows = [here] * covering + [[*elsewhere[:1], 0.0, -0.9 + 0.001 * k, *elsewhere[3:]] for k in range(fists - covering)]
    shade_hand(ax, np.array(rows), np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]))
    fig.canvas.draw()
    pixel = np.asarray(fig.canvas.buffer_rgba())[100, 100, :3] / 255.0
    a = 1.0 - 0.55 ** (covering / fists)
    assert pixel == pytest.approx(a * np.array(to_rgb("C1")) + (1 - a), abs=2.5 / 255)
    plt.close(fig)


def test_the_views_scale_bar_is_the_views_scale(guide_data):
    """Page 1's bar is as long as the length it names at the scale the four views share."""
    import re

    page = guide_pages(guide_data)[0]
    page.canvas.draw()
    views = [ax for ax in page.axes if ax.get_title() in GUIDE_VIEWS]
    px_per_mm = {round(float(np.diff(ax.transData.transform([[0, 0], [0.001, 0]])[:, 0])[0]), 6) for ax in views}
    assert len(px_per_mm) == 1  # one scale
    (text,) = [t.get_text() for t in page.texts if t.get_text().startswith("the views:")]
    mm, k = float(re.search(r"(\d+) mm", text).group(1)), float(re.search(r"1:([\d.]+)", text).group(1))
    bar = next(ax for ax in page.axes if ax not in views)
    ends = bar.transData.transform([[0.0, 0.0], [mm, 0.0]])
    assert ends[1, 0] - ends[0, 0] == pytest.approx(mm * px_per_mm.pop(), rel=1e-6)
    # printed to one decimal: within half of it
    assert k == pytest.approx(page.dpi / 25.4 / np.diff(views[0].transData.transform([[0, 0], [0.001, 0]])[:, 0])[0], abs=0.05)


def test_a_marker_line_too_long_for_the_page_goes_on_under_its_number(guide_data):
    """The longest line a marker's landmarks can make (three far readings, a slanted face, a
    mark the readings cannot place) wraps under its number and stays on the drawn page (the
    PDF's Courier is as wide a character; bench_props_real.py reads the written PDFs)."""
    import dataclasses

    from starforge.render._mpl import text_boxes
    from starforge.render.guide import overlapping_texts

    long = (
        "on flat face F46 (facing (+0.32, +0.95, -0.00), 458 mm2); 1197.0 mm from C13, 1200.1 mm from C14, "
        "1246.2 mm from T16 (to 112.5 mm only: place it by the drawings); tilt 90 deg from +z, leaning +y"
    )
    data = dataclasses.replace(guide_data, landmarks=tuple(long for _ in guide_data.landmarks))
    page = guide_pages(data)[0]
    W, H = page.bbox.width, page.bbox.height
    for t, (x0, y0, x1, y1) in text_boxes(page):
        assert x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H, t
    assert overlapping_texts(page) == []
    table = [t for t in page.texts if t.get_text().startswith(" 1. ")][0].get_text().split("\n")
    assert len(table) == 2 * len(guide_data.landmarks) and all(line.startswith("    ") for line in table[1::2])
    # wrapped at a space: the text reads the same joined up again
    assert " ".join(x.strip() for x in table[:2]) == f" 1. {long}; margin {guide_data.margin_mm[0]:.1f} mm".strip()


@pytest.mark.parametrize("band", [False, True])
def test_a_part_of_the_prop_in_front_of_the_hand_hides_it(band):
    """A slab seen from above a fist held under it hides the fist: the pixel at the slab's middle
    is the slab's grey, not orange; seen from below, the fist is in front and its shade shows
    there.  The fist is a capsule or a band (whose end circles, seen end on, reach no nearer)."""
    import types

    import matplotlib.pyplot as plt
    import trimesh

    from starforge.render.prop_views import VIEWS, shade_grips, shaded

    slab = trimesh.creation.box(extents=(1.0, 1.0, 0.1), transform=trimesh.transformations.translation_matrix([0, 0, 0.5]))
    # a fist round a handle along z, under the slab: its top at z = 0.4 (a band's circles reach no higher)
    fist = [0.0, 0.0, -0.4, 0.0, 0.0, 0.4 - (0.0 if band else 0.3), 0.3, float(band)]
    d = types.SimpleNamespace(hand=np.array([fist]), wrists=None, triangles=np.asarray(slab.triangles),
                              face_normals=np.asarray(slab.face_normals))  # fmt: skip
    for view, hidden in (("top (from +z)", True), ("bottom", False)):
        B = VIEWS["top (from +z)"] if hidden else np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
        fig = plt.figure(figsize=(2, 2), dpi=100)
        ax = fig.add_axes([0, 0, 1, 1])
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.axis("off")
        shaded(ax, d.triangles, d.face_normals, B)
        shade_grips(ax, d, B)
        fig.canvas.draw()
        r, g, b = np.asarray(fig.canvas.buffer_rgba())[100, 100, :3] / 255.0
        plt.close(fig)
        assert (abs(r - b) < 2.5 / 255) == hidden, (view, r, g, b)
