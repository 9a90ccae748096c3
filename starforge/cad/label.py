"""The engraved star id: a pixel font whose strokes and counters print at the chosen nozzle.

Every glyph is 3 x 5 square pixels of side ``pixel_mm``; a stroke, a counter (the raised island
inside a 0, 6, 8, 9) and the gap between two strokes are whole pixels, so none is narrower than
one pixel.  :func:`pixel_mm` makes a pixel at least 2 nozzle widths (an extrusion is about 1.1
nozzle widths in PrusaSlicer's defaults), so the slicer keeps every counter and every groove.
Seven-segment digits (the previous engraving) left a counter of 0.19 x the digit height and cut
overlapping segment boxes whose faces met at nearly, not exactly, equal coordinates: slivers
that became non-manifold edges once the STL rounded them to float32.  Here a glyph is cut as
non-overlapping rectangles (pixel runs merged), every corner computed from integer pixel
indices by one formula on a dyadic grid (:data:`GRID_MM`, 1/1024 mm: the pixel and the label's
corner are multiples of it), so every box corner, centre and half-size is exact in binary
floating point (and in the STL's float32) and neighbouring rectangles share faces exactly.

Reading direction (placement frame, see :mod:`starforge.cad.body`): the label is read from
above (+y), up the page is -z and the reader's right +x.  In the printing orientation
(:func:`starforge.cad.plate.print_transform`: x -> X, -z -> Y) that is the bed seen from above
with +Y up the page: the slicer's top view, and a person in front of the printer.
"""

from __future__ import annotations

from starforge.cad.primitives import Box
from starforge.errors import StarforgeError

#: glyphs, 5 rows of 3 pixels, top row first ("#" = engraved)
FONT = {
    "0": ("###", "#.#", "#.#", "#.#", "###"),
    "1": (".#.", "##.", ".#.", ".#.", "###"),
    "2": ("###", "..#", "###", "#..", "###"),
    "3": ("###", "..#", ".##", "..#", "###"),
    "4": ("#.#", "#.#", "###", "..#", "..#"),
    "5": ("###", "#..", "###", "..#", "###"),
    "6": ("###", "#..", "###", "#.#", "###"),
    "7": ("###", "..#", "..#", "..#", "..#"),
    "8": ("###", "#.#", "###", "#.#", "###"),
    "9": ("###", "#.#", "###", "..#", "###"),
    "-": ("...", "...", "###", "...", "..."),
}
COLS, ROWS = 3, 5
#: pixels between two glyphs
GAP = 1
#: a pixel is at least this many nozzle widths (strokes, counters and gaps are whole pixels):
#: Slic3r 1.3 at a 0.4 mm nozzle dropped 0.6 mm counters (1.5 widths) and kept 0.75 mm ones
PIXEL_PER_NOZZLE = 2.0
#: every label coordinate is a multiple of this, mm (exact in float32 below 16 m)
GRID_MM = 1.0 / 1024


def _snap(v: float, up: bool = False) -> float:
    import math

    k = v / GRID_MM
    return (math.ceil(k) if up else round(k)) * GRID_MM


def pixel_mm(label_mm: float, nozzle_mm: float) -> float:
    """Pixel side in effect, mm: ``label_mm / 5`` (the digit height asked for), at least
    :data:`PIXEL_PER_NOZZLE` nozzle widths."""
    return _snap(max(label_mm / ROWS, PIXEL_PER_NOZZLE * nozzle_mm), up=True)


def _check(text: str) -> None:
    bad = [ch for ch in text if ch not in FONT]
    if bad or not text:
        raise StarforgeError(f"label text may hold digits and '-', got {text!r}")


