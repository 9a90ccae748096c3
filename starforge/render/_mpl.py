"""What every picture needs: figures on matplotlib's Agg canvas without pyplot (imported only
when a picture is drawn), its text settings scoped to the drawing, and a byte-stable, atomic
PNG write."""

from __future__ import annotations

import functools
import io
from pathlib import Path

#: the text settings every picture is drawn with (:func:`drawing`): unhinted glyphs sit where the
#: font puts them, as in the PDFs (whose text the PNG's layout measures for them), and FreeType's
#: auto-hinter, much of the time a text-heavy page takes to draw, does not run
RC = {"text.hinting": "no_hinting"}


def drawing(fn):
    """Run ``fn`` (a function that draws pictures) with :data:`RC` and without a warning per
    glyph its fonts lack (a CJK prop or file name in a title is drawn as boxes: the name is
    written in full in the text outputs), both undone when it returns: a notebook's own figures
    and settings are left as they were."""

    @functools.wraps(fn)
    def draw(*args, **kwargs):
        import warnings

        import matplotlib

        with matplotlib.rc_context(RC), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font", category=UserWarning)
            return fn(*args, **kwargs)

    return draw


def figure(**kwargs):
    """A matplotlib ``Figure`` (``kwargs`` as ``Figure`` takes them) on an Agg canvas of its own:
    not pyplot's, so drawing switches no backend and registers no figure with pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def subplots(nrows: int = 1, ncols: int = 1, *, sharex=False, sharey=False, squeeze: bool = True,
             subplot_kw=None, gridspec_kw=None, **fig_kw):
    """``(fig, axes)`` as ``pyplot.subplots`` returns them, the figure made by :func:`figure`."""
    fig = figure(**fig_kw)
    axes = fig.subplots(nrows, ncols, sharex=sharex, sharey=sharey, squeeze=squeeze, subplot_kw=subplot_kw, gridspec_kw=gridspec_kw)
    return fig, axes


def discard(fig) -> None:
    """Drop ``fig``'s artists, so that their arrays are freed at once by reference counting, not
    at the next garbage collection (commands run with the collector paused)."""
    fig.clear()


#: zlib level of the PNGs: on these flat-coloured pictures level 3 compresses several times faster
#: than zlib's default (6) into files of about the same size (the pixels are the same either way)
PNG_COMPRESS_LEVEL = 3


def save_png(fig, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG atomically; no 'Software' metadata, so the same figure gives the same bytes."""
    from starforge.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(
        buf, format="png", dpi=dpi, metadata={"Software": None}, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL}
    )
    return atomic_write_bytes(path, buf.getvalue())


def wrap_to_width(fig, text_artist, fraction: float = 0.96) -> None:
    """Break ``text_artist``'s text into lines (at spaces) until it is no wider than ``fraction``
    of its axes (of the figure for a figure's text): a long title fits instead of being cut at the
    edge."""
    import textwrap

    full = text_artist.get_text()
    renderer = fig.canvas.get_renderer()
    limit = fraction * (text_artist.axes or fig).bbox.width
    width = len(full)
    while width > 20 and text_artist.get_window_extent(renderer).width > limit:
        width = int(width * 0.85)
        text_artist.set_text("\n".join(textwrap.wrap(full, width)))


def boxes_overlap(a, b, pad: float = 0.5) -> bool:
    """Two display boxes (``Bbox``) overlap by more than ``pad`` pixels both ways."""
    return min(a.x1, b.x1) - max(a.x0, b.x0) > pad and min(a.y1, b.y1) - max(a.y0, b.y0) > pad


def label_box(t, renderer):
    """A text's display box; for a text drawn in a frame (a marker's number in its circle), the
    frame's box, which is larger than the text's: the frame's box style applied to the text's box
    as matplotlib draws it for an unrotated text (without placing the patch, which is slow)."""
    from matplotlib.transforms import Bbox

    box = t.get_window_extent(renderer)
    patch = t.get_bbox_patch()
    if patch is None:
        return box
    path = patch.get_boxstyle()(box.x0, box.y0, box.width, box.height, renderer.points_to_pixels(t.get_size()))
    v = path.vertices
    return Bbox.from_extents(*v.min(axis=0), *v.max(axis=0))


def text_boxes(fig) -> list[tuple[str, tuple[float, float, float, float]]]:
    """Every text ``fig`` draws with its box in pixels (x0, y0, x1, y1), its frame's where it has
    one (:func:`label_box`): titles, labels, the tick labels inside the axes' limits, legend
    entries, free text; for checking that none overlaps another or leaves the figure."""
    from matplotlib.text import Text

    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    ticks, shown = set(), set()
    for ax in fig.axes:
        for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                labels = {id(tick.label1), id(tick.label2)}
                ticks |= labels
                if ax.axison and min(lo, hi) - 1e-9 <= tick.get_loc() <= max(lo, hi) + 1e-9:
                    shown |= labels
    out = []
    for t in fig.findobj(Text):
        if not t.get_visible() or not t.get_text().strip() or (id(t) in ticks and id(t) not in shown):
            continue
        if t.axes is not None and not t.axes.get_visible():
            continue
        b = label_box(t, renderer)
        out.append((t.get_text(), (float(b.x0), float(b.y0), float(b.x1), float(b.y1))))
    return out
