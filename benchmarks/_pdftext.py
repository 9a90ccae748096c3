"""Text in a written PDF as a reader finds it: every glyph's box per page, read by pdfminer.six
(independent of the matplotlib that drew the file), and the glyphs that overlap.

Layout analysis is off, so glyphs of two strings are never merged into one line: two strings
drawn over each other show as overlapping glyphs.  Each box is shrunk by a fifth of its size per
side before the test, so neighbouring glyphs of one word only touch."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SHRINK = 0.2


def glyph_boxes(path: str | Path) -> list[tuple[tuple[float, float], list[tuple[str, tuple]]]]:
    """[((page width, page height), [(glyph, (x0, y0, x1, y1)), ...]) per page], in points."""
    from pdfminer.high_level import extract_pages
    from pdfminer.layout import LTChar

    def glyphs(el):
        if isinstance(el, LTChar):
            yield el
        elif hasattr(el, "__iter__"):
            for x in el:
                yield from glyphs(x)

    pages = []
    for page in extract_pages(str(path), laparams=None):
        boxes = [(c.get_text(), (c.x0, c.y0, c.x1, c.y1)) for c in glyphs(page) if c.get_text().strip()]
        pages.append(((page.width, page.height), boxes))
    return pages


def overlapping_glyphs(boxes) -> list[tuple[int, int]]:
    """Index pairs (i < j) of the boxes (x0, y0, x1, y1) that overlap once each is shrunk."""
    b = np.array(boxes, dtype=float).reshape(-1, 4)
    w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
    s = np.stack([b[:, 0] + SHRINK * w, b[:, 1] + SHRINK * h, b[:, 2] - SHRINK * w, b[:, 3] - SHRINK * h], axis=1)
    ix = np.minimum(s[:, None, 2], s[None, :, 2]) - np.maximum(s[:, None, 0], s[None, :, 0])
    iy = np.minimum(s[:, None, 3], s[None, :, 3]) - np.maximum(s[:, None, 1], s[None, :, 1])
    return [tuple(map(int, p)) for p in np.argwhere(np.triu((ix > 0) & (iy > 0), 1))]


def off_page(page) -> list[str]:
    """The glyphs of one page (an item of :func:`glyph_boxes`) that leave the page."""
    (W, H), glyphs = page
    return [g for g, (x0, y0, x1, y1) in glyphs if x0 < -0.5 or y0 < -0.5 or x1 > W + 0.5 or y1 > H + 0.5]
