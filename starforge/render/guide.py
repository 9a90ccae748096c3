"""The rigging guide a technician sticks the markers on from: ``guide.pdf`` (and its first page
as ``guide.png``).

Page 1: four orthographic views at one scale (its bar at the top right) with the numbered markers (filled where the prop does not hide
them from that side, hollow and grey where it does), the landmarks (tips T, corners C: blue
triangles), the hand's grips; under them, per marker, the face it sits on, its distances from
the landmarks that locate it best and how tightly, its tilt and its seat margin; then the caliper table (every pair of ball
centres, the reading across both balls' outsides, the tolerance).  Page 2: a template at a
printed scale of 1:1 where the prop fits an A4 sheet (else 1:2, 1:5, ...) with a scale bar to
check the print against (drawing and bar at that one scale), crosshairs at the markers' base
centres.

No two texts overlap: text blocks are stacked by their measured extents (:class:`_Cursor`),
and the labels inside a view are placed by :func:`declutter` where they cover no other label, no
marker and no landmark's triangle.  Landmarks that fall on one spot in a view share one triangle
and one label ("T4/T5"); a landmark label with no free spot is left out, those already labelled
in an earlier view giving way first (the tests check that every landmark the table names is
labelled in some view).
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np

from starforge.props.guide import TAPE_MM, TAPE_REL, template_scale
from starforge.render._mpl import boxes_overlap, discard, drawing, figure, save_png, text_boxes
from starforge.render.prop_views import (
    VIEWS,
    declutter,
    frame,
    markers_in_view,
    plot_data,
    shade_grips,
    shaded,
    shared_half_width,
)
from starforge.runtime.procs import can_fork, fork_helper, release

#: the guide's four views (names in :data:`starforge.render.prop_views.VIEWS`)
GUIDE_VIEWS = ("front (from -y)", "side (from +x)", "top (from +z)", "back (from +y)")
_PAGE = (11.69, 8.27)  # A4 landscape, inches
_MM = 25.4  # mm per inch
#: every text style the guide draws in (matplotlib text keywords); :func:`load_fonts` loads them
TEXT_STYLES = {
    "title": {"fontsize": 13, "weight": "bold"},
    "heading": {"fontsize": 11, "weight": "bold"},
    "view": {"fontsize": 9},
    "caption": {"fontsize": 8},  # also the markers' numbers in the views (prop_views)
    "body": {"fontsize": 7.5},
    "number": {"fontsize": 7},
    "landmark": {"fontsize": 6},
    "table": {"fontsize": 6.8, "family": "monospace"},
    "caliper": {"fontsize": 6.5, "family": "monospace"},
}
_DPI = 110  # guide.png
_VIEW_BOX = (0.235, 0.445)  # each view's width and height, before the text's share of the page is known
_VIEW_TOP = 0.915  # the views' top (page fraction), below the title
_MIN_VIEW_HEIGHT = 0.3  # the views' least height (page fraction), when the text needs the room
_BOTTOM = 0.03  # the page's bottom margin (page fraction)
_TEMPLATE_BAND = (0.12, 0.915)  # the template's drawing: above its scale bar, below its heading (page fractions)
_DOT_AREA = 40  # a marker's dot in the views (scatter size: points squared)
_TRIANGLE_PT = 4  # a landmark's triangle, points across


def _line_chars(left: float, style: str) -> int:
    """Characters of ``TEXT_STYLES[style]`` a line across the page between margins of ``left``
    (a fraction of its width) holds, at 0.6 em a character (Courier's width; wider than the
    proportional body font's average, so a body line wrapped at it fits)."""
    return int((1.0 - 2 * left) * _PAGE[0] * 72.0 / (0.6 * TEXT_STYLES[style]["fontsize"]))


def coincident_landmarks(features, B, tol: float) -> list[tuple[list[str], np.ndarray]]:
    """The landmarks ``features`` ((name, point) pairs) as seen in view ``B``, those that fall
    within ``tol`` of each other (in the view's plane) grouped under one symbol: (names, the first
    one's 2D point) per group, in the order of ``features``."""
    groups: list[tuple[list[str], np.ndarray]] = []
    for fname, p in features:
        q = np.asarray(p, float) @ B[:2].T
        for names, g in groups:
            if np.linalg.norm(q - g) <= tol:
                names.append(fname)
                break
        else:
            groups.append(([fname], q))
    return groups


def overlapping_texts(fig) -> list[tuple[str, str]]:
    """Every pair of visible texts of ``fig`` whose boxes (frames included) overlap (the guide's check)."""
    from matplotlib.transforms import Bbox

    boxes = [(t, Bbox.from_extents(*b)) for t, b in text_boxes(fig)]
    return [(boxes[i][0], boxes[j][0]) for i in range(len(boxes)) for j in range(i + 1, len(boxes)) if boxes_overlap(boxes[i][1], boxes[j][1])]


class _Cursor:
    """Stacks text blocks down the page from the top, each placed by its measured height."""

    def __init__(self, fig, top: float, left: float = 0.02, gap: float = 0.008):
        self.fig, self.y, self.left, self.gap = fig, top, left, gap
        self.texts: list = []  # every block placed, in order

    def block(self, text: str, x: float | None = None, **kw):
        """A text whose top is at the cursor (figure fractions)."""
        t = self.fig.text(self.left if x is None else x, self.y, text, va="top", ha="left", **kw)
        self.texts.append(t)
        return t

    def lower(self, by: float) -> None:
        """Move every block placed, and the cursor, ``by`` (figure fraction) down the page."""
        for t in self.texts:
            x, y = t.get_position()
            t.set_position((x, y - by))
        self.y -= by

    def advance(self, *texts) -> None:
        """Move the cursor below the lowest of ``texts``."""
        r = self.fig.canvas.get_renderer()
        fig_h = self.fig.bbox.height
        low = min(t.get_window_extent(r).y0 for t in texts) / fig_h
        self.y = low - self.gap

    def columns(self, lines: list[str], width: float, **kw) -> None:
        """``lines`` in as many columns of figure width ``width`` as fit the page's width."""
        if not lines:
            return
        ncol = max(1, int((1.0 - 2 * self.left) / width + 1e-9))
        per = -(-len(lines) // ncol)
        ts = [self.block("\n".join(lines[c * per : (c + 1) * per]), x=self.left + c * width, **kw)
              for c in range(ncol) if lines[c * per : (c + 1) * per]]  # fmt: skip
        self.advance(*ts)


@drawing
def guide_pages(res) -> list:
    """The guide's pages as matplotlib figures (see the module docstring)."""
    d = plot_data(res)
    return [_first_page(d), _template_page(d)]


def _first_page(d):
    """Page 1: the views, the marker table and the caliper check."""
    fig = figure(figsize=_PAGE)
    fig.text(0.02, 0.975, f"Rigging guide: {d.name}, {len(d.marker_centres)} markers", va="top",
             **TEXT_STYLES["title"])  # fmt: skip
    lo, hi = d.bounds
    cur = _Cursor(fig, top=0.46)
    size = " x ".join(f"{(hi - lo)[k] * 1000:.1f}" for k in range(3))
    err = d.placement_error_mm
    head = cur.block(
        f"Marker: {d.seat_text}.  Prop {size} mm (x, y, z).\n"
        "Find each marker's base centre from the landmarks named (T: a tip, C: a corner; blue triangles) with a ruler "
        "or caliper, on the face given;\n'to 1.2 mm': 95 % of marks set from those readings (each read to "
        f"{TAPE_MM:g} mm + {100 * TAPE_REL:g} %) land within it; where that is more than the placement error, place "
        "the mark by the drawings.\nThe tilt is the angle of the marker's axis from the prop's +z.  Margin: how far "
        "(mm) a base may land off its mark before it overhangs an edge or a tilted\nsurface (each is at least the "
        f"{err:g} mm placement error).  Filled markers: in front in that view; hollow, grey: the prop hides them.  "
        "Orange: where the hand holds it.",
        **TEXT_STYLES["body"],
    )
    cur.advance(head)
    if d.standoff_text:  # a block of its own, a gap further down: a PDF reader's glyph boxes (the font's
        # ascent and descent) reach past the extents the page is laid out by
        cur.y -= cur.gap
        chars = _line_chars(cur.left, "body")
        text = textwrap.fill(d.standoff_text[:1].upper() + d.standoff_text[1:] + ".", chars, break_on_hyphens=False)
        cur.advance(cur.block(text, **TEXT_STYLES["body"]))
    margin = d.margin_mm if d.margin_mm is not None else np.full(len(d.landmarks), np.nan)
    # a line too long for the page goes on under its number (the table's font is monospaced:
    # Courier in the PDF, 0.6 em a character)
    width = _line_chars(cur.left, "table")
    lines = [
        textwrap.fill(f"{i + 1:>2}. {t}; margin {m:.1f} mm", width, subsequent_indent="    ", break_on_hyphens=False)
        for i, (t, m) in enumerate(zip(d.landmarks, margin, strict=True))
    ]
    cur.advance(cur.block("\n".join(lines), **TEXT_STYLES["table"]))
    if d.caliper:
        tol = d.caliper[0][4]
        cap = cur.block(
            f"Caliper check (ball centre to centre; across both balls' outsides, add one ball diameter), each within "
            f"+-{tol:g} mm:", **TEXT_STYLES["body"],
        )  # fmt: skip
        cur.advance(cap)
        rows = [f"{a}-{b}: {c:6.1f} ({o:.1f} outside)" for a, b, c, o, _ in d.caliper]
        cur.columns(rows, 0.16, **TEXT_STYLES["caliper"])
    # the views take what the text leaves of the page: the text moves down to the bottom margin
    # (or up, when it runs past it: a long caliper table, the views then shorter)
    spare = max(cur.y - _BOTTOM, _MIN_VIEW_HEIGHT - _VIEW_BOX[1])
    cur.lower(spare)
    height = _VIEW_BOX[1] + spare
    named: set[str] = set()  # landmarks already labelled in an earlier view
    # one scale for every view, as large as the views' boxes (taller than wide) hold the prop
    # markers on posts stand well off the prop: the views frame their balls too
    balls = d.marker_centres if d.standoff_text else np.zeros((0, 3))
    half = shared_half_width(np.vstack([d.triangles.reshape(-1, 3), balls]), [VIEWS[n] for n in GUIDE_VIEWS],
                             height * _PAGE[1] / (_VIEW_BOX[0] * _PAGE[0]), 1.3)  # fmt: skip
    for k, name in enumerate(GUIDE_VIEWS):
        B = VIEWS[name]
        ax = fig.add_axes([0.01 + 0.245 * k, _VIEW_TOP - height, _VIEW_BOX[0], height])
        proj = shaded(ax, d.triangles, d.face_normals, B)
        span = frame(ax, np.vstack([proj.reshape(-1, 3), balls @ B.T]), pad=1.3, half_width=half)
        shade_grips(ax, d, B, wrists=False)
        numbers = markers_in_view(ax, d, B, span, size=_DOT_AREA, view=name)
        triangles, marks = [], []
        for names, q in coincident_landmarks(d.features, B, 0.01 * span):
            ax.plot([q[0]], [q[1]], marker="^", color="C0", ms=_TRIANGLE_PT, zorder=5.5)
            triangles.append((q, _TRIANGLE_PT + 1))
            label = ax.text(q[0], q[1] - 0.035 * span, "/".join(names), color="C0", ha="center", va="center", zorder=6,
                            **TEXT_STYLES["landmark"])  # fmt: skip
            marks.append((set(names) <= named, label))
        ax.set_title(name, **TEXT_STYLES["view"])
        for sp in ax.spines.values():
            sp.set_visible(False)
        # landmarks labelled in an earlier view give way first (declutter hides the first listed first)
        marks.sort(key=lambda m: not m[0])
        numbers.place(ax, [t for _, t in marks], triangles)
        named |= {n for _, t in marks if t.get_visible() for n in t.get_text().split("/")}
    _views_scale_bar(fig, _VIEW_BOX[0] * _PAGE[0] / (2 * half))
    return fig


#: the lengths (mm on the prop) a scale bar may show
_BAR_MM = (5, 10, 20, 50, 100, 200, 500, 1000, 2000)


def _views_scale_bar(fig, inch_per_m: float) -> None:
    """A scale bar for the views (one scale for all four) at the top right of page 1: the
    longest round length that prints at most an inch, and the printed scale it makes."""
    mm = max((x for x in _BAR_MM if x * inch_per_m / 1000.0 <= 1.0), default=_BAR_MM[0])
    w = mm * inch_per_m / 1000.0 / _PAGE[0]  # page fraction
    right = 0.98
    _scale_bar(fig, [right - w, 0.962, w, 0.01], mm, (0, mm / 2, mm))
    k = 1000.0 / (25.4 * inch_per_m)  # prop mm per printed mm
    fig.text(right - w - 0.006, 0.962, f"the views: {mm:g} mm on the prop (printed at about 1:{k:.1f})", ha="right",
             va="bottom", **TEXT_STYLES["caption"])  # fmt: skip


def _scale_bar(fig, rect, mm: float, ticks) -> None:
    """A scale bar in its own axes at ``rect`` (page fractions) whose width is ``mm`` on the
    prop: a baseline with a stroke at each of ``ticks`` (mm), none clipped at the axes' edge."""
    bar = fig.add_axes(rect)
    bar.set_xlim(0, mm)
    bar.set_ylim(-0.2, 1)
    bar.axis("off")
    for x in ticks:
        bar.plot([x, x], [0, 1], color="k", lw=0.8, clip_on=False)
    bar.plot([0, mm], [0, 0], color="k", lw=1.2, clip_on=False)


def _template_page(d):
    """A view at a printed scale (1:1 where it fits) with a scale bar and the markers' base
    centres as crosshairs (see the module docstring)."""
    # the view whose silhouette is largest among front, side and top
    best = max(GUIDE_VIEWS[:3], key=lambda n: float(np.prod(np.ptp(d.triangles.reshape(-1, 3) @ VIEWS[n][:2].T, axis=0))))
    B = VIEWS[best]
    if np.ptp(d.triangles.reshape(-1, 3) @ B[1]) > np.ptp(d.triangles.reshape(-1, 3) @ B[0]):
        B = np.array([B[1], -B[0], B[2]])  # turned a quarter: the long side along the sheet
    proj = d.triangles.reshape(-1, 3) @ B.T
    lo2, hi2 = proj[:, :2].min(axis=0), proj[:, :2].max(axis=0)
    ext_mm = (hi2 - lo2) * 1000.0
    lo_band, hi_band = (f * _PAGE[1] for f in _TEMPLATE_BAND)
    k = template_scale((float(ext_mm[0]), float(ext_mm[1])), (_PAGE[0] * _MM - 40.0, (hi_band - lo_band) * _MM - 20.0))
    fig = figure(figsize=_PAGE)
    # the drawing's box: the view at 1:k and 10 mm (printed) round it, the same as its limits
    # below, so that the drawing is at the scale the bar shows
    w_in, h_in = (ext_mm / k + 20.0) / _MM
    left = (_PAGE[0] - w_in) / 2
    bottom = min(max(0.62 * _PAGE[1] - h_in / 2, lo_band), hi_band - h_in)  # between the scale bar and the heading
    ax = fig.add_axes([left / _PAGE[0], bottom / _PAGE[1], w_in / _PAGE[0], h_in / _PAGE[1]])
    shaded(ax, d.triangles, d.face_normals, B)
    pad = 0.010 * k  # m on the prop: 10 mm printed
    ax.set_xlim(lo2[0] - pad, hi2[0] + pad)
    ax.set_ylim(lo2[1] - pad, hi2[1] + pad)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for sp in ax.spines.values():
        sp.set_visible(False)
    near = ~np.asarray(d.hidden.get(best, np.zeros(len(d.marker_points), bool)), bool)
    pts = d.marker_points @ B.T
    labels = []
    for i, p in enumerate(pts):
        col = "k" if near[i] else "0.55"
        r = 0.0015 * k  # 1.5 mm printed each way: a crosshair 3 mm across
        ax.plot([p[0] - r, p[0] + r], [p[1], p[1]], color=col, lw=0.6)
        ax.plot([p[0], p[0]], [p[1] - r, p[1] + r], color=col, lw=0.6)
        labels.append(ax.text(p[0] + 1.2 * r, p[1] + 1.2 * r, str(i + 1), color=col, ha="left", va="bottom",
                              **TEXT_STYLES["number"]))  # fmt: skip
    cross_pt = 3.0 / _MM * 72.0 + 1.0  # a crosshair, 3 mm across printed, in points (the page is drawn 1:1)
    declutter(ax, [], labels, [], [(p[:2], cross_pt) for p in pts])
    # the scale bar: 50 mm on the prop (printed 50 / k mm), ticks every 10 mm
    _scale_bar(fig, [0.06, 0.08, (50.0 / k) / _MM / _PAGE[0], 0.02], 50.0, range(0, 51, 10))
    fig.text(0.06, 0.05, f"scale bar: 50 mm on the prop, ticks every 10 mm, printed at 1:{k}", va="top",
             **TEXT_STYLES["caption"])  # fmt: skip
    fig.text(0.02, 0.975, f"Template, {best}, scale 1:{k}: print at 100 % (no 'fit to page') and check the scale bar "
             "with a ruler", va="top", **TEXT_STYLES["heading"])  # fmt: skip
    fig.text(0.02, 0.94, "+ the base centre of each marker (grey: on the far side of the prop in this view)" + (
        "; cut the outline out to lay on the prop" if k == 1 else "; the prop is larger than the sheet at 1:1"),
        va="top", **TEXT_STYLES["caption"])  # fmt: skip
    return fig


@drawing
def guide_files(res, folder: str | Path, split: bool = False) -> list[str]:
    """Write ``guide.pdf`` (every page) and ``guide.png`` (page 1) into ``folder``.

    ``split``: for a process of its own that draws only the guide (a render process): once page
    1 is laid out, a forked copy of it lays out the template page and writes the PDF while it
    writes the PNG, on another core (the same bytes as one after the other; one after the other
    where it cannot fork)."""
    d = plot_data(res)
    first = _first_page(d)
    pid = fork_helper() if split and can_fork() else None
    if pid == 0:  # the PDF's process: never returns
        code = 1
        try:
            _write_pdf([first, _template_page(d)], folder)
            code = 0
        finally:
            os._exit(code)
    save_png(first, Path(folder) / "guide.png", dpi=_DPI)
    pages = [first]
    if pid is None:
        pages.append(_template_page(d))
        _write_pdf(pages, folder)
    else:
        status = os.waitpid(pid, 0)[1]
        release(pid)
        if status != 0:
            raise RuntimeError("writing guide.pdf failed in its process")
    for fig in pages:
        discard(fig)
    return ["guide.png", "guide.pdf"]


def _write_pdf(pages, folder: str | Path) -> None:
    import io

    from matplotlib.backends.backend_pdf import PdfPages

    from starforge.io import atomic_write_bytes

    buf = io.BytesIO()
    with _pdf_fonts(pages), PdfPages(buf, metadata={"Creator": None, "Producer": None, "CreationDate": None}) as pdf:
        for fig in pages:
            pdf.savefig(fig)
    atomic_write_bytes(Path(folder) / "guide.pdf", buf.getvalue())


@drawing
def load_fonts() -> None:
    """Draw a line in every text style of the guide into a PNG and a PDF that are thrown away, so
    that the fonts (and the PDF's standard-font metrics) are found and loaded before the guide is
    drawn (its render process does this while the placement still runs; the guide is the same)."""
    import io

    fig = figure(figsize=(1, 1))
    for kw in TEXT_STYLES.values():
        fig.text(0.5, 0.5, "0123456789 mm", **kw)
    fig.savefig(io.BytesIO(), format="png", dpi=_DPI)
    with _pdf_fonts([fig]):
        fig.savefig(io.BytesIO(), format="pdf")
    discard(fig)


def _pdf_fonts(figs):
    """The PDF's text in PDF's standard fonts (Helvetica, Courier: every reader has them) rather
    than embedded subsets of DejaVu: no fontTools import and no subsetting (about 0.3-0.5 s of
    a CLI run's critical path) and a file a third the size.  Only where every string on the
    page is Latin-1 (what the standard fonts cover); otherwise the embedded fonts."""
    import contextlib
    import logging

    import matplotlib

    texts = [t.get_text() for f in figs for t in f.findobj(lambda a: hasattr(a, "get_text") and hasattr(a, "get_fontname"))]
    try:
        "".join(texts).encode("latin-1")
    except UnicodeEncodeError:
        return contextlib.nullcontext()
    stack = contextlib.ExitStack()
    stack.enter_context(matplotlib.rc_context({"pdf.use14corefonts": True}))
    log = logging.getLogger("matplotlib.font_manager")  # 'no normal weight of Helvetica, using medium'
    level = log.level
    log.setLevel(logging.ERROR)
    stack.callback(log.setLevel, level)
    return stack
