"""Dimensioned drawings of rigid bodies (to rebuild a tool): three orthographic views of the
markers in the file's own frame, every pairwise distance drawn in the top view (up to
:data:`MAX_DRAWN_PAIRS` pairs) and tabulated, and a table of marker coordinates; one page per
body in a PDF, one PNG per body, and the same numbers in a CSV.  Lengths in mm."""

from __future__ import annotations

import csv
import io
import itertools
from pathlib import Path

import numpy as np

from starforge.render._mpl import discard, drawing, figure, save_png

#: pairs whose dimension lines are drawn in the top view (more would hide the markers)
MAX_DRAWN_PAIRS = 15
_VIEWS = (("top (x, y)", 0, 1), ("front (x, z)", 0, 2), ("side (y, z)", 1, 2))
_DPI = 110


def pair_distances(points_mm) -> list[tuple[int, int, float]]:
    """(i, j, distance mm) of every marker pair i < j of ``points_mm`` (n, 3) mm."""
    P = np.asarray(points_mm, dtype=float)
    return [(i, j, float(np.linalg.norm(P[i] - P[j]))) for i, j in itertools.combinations(range(len(P)), 2)]


def dimensions_csv(bodies) -> str:
    """``body,kind,a,b,x_mm,y_mm,z_mm,distance_mm`` rows: each marker (kind ``marker``, a = its
    number from 1, b = its name) and each pair (kind ``distance``, a and b the marker numbers)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["body", "kind", "a", "b", "x_mm", "y_mm", "z_mm", "distance_mm"])
    for name, P, names in bodies:
        for i, p in enumerate(np.asarray(P, dtype=float)):
            w.writerow([name, "marker", i + 1, names[i] if names else "", *(f"{v:.6f}" for v in p), ""])
        for i, j, d in pair_distances(P):
            w.writerow([name, "distance", i + 1, j + 1, "", "", "", f"{d:.6f}"])
    return buf.getvalue()


def _draw(fig, name: str, P: np.ndarray, names, source: str) -> None:
    n = len(P)
    grid = fig.add_gridspec(2, 3, height_ratios=[1.0, 1.0])
    pad = 0.15 * max(1.0, float(np.ptp(P, axis=0).max()))
    pairs = pair_distances(P)
    for k, (title, a, b) in enumerate(_VIEWS):
        ax = fig.add_subplot(grid[0, k])
        if k == 0 and len(pairs) <= MAX_DRAWN_PAIRS:
            for i, j, d in pairs:
                ax.plot(P[[i, j], a], P[[i, j], b], color="0.6", lw=0.7, zorder=1)
                mid = 0.5 * (P[i] + P[j])
                ax.annotate(
                    f"{d:.2f}",
                    (mid[a], mid[b]),
                    fontsize=6,
                    color="C3",
                    ha="center",
                    va="center",
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8},
                )
        ax.scatter(P[:, a], P[:, b], s=40, color="C0", zorder=2)
        for i in range(n):
            ax.annotate(str(i + 1), (P[i, a], P[i, b]), xytext=(4, 4), textcoords="offset points", fontsize=8)
        ax.plot([0], [0], "+", color="k", ms=8)  # the body's origin
        half = 0.5 * float(max(np.ptp(P[:, a]), np.ptp(P[:, b]))) + pad  # the same scale on both axes
        mid_a, mid_b = 0.5 * (P[:, a].min() + P[:, a].max()), 0.5 * (P[:, b].min() + P[:, b].max())
        ax.set_xlim(mid_a - half, mid_a + half)
        ax.set_ylim(mid_b - half, mid_b + half)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(f"{'xyz'[a]} [mm]", fontsize=8)
        ax.set_ylabel(f"{'xyz'[b]} [mm]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    rows = [[str(i + 1), (names[i] if names else "")[:18], *(f"{v:.3f}" for v in P[i])] for i in range(n)]
    ax = fig.add_subplot(grid[1, :2])
    ax.axis("off")
    table = ax.table(cellText=rows, colLabels=["#", "name", "x [mm]", "y [mm]", "z [mm]"], loc="upper center")
    table.auto_set_font_size(False)
    table.set_fontsize(7)
    ax = fig.add_subplot(grid[1, 2])
    ax.axis("off")
    shown = pairs[:30]
    table = ax.table(
        cellText=[[f"{i + 1}-{j + 1}", f"{d:.3f}"] for i, j, d in shown],
        colLabels=["pair", "distance [mm]"],
        loc="upper center",
    )
    table.auto_set_font_size(False)
    table.set_fontsize(7)
    more = f" ({len(pairs) - len(shown)} more pairs in dimensions.csv)" if len(pairs) > len(shown) else ""
    fig.suptitle(f"{name}: {n} markers, from {Path(source).name}{more}", fontsize=10)


@drawing
def write_drawings(bodies, folder) -> list[Path]:
    """For ``bodies`` [(name, (n, 3) mm, marker names or None, source)] write into ``folder``:
    ``drawing.pdf`` (a page per body), ``<name>.png`` per body and ``dimensions.csv``
    (:func:`dimensions_csv`).  Returns the paths written."""
    from matplotlib.backends.backend_pdf import PdfPages

    from starforge.io import atomic_write_text

    folder = Path(folder)
    out = []
    pdf_path = folder / "drawing.pdf"
    with PdfPages(pdf_path, metadata={"CreationDate": None, "ModDate": None}) as pdf:
        for name, P, names, source in bodies:
            fig = figure(figsize=(11.69, 8.27))  # A4 landscape, inches
            try:
                _draw(fig, name, np.asarray(P, dtype=float), names, source)
                pdf.savefig(fig)
                out.append(save_png(fig, folder / f"{name}.png", dpi=_DPI))
            finally:
                discard(fig)
    out.append(pdf_path)
    out.append(atomic_write_text(folder / "dimensions.csv", dimensions_csv([b[:3] for b in bodies])))
    return out
