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

from starforge.cad.body import body_bounds, body_name
from starforge.render._mpl import drawing

_DPI = 110


#: bodies up to this size, mm, are drawn with the triangles' own edge length; larger ones with
#: edges in proportion
VIEW_SPAN_MM = 64.0


def _view_triangles(body, segments: int = 20, edge_mm: float = 0.8) -> np.ndarray:
    """(m, 3, 3) triangles of a coarse mesh, in the picture frame (x, -z, y): +y up."""
    from starforge.cad.mesh import body_manifold, manifold_arrays
    from starforge.cad.plate import TO_BED

    # even-sized triangles: matplotlib sorts whole triangles by depth, long slivers misdraw; on a
    # body larger than a star's (a lab's tool) they grow with it, so a picture keeps about a
    # star's count of them (matplotlib's drawing time grows with the count)
    solid = body_manifold(body, sphere_segments=segments, cylinder_segments=12)
    span = float(np.ptp(body_bounds(body), axis=0).max())
    solid = solid.refine_to_length(max(edge_mm, edge_mm * span / VIEW_SPAN_MM))
    v, f = manifold_arrays(solid)
    return (v @ TO_BED.T)[f]


#: light for the shaded views: from above and the viewer's left, so that an engraving's walls
#: (the id) are dark against the face they are cut into
_LIGHT = np.array([0.45, -0.55, 0.7]) / np.linalg.norm([0.45, -0.55, 0.7])
_BODY_RGB = np.array([0.93, 0.72, 0.35])  # a light warm tone: dark engraving edges read on it
#: faces this far below the label's face, mm, are the engraving's floor in the top views
ENGRAVED_MIN_MM, ENGRAVED_MAX_MM = 0.05, 3.0


def _shades(tris: np.ndarray) -> np.ndarray:
    """(m, 4) RGBA per triangle: the body colour lit by :data:`_LIGHT` (strong contrast)."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = 0.18 + 0.82 * np.clip(n @ _LIGHT, 0, 1) ** 1.5
    return np.column_stack([np.outer(shade, _BODY_RGB), np.ones_like(shade)])


def _draw(ax, tris: np.ndarray, title: str, half: float | None = None, zoom: float = 1.45,
          title_size: float = 14) -> None:
    """Shaded triangles, three-quarter view; ``half`` is the half-size of the view cube, mm (one
    scale for several pictures)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colors = _shades(tris)
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


def _top(ax, tris: np.ndarray, face_mm: float | None = None) -> None:
    """The body seen from above (picture x right, y up the page), drawn in 2D: triangles painted
    from the lowest to the highest.  ``face_mm``: the height of the face the id is engraved in;
    what lies just below it (the engraving's floor) is drawn dark, so the id reads from above."""
    from matplotlib.collections import PolyCollection

    up = tris[:, :, 2].mean(axis=1)
    facing = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])[:, 2] > 0
    order = np.argsort(up[facing], kind="stable")
    t = tris[facing][order]
    colors = _shades(t)
    if face_mm is not None:
        z = t[:, :, 2].mean(axis=1)
        colors[(z < face_mm - ENGRAVED_MIN_MM) & (z > face_mm - ENGRAVED_MAX_MM), :3] = 0.12
    ax.add_collection(PolyCollection(t[:, :, :2], facecolors=colors, edgecolors=colors, linewidths=0.3))
    ax.set_aspect("equal")
    ax.set_axis_off()