def glyph_rects(ch: str) -> list[tuple[int, int, int, int]]:
    """The engraved pixels of glyph ``ch`` as non-overlapping rectangles ``(c0, r0, c1, r1)``
    (columns ``c0 <= c < c1``, rows ``r0 <= r < r1``, row 0 at the top): runs along each row,
    merged down the rows while the run repeats."""
    _check(ch)
    runs: list[tuple[int, int, int]] = []  # (row, c0, c1)
    for r, row in enumerate(FONT[ch]):
        c = 0
        while c < COLS:
            if row[c] == "#":
                c0 = c
                while c < COLS and row[c] == "#":
                    c += 1
                runs.append((r, c0, c))
            else:
                c += 1
    rects: list[list[int]] = []
    for r, c0, c1 in runs:
        for rect in rects:
            if rect[0] == c0 and rect[2] == c1 and rect[3] == r:
                rect[3] = r + 1
                break
        else:
            rects.append([c0, r, c1, r + 1])
    return [tuple(x) for x in rects]


def glyph_counters(ch: str) -> list[tuple[int, int]]:
    """Pixels ``(c, r)`` of ``ch`` left standing and enclosed by its strokes (4-connected: not
    reachable from outside the glyph's cell): the counters of 0, 4, 6, 8, 9."""
    _check(ch)
    rows = FONT[ch]
    free = {(c, r) for r in range(ROWS) for c in range(COLS) if rows[r][c] == "."}
    outside = {p for p in free if p[0] in (0, COLS - 1) or p[1] in (0, ROWS - 1)}
    todo = list(outside)
    while todo:
        c, r = todo.pop()
        for q in ((c + 1, r), (c - 1, r), (c, r + 1), (c, r - 1)):
            if q in free and q not in outside:
                outside.add(q)
                todo.append(q)
    return sorted(free - outside)


def label_size(text: str, height_mm: float) -> tuple[float, float]:
    """(width along x, height along z) of the label, mm, for glyphs ``height_mm`` tall."""
    p = _snap(height_mm / ROWS)
    n = len(text)
    return (p * (n * COLS + (n - 1) * GAP), height_mm)


def _origin(text: str, p: float, centre_xz) -> tuple[float, float]:
    w, h = label_size(text, p * ROWS)
    return (_snap(float(centre_xz[0]) - w / 2), _snap(float(centre_xz[1]) - h / 2))


def _placed(text: str, height_mm: float, centre_xz, cells) -> list[tuple[float, float, float, float]]:
    """Glyph cells ``(c0, r0, c1, r1)`` (pixels, from ``cells(ch)``) of every character of the
    label, as ``(x0, x1, z0, z1)`` rectangles in mm in the plate plane."""
    _check(text)
    p = _snap(height_mm / ROWS)
    x_left, z_top = _origin(text, p, centre_xz)
    out = []
    for k, ch in enumerate(text):
        base = k * (COLS + GAP)
        for c0, r0, c1, r1 in cells(ch):
            out.append((x_left + (base + c0) * p, x_left + (base + c1) * p, z_top + r0 * p, z_top + r1 * p))
    return out


def label_rects(text: str, height_mm: float, centre_xz) -> list[tuple[float, float, float, float]]:
    """Engraved rectangles ``(x0, x1, z0, z1)``, mm, in the plate plane (read from +y, up the
    page -z: the first row has the smallest z)."""
    return _placed(text, height_mm, centre_xz, glyph_rects)


def label_counters(text: str, height_mm: float, centre_xz) -> list[tuple[float, float, float, float]]:
    """Counter pixels ``(x0, x1, z0, z1)``, mm, of the label (what must stay standing)."""
    return _placed(text, height_mm, centre_xz, lambda ch: [(c, r, c + 1, r + 1) for c, r in glyph_counters(ch)])


def label_boxes(text: str, height_mm: float, centre_xz, y_top: float, depth_mm: float) -> list[Box]:
    """Engraving boxes for ``text`` on the face y = ``y_top``: ``depth_mm`` deep, reaching 0.1 mm
    above the face (a clean cut that stays below any sphere: ``standoff_mm`` >= 0.2)."""
    yc, hy = y_top - depth_mm / 2 + 0.05, depth_mm + 0.1
    return [
        Box(((x0 + x1) / 2, yc, (z0 + z1) / 2), (x1 - x0, hy, z1 - z0))
        for x0, x1, z0, z1 in label_rects(text, height_mm, centre_xz)
    ]
