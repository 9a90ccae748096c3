"""Family sheet: every star (or the first ``limit``) drawn from two sides, labelled by id."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from starforge.render._mpl import drawing

_EDGES = [(0, 1), (2, 3), (1, 2), (0, 3), (0, 2), (1, 3)]


def _nice_length(mm: float) -> float:
    """The largest 1, 2 or 5 x 10^k mm that is at most ``mm`` (a scale bar's length)."""
    k = 10 ** np.floor(np.log10(mm))
    return float(max(m * k for m in (1, 2, 5) if m * k <= mm))


@drawing
def family_sheet(family, path: str | Path, limit: int = 40, cols: int = 8) -> Path:
    """Write a PNG: for each star, its xz view (long side vertical) and xy view, to scale.

    Parameters
    ----------
    family : starforge.stars.model.Family
    path : output PNG path (written as given; callers stage it)
    limit : int  how many stars (the most compact come first in a family)
    cols : int   stars per row
    """
    from matplotlib.patches import Circle, Rectangle

    from starforge.render._mpl import discard, save_png, subplots

    stars = family.stars[:limit]
    rows = max(1, int(np.ceil(len(stars) / cols)))
    box = np.sort(np.asarray(family.spec.box_mm, dtype=float))  # short, middle, long
    r = family.spec.marker_mm / 2
    fig, axes = subplots(rows, cols, figsize=(cols * 1.55, rows * 2.35), squeeze=False)
    for ax in axes.ravel():
        ax.set_axis_off()
    # physical limit around the star: x spans the middle side, z the long side
    xw, zl = box[1], box[2]
    bar = _nice_length(xw / 2)  # scale bar, mm
    bar_room = 4.0  # mm under each cell's limit (the bar's row)
    for ax, s in zip(axes.ravel(), stars, strict=False):
        V = s.vertices
        ext = s.obb_extents
        ax.add_patch(
            Rectangle((-xw / 2, -r - (zl - ext[2] - 2 * r) / 2), xw, zl, fill=False, lw=0.6, ls="--", ec="0.6")
        )
        for a, b in _EDGES:
            ax.plot(V[[a, b], 0], V[[a, b], 2], color="0.45", lw=0.8, zorder=1)
        order = np.argsort(V[:, 1])  # draw far spheres first
        for k in order:
            ax.add_patch(Circle((V[k, 0], V[k, 2]), r, color="#2b6cb0", ec="white", lw=0.5, zorder=2 + V[k, 1]))
        bottom = -r - (zl - ext[2] - 2 * r) / 2
        ax.set_xlim(-xw / 2 - 1, xw / 2 + 1)
        ax.set_ylim(bottom - 1 - bar_room, bottom + zl + 1)  # every cell the same size: one scale
        ax.set_aspect("equal")
        ax.set_title(f"{s.id}", fontsize=9, pad=1, fontweight="bold")
    # a mm scale bar under the first star (all cells share its scale)
    ax0 = axes.ravel()[0]
    s0 = stars[0]
    y_bar = -r - (zl - s0.obb_extents[2] - 2 * r) / 2 - 1 - bar_room / 2
    ax0.plot([-xw / 2, -xw / 2 + bar], [y_bar, y_bar], color="black", lw=2, solid_capstyle="butt")
    ax0.text(-xw / 2 + bar + 1, y_bar, f"{bar:g} mm", fontsize=7, va="center", ha="left")
    sp = family.spec
    fig.suptitle(
        f"{sp.name}: {len(family)} stars (showing {len(stars)}), rule {sp.rule}, "
        f"limit {' x '.join(f'{b:g}' for b in sp.box_mm)} mm (dashed), {sp.marker_mm:g} mm markers; "
        f"one scale, bar {bar:g} mm",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    save_png(fig, path, dpi=110)
    discard(fig)
    return Path(path)