def _limit_xy(body, limit_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(size (3,), the limit's side matched to each axis (3,), centre (3,)) of ``body`` in its
    placement frame, mm: the sides are matched by rank, as the fit check does
    (:func:`starforge.cad.body.fit_report`)."""
    from starforge.cad.body import body_bounds

    b = body_bounds(body)
    size = b[1] - b[0]
    matched = np.empty(3)
    matched[np.argsort(size, kind="stable")] = np.sort(np.asarray(limit_mm, float))
    return size, matched, (b[0] + b[1]) / 2


def _limit_box(ax, body, limit_mm) -> bool:
    """Draw the size limit's rectangle around the top view (x and z sides of the placement frame,
    matched by rank); True when the body fits the limit."""
    from matplotlib.patches import Rectangle

    from starforge.tol import tol

    size, matched, c = _limit_xy(body, limit_mm)
    fits = bool(np.all(np.sort(size) <= np.sort(matched) + tol.length_mm))
    # picture frame (x, -z, y): the top view's axes are placement x and -z
    w, h = matched[0], matched[2]
    ax.add_patch(Rectangle((c[0] - w / 2, -c[2] - h / 2), w, h, fill=False, lw=1.2, ls="--",
                           edgecolor="#1a7f37" if fits else "#cf222e"))
    return fits


def _size_text(body, limit_mm) -> str:
    from starforge.cad.body import body_bounds

    b = body_bounds(body)
    size = b[1] - b[0]
    text = " x ".join(f"{v:.1f}" for v in size) + " mm"
    if limit_mm is not None:
        text += " (limit " + " x ".join(f"{v:g}" for v in limit_mm) + ")"
    return text


def body_title(body) -> str:
    """``star 4`` for a star's body; ``Cup (id 4)`` for a tool's (its files carry its name)."""
    return f"star {body.star_id}" if body.name == body_name(body.star_id) else f"{body.name} (id {body.star_id})"


@drawing
def render_body_png(body, path: str | Path, size_px: int = 480, limit_mm=None) -> Path:
    """One body: a three-quarter view and a top view (its engraved id readable), titled
    ``star <id>, mount <mount>`` with its size (and the family's size limit, dashed round the
    top view, when ``limit_mm`` is given); written to ``path``."""
    from starforge.render._mpl import discard, figure, save_png

    fig = figure(figsize=(2 * size_px / _DPI, size_px / _DPI), dpi=_DPI)
    try:
        tris = _view_triangles(body)
        ax = fig.add_axes((0.0, 0.0, 0.5, 0.84), projection="3d")
        ext = np.sort(np.ptp(tris.reshape(-1, 3), axis=0))
        # the view cube's corners lie far outside a slender body (zoomed in), not a squat one
        _draw(ax, tris, "", zoom=1.45 if ext[1] <= 0.6 * ext[2] else 1.0)
        top = fig.add_axes((0.54, 0.06, 0.42, 0.74))
        _top(top, tris, body.label_face_y)
        if limit_mm is not None:
            _limit_box(top, body, limit_mm)
        top.autoscale_view()
        top.set_title("from above", fontsize=9)
        fig.text(0.5, 0.95, f"{body_title(body)}, mount {body.mount}", ha="center", va="center",
                 fontsize=14, fontweight="bold")
        fig.text(0.5, 0.88, "size " + _size_text(body, limit_mm), ha="center", va="center", fontsize=9)
        save_png(fig, path, dpi=_DPI)
    finally:
        discard(fig)
    return Path(path)


@drawing
def render_sheet_png(bodies, path: str | Path, cell_px: int = 240, box_mm=None) -> Path:
    """All bodies from above on one sheet at one scale, each with its id, its size and, given the
    family's size limit ``box_mm``, the limit dashed round it (green: fits; red: does not)."""
    from starforge.render._mpl import discard, figure, save_png

    n = len(bodies)
    cols = min(n, 6)
    rows = math.ceil(n / cols)
    tris = [_view_triangles(b, segments=12, edge_mm=1.5) for b in bodies]
    span = max(float(np.ptp(t.reshape(-1, 3)[:, :2], axis=0).max()) for t in tris)
    if box_mm is not None:
        span = max(span, float(max(box_mm)))
    half = 0.55 * span
    fig = figure(figsize=(cols * cell_px / _DPI, rows * cell_px / _DPI + 0.3), dpi=_DPI)
    try:
        h = (1 - 0.3 / fig.get_figheight()) / rows
        for k, (b, t) in enumerate(zip(bodies, tris, strict=True)):
            r, c = divmod(k, cols)
            ax = fig.add_axes((c / cols, 1 - (r + 1) * h, 1 / cols, 0.78 * h))
            _top(ax, t, b.label_face_y)
            fits = _limit_box(ax, b, box_mm) if box_mm is not None else True
            mid = (t.reshape(-1, 3).min(0) + t.reshape(-1, 3).max(0)) / 2
            ax.set_xlim(mid[0] - half, mid[0] + half)
            ax.set_ylim(mid[1] - half, mid[1] + half)
            size = _size_text(b, None)
            ax.set_title(f"{body_title(b)}\n{size}", fontsize=9, fontweight="bold",
                         color="black" if fits else "#cf222e")
        note = f"from above, one scale: each cell spans {2 * half:.0f} mm"
        if box_mm is not None:
            note += "; dashed: the size limit " + " x ".join(f"{v:g}" for v in box_mm) + " mm (red: exceeded)"
        fig.text(0.01, 0.01, note, fontsize=8)
        save_png(fig, path, dpi=_DPI)
    finally:
        discard(fig)
    return Path(path)


def draw_previews(bodies, folder: str | Path, box_mm=None) -> list[Path]:
    """``folder/<body>.png`` per body and ``folder/sheet.png`` (:func:`render_sheet_png`), as
    progress stages "preview" and "sheet" (:mod:`starforge.runtime.progress`).  ``box_mm``: the family's size
    limit, drawn on the sheet against each body's outline."""
    from starforge.runtime import progress

    folder = Path(folder)
    folder.mkdir(exist_ok=True)
    written = []
    with progress.stage("preview", total=len(bodies), unit="pictures") as st:
        for b in bodies:
            written.append(render_body_png(b, folder / f"{b.name}.png", limit_mm=box_mm))
            st.update(advance=1)
    # a stage of its own: the sheet draws every body, so as one more count it would take the
    # preview's measured rate several times too short
    with progress.stage("sheet"):
        written.append(render_sheet_png(bodies, folder / "sheet.png", box_mm=box_mm))
    return written
