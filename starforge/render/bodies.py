"""Pictures of printable star bodies: one PNG per body and a sheet of all of them with their ids.

Drawn with matplotlib (Agg, imported inside the functions) from a coarse manifold3d mesh of
the same body description the STL/3MF come from.  The body stands on its mount (+y up in the
placement frame is up in the picture); the finished (coated) marker outlines are drawn as the
printed spheres, the engraved id is visible on the plate.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

_DPI = 110


def _view_triangles(body, segments: int = 20, edge_mm: float = 0.8) -> np.ndarray:
    """(m, 3, 3) triangles of a coarse mesh, in the picture frame (x, -z, y): +y up."""
    from starforge.cad.mesh import body_manifold, manifold_arrays
    from starforge.cad.plate import TO_BED

    # even-sized triangles: matplotlib sorts whole triangles by depth, long slivers misdraw
    solid = body_manifold(body, sphere_segments=segments, cylinder_segments=12).refine_to_length(edge_mm)
    v, f = manifold_arrays(solid)
    return (v @ TO_BED.T)[f]


def _draw(ax, tris: np.ndarray, title: str, half: float | None = None, zoom: float = 1.45,
          title_size: float = 14) -> None:
    """Shaded triangles; ``half`` is the half-size of the view cube, mm (one scale for a sheet)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([0.3, -0.5, 0.8])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(n @ light, 0, 1)
    colors = np.column_stack([0.55 * shade, 0.62 * shade, 0.75 * shade, np.ones_like(shade)])
    # each triangle's edge in its own colour: no light seams between the triangles (the streaks)
    ax.add_collection3d(Poly3DCollection(tris, facecolors=colors, edgecolors=colors, linewidths=0.3))
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    mid = (lo + hi) / 2
    half = (hi - lo).max() / 2 if half is None else half
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1), zoom=zoom)  # the view cube's corners lie far outside the body
    ax.view_init(elev=50, azim=-60)
    ax.set_axis_off()
    ax.set_title(title, fontsize=title_size, fontweight="bold", pad=0)


def render_body_png(body, path: str | Path, size_px: int = 480) -> Path:
    """One body, three-quarter view, title ``star <id> (<mount>)``; written to ``path``."""
    from starforge.render._mpl import pyplot, save_png

    plt = pyplot()
    fig = plt.figure(figsize=(size_px / _DPI, size_px / _DPI), dpi=_DPI)
    try:
        ax = fig.add_axes((0.0, 0.0, 1.0, 0.92), projection="3d")
        _draw(ax, _view_triangles(body), f"star {body.star_id} ({body.mount})")
        save_png(fig, path, dpi=_DPI)
    finally:
        plt.close(fig)
    return Path(path)


def render_sheet_png(bodies, path: str | Path, cell_px: int = 240, box_mm=None) -> Path:
    """All bodies on one sheet at one scale (the largest body fills its cell), titled with ids."""
    from starforge.render._mpl import pyplot, save_png

    plt = pyplot()
    n = len(bodies)
    cols = min(n, 6)
    rows = math.ceil(n / cols)
    tris = [_view_triangles(b, segments=12, edge_mm=1.5) for b in bodies]
    half = max(float((t.reshape(-1, 3).max(0) - t.reshape(-1, 3).min(0)).max()) for t in tris) / 2
    fig = plt.figure(figsize=(cols * cell_px / _DPI, rows * cell_px / _DPI), dpi=_DPI)
    try:
        for k, (b, t) in enumerate(zip(bodies, tris, strict=True)):
            r, c = divmod(k, cols)
            ax = fig.add_axes((c / cols, 1 - (r + 1) / rows, 1 / cols, 0.9 / rows), projection="3d")
            _draw(ax, t, f"star {b.star_id}", half=half, title_size=11)
        fig.text(0.01, 0.01, f"one scale: each cell spans {2 * half:.1f} mm", fontsize=7)
        save_png(fig, path, dpi=_DPI)
    finally:
        plt.close(fig)
    return Path(path)


def render_previews(bodies, folder: str | Path, box_mm=None) -> list[Path]:
    """``folder/<body>.png`` per body and ``folder/sheet.png`` (:func:`render_sheet_png`), as
    progress stage "preview" (:mod:`starforge.runtime.progress`).  ``box_mm``: the family's size
    limit, drawn on the sheet against each body's outline."""
    from starforge.runtime import progress

    folder = Path(folder)
    folder.mkdir(exist_ok=True)
    written = []
    with progress.stage("preview", total=len(bodies) + 1, unit="pictures") as st:
        for b in bodies:
            written.append(render_body_png(b, folder / f"{b.name}.png"))
            st.update(advance=1)
        written.append(render_sheet_png(bodies, folder / "sheet.png", box_mm=box_mm))
        st.update(advance=1)
    return written
