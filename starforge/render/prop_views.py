"""What every picture of a placement draws from: :class:`PlotData` (plain, picklable arrays) and
the view helpers (orthographic bases, the prop shaded by the painter's algorithm, the hand's
outline, numbered markers with labels kept apart, near or far from the viewer).

A marker is *near* in a view when the sight line from its ball centre towards the viewer misses
the prop (a ball is seen from every side, so this, not the way its base faces, decides whether
it is in front); that is computed once with the prop's mesh (:func:`hidden_in_views`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from starforge.geometry.frames import perpendicular_basis
from starforge.geometry.outline import sweep_outline
from starforge.render._mpl import label_box


@dataclass(frozen=True)
class PlotData:
    """What the two pictures need, as plain arrays (metres, prop frame)."""

    name: str
    final_cost: float
    mean_visibility: float
    best: int
    run_costs: tuple = field(repr=False)  # per run: (history_cost, history_best, history_n)
    temperatures: np.ndarray = field(repr=False)  # schedule over the best run's iterations
    triangles: np.ndarray = field(repr=False)
    face_normals: np.ndarray = field(repr=False)
    marker_points: np.ndarray = field(repr=False)
    marker_normals: np.ndarray = field(repr=False)
    marker_visibility: np.ndarray = field(repr=False)
    marker_centres: np.ndarray = field(default=None, repr=False)
    landmarks: tuple = ()  # per marker: the text of starforge.props.guide.landmarks
    contact: np.ndarray = field(default=None, repr=False)
    edge_mm: np.ndarray = field(default=None, repr=False)
    bounds: np.ndarray = field(default=None, repr=False)  # (2, 3) m
    seat_text: str = ""
    standoff_text: str = ""  # the posts the markers stand on, a sentence; "" without
    hand: np.ndarray = field(default=None, repr=False)  # (k, 8) the grips' fists (capsule_arrays)
    visibility_label: str = "visibility"
    wrists: np.ndarray = field(default=None, repr=False)  # (k, 8) the grips' wrists
    hidden: dict = field(default_factory=dict)  # view name -> (m,) bool: the prop hides the marker there
    features: tuple = ()  # (name, (3,) point m) landmarks the guide names
    caliper: tuple = ()  # (a, b, centre_mm, outside_mm, tolerance_mm) per marker pair
    margin_mm: np.ndarray = field(default=None, repr=False)  # (m,) seat margin
    placement_error_mm: float = 0.0
    rings: np.ndarray = field(default=None, repr=False)  # (m, 2, k, 3) each clamp's ring faces, m (NaN: no clamp)
    search: dict = field(default_factory=dict, repr=False)  # the tracked search without chains (search_data)


#: a mesh with more faces is drawn simplified (:func:`drawn_faces`), to at most DRAWN_FACES faces
MAX_FACES = 20000
DRAWN_FACES = 6000


def plot_data(res, max_faces: int = MAX_FACES) -> PlotData:
    """:class:`PlotData` from a :class:`starforge.props.result.PlacementResult`.

    Meshes with more than ``max_faces`` faces are drawn simplified (:func:`drawn_faces`).
    """
    if isinstance(res, PlotData):
        return res
    runs = res.anneal.runs
    best = int(np.argmin(res.anneal.costs))
    n_hist = len(runs[best].history_cost)
    if res.tracked is not None:  # the tracked chains cool geometrically from t0 to 1e-4
        ts = res.spec.track
        decay = (1e-4 / ts.t0) ** (1.0 / max(1, ts.iterations)) if ts.t0 > 0 else 0.0
        temps = ts.t0 * decay ** np.arange(n_hist) if ts.t0 > 0 else np.zeros(n_hist)
    else:
        temps = np.array([res.spec.chain.temperature(i) for i in range(n_hist)])
    prop = res.prop
    tris, normals = drawn_faces(prop.vertices, prop.faces, max_faces)
    from starforge.props.guide import caliper_pairs
    from starforge.props.hand import capsule_arrays
    from starforge.props.standoff import clamp_size, standoff_words

    idx = list(res.marker_sites)
    seat = res.seat
    tracked = res.tracked is not None
    features, marks = res.rigging
    used = {m["name"] for mk in marks for m in mk["measure_from"]}
    err = res.spec.seat.placement_error_mm
    grips = getattr(res, "grips", ()) or ()
    return PlotData(
        name=res.prop.name,
        final_cost=float(res.cost.total),
        mean_visibility=float(res.cost.mean_visibility),
        best=best,
        run_costs=tuple((r.history_cost, r.history_best, r.history_n) for r in runs),
        temperatures=temps,
        triangles=tris,
        face_normals=normals,
        marker_points=res.marker_points,
        marker_normals=res.marker_normals,
        marker_visibility=res.marker_visibility,
        marker_centres=res.centres(),
        landmarks=tuple(
            (f"on a clamp round the {clamp_size(rod):g} mm rod (its margin: along the rod); " if rod > 0 else "") + m["text"]
            for m, rod in zip(marks, res.marker_rods_mm, strict=True)
        ),
        contact=np.asarray(res.seat_report.contact)[idx],
        edge_mm=np.asarray(res.seat_report.edge_m)[idx] * 1000.0,
        bounds=np.asarray(prop.bounds_m, float),
        seat_text=(
            f"{seat.name}: {seat.ball_mm:g} mm ball, centre {seat.centre_height_mm:g} mm above a {seat.base_mm:g} mm "
            + ("post's foot" if seat.standoff_mm > 0 else "base")
            if seat.base_mm > 0
            else f"{seat.ball_mm:g} mm ball on the surface"
        ),
        standoff_text=standoff_words(seat, res.marker_rods_mm) if seat.standoff_mm > 0 else "",
        hand=capsule_arrays([g.capsules[0] for g in grips]) if grips else capsule_arrays(res.capsules),
        visibility_label=(
            "fraction of scenarios seen by 2 surviving cameras" if tracked else "visibility (fraction of poses x pairs)"
        ),
        wrists=capsule_arrays([c for g in grips for c in g.capsules[1:]]),
        hidden=hidden_in_views(prop, res.centres(), VIEWS),
        features=tuple((f["name"], np.asarray(f["point"], float)) for f in features if f["name"] in used),
        caliper=tuple(
            (c["a"], c["b"], c["centre_mm"], c["outside_mm"], c["tolerance_mm"])
            for c in caliper_pairs(res.centres(), seat.ball_mm, err)
        ),
        margin_mm=None if res.seat_report.margin_m is None else np.asarray(res.seat_report.margin_m)[idx] * 1000.0,
        placement_error_mm=err,
        rings=clamp_rings(res.marker_points, res.marker_normals, res.marker_rods_mm, res.marker_rod_axes,
                          seat.base_radius_m),
        search=search_data(res.tracked) if tracked else {},
    )


def search_data(opt) -> dict:
    """What ``convergence.png`` draws of the tracked optimizer's search (a
    :class:`starforge.props.tracked_optimizer.Optimized`): the greedy search's cost after each
    addition and swap, the random layouts' lower-bound costs, and every candidate in ranked order
    as ``(name, cost, held-out tracked fraction or None)`` with the winner first."""
    sel = opt.baselines["selection"]
    return {
        **opt.search_summary(),
        "random_lower": None if opt.random_lower is None else np.asarray(opt.random_lower, float),
        "candidates": tuple((n, float(c["cost"]), c["validation_tracked"]) for n, c in sel["candidates"].items()),
        "winner": sel["winner"],
    }


def drawn_faces(vertices: np.ndarray, faces: np.ndarray, max_faces: int = MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
    """The faces a picture draws: the triangles (f, 3, 3) m of the mesh of ``vertices`` (m) and
    ``faces``, and their unit normals (f, 3; zero for a face of no area), as they are when
    ``f <= max_faces``; else the mesh simplified by vertex clustering to at most
    :data:`DRAWN_FACES` faces (vertices snapped to the mean of their cell of a cubic grid, faces
    that collapse or repeat dropped, normals recomputed from the kept winding, the grid coarsened
    until few enough remain).  A picture a thousand pixels wide cannot show the detail lost, while
    the surface stays closed (a subset of the faces would leave it full of holes) and drawing and
    the PDF stay small.
    """
    from starforge.meshfiles import face_normals

    pts = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if len(faces) <= max_faces:
        return pts[faces], face_normals(pts, faces)
    lo = pts.min(axis=0)
    span = float(np.ptp(pts, axis=0).max()) or 1.0
    cells = max(8, int(np.sqrt(DRAWN_FACES)))  # cells along the longest side
    while True:
        key = np.floor((pts - lo) / (span / cells)).astype(np.int64).clip(0, cells)
        _, cell = np.unique(key[:, 0] * (cells + 1) ** 2 + key[:, 1] * (cells + 1) + key[:, 2], return_inverse=True)
        f = cell[faces]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        f = f[np.sort(np.unique(np.sort(f, axis=1), axis=0, return_index=True)[1])]
        if len(f) <= DRAWN_FACES or cells <= 8:
            break
        cells = max(8, int(cells * 0.9 * np.sqrt(DRAWN_FACES / len(f))))
    centre = np.zeros((cell.max() + 1, 3))
    np.add.at(centre, cell, pts)
    centre /= np.bincount(cell)[:, None]
    n = face_normals(centre, f)
    ok = n.any(axis=1)  # the faces the snapping left without area are dropped
    return centre[f][ok], n[ok]


def view_basis(elev_deg: float, azim_deg: float) -> np.ndarray:
    """(3, 3) rows: screen right, screen up, towards the viewer, for a z-up orthographic view."""
    e, a = np.radians(elev_deg), np.radians(azim_deg)
    toward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(toward, right)
    return np.array([right, up, toward])


def shaded(ax, tris, fn, B, light=None, nearer_than: float | None = None, zorder: float = 1.0):
    """Draw the prop's faces seen along ``B[2]`` (painter's algorithm); return the projection.
    ``nearer_than``: only the faces wholly nearer the viewer than that depth (along ``B[2]``),
    drawn again above what lies behind them (the grips' shade, :func:`shade_grips`)."""
    from matplotlib.collections import PolyCollection

    if light is None:
        light = np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85])
    proj = tris @ B.T
    front = fn @ B[2] > 0
    if nearer_than is not None:
        front &= proj[:, :, 2].min(axis=1) > nearer_than
        if not front.any():
            return proj
    order = np.argsort(proj[front][:, :, 2].mean(axis=1))
    shade = np.clip(np.abs(fn[front] @ B[2]), 0, 1) * 0.35 + np.clip(fn[front] @ light, 0, 1) * 0.2 + 0.4
    polys = proj[front][order][:, :, :2]
    cols = np.repeat(shade[order][:, None], 3, axis=1)
    # drawn again over a shade, the seams between faces (their edges, anti-aliased) would let it
    # through: there the edges are drawn wider
    width = 0.2 if nearer_than is None else 0.6
    ax.add_collection(PolyCollection(polys, facecolors=cols, edgecolors=cols, linewidths=width, zorder=zorder))
    return proj


def shade_hand(ax, hand, B, deepest: float = 0.45):
    """The hand's capsules and bands (rows of :func:`starforge.props.hand.capsule_arrays`) as
    one collection of translucent silhouettes that deepen where they overlap: a spot inside all
    of them is ``deepest`` opaque, one inside a share s of them ``1 - (1 - deepest)**s``, so the
    shade reads as how many of the grips cover it.  A capsule's silhouette is a stadium, a
    band's the convex hull of its two end circles (:func:`~starforge.geometry.outline.sweep_outline`)."""
    from matplotlib.collections import PolyCollection

    from starforge.props.hand import CAPSULE_COLUMNS

    c = np.asarray(hand, float).reshape(-1, CAPSULE_COLUMNS)
    if not len(c):
        return
    total = len(c)
    # grips that differ only where the picture does not show (the same fist) draw as one
    # silhouette as deep as that many layers: fewer, larger-alpha layers fill faster and round less
    c, copies = np.unique(np.round(c, 9), axis=0, return_counts=True)
    a, b, r, band = c[:, :3], c[:, 3:6], c[:, 6], c[:, 7] != 0
    rings: list = [None] * len(c)
    if band.any():  # each end circle of the band, seen along B[2], swept to the other end
        u = b[band] - a[band]
        u /= np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
        e1, e2 = perpendicular_basis(u)
        t = np.linspace(0, 2 * np.pi, 48, endpoint=False)[None, :, None]
        rim = np.cos(t) * e1[:, None] + np.sin(t) * e2[:, None]
        circle = a[band][:, None] + r[band][:, None, None] * rim
        swept = sweep_outline(circle @ B[:2].T, (b[band] - a[band]) @ B[:2].T)
        for i, ring in zip(np.flatnonzero(band), swept, strict=True):
            rings[i] = ring
    if (~band).any():  # a stadium: two half circles joined along the projected axis
        p0, p1 = a[~band] @ B[:2].T, b[~band] @ B[:2].T
        d = p1 - p0
        ang = np.where(np.hypot(d[:, 0], d[:, 1]) > 1e-12, np.arctan2(d[:, 1], d[:, 0]), 0.0)
        u = np.column_stack([np.cos(ang), np.sin(ang)])[:, None]
        v = np.column_stack([-np.sin(ang), np.cos(ang)])[:, None]
        t = np.linspace(-np.pi / 2, np.pi / 2, 24)[None, :, None]
        rr = r[~band][:, None, None]
        cap1 = p1[:, None] + rr * (np.cos(t) * u + np.sin(t) * v)
        cap0 = p0[:, None] + rr * (-np.cos(t) * u - np.sin(t) * v)
        stadium = np.concatenate([cap1, cap0, cap1[:, :1]], axis=1)
        for i, ring in zip(np.flatnonzero(~band), stadium, strict=True):
            rings[i] = ring
    from matplotlib.colors import to_rgb

    alpha = 1.0 - (1.0 - deepest) ** (copies / total)  # k layers of 1 - (1 - deepest)**(1 / total)
    colours = [(*to_rgb("C1"), float(a)) for a in alpha]
    ax.add_collection(PolyCollection(rings, facecolors=colours, edgecolors="none", zorder=2), autolim=False)


def spread_labels(points: np.ndarray, span: float, rounds: int = 200) -> np.ndarray:
    """(n, 2) label positions near ``points`` (n, 2) that keep apart from each other and from
    every point: each starts one step out from the points' centre and is pushed by the
    others until no two are closer than ``0.07 * span`` (or ``rounds`` pass), never more than
    three steps from its point.

    The labels move one at a time, each against the positions of the round's start, in plain
    floats: a dozen labels make numpy's per-call cost most of the time, and scalar arithmetic
    gives the same positions on every machine."""
    pts = np.asarray(points, float)
    n = len(pts)
    if n == 0:
        return pts
    gap = 0.07 * span
    c = pts.mean(axis=0)
    d = pts - c
    norm = np.linalg.norm(d, axis=1)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    fallback = np.column_stack([np.cos(ang), np.sin(ang)])
    u = np.where(norm[:, None] > 1e-9 * span, d / np.maximum(norm, 1e-300)[:, None], fallback).tolist()
    P = pts.tolist()
    L = (pts + 1.2 * gap * np.asarray(u)).tolist()
    tiny, still, reach = 1e-9 * span, 1e-12 * span, 3 * gap
    for _ in range(rounds):
        moved = False
        others = [tuple(q) for q in L] + [tuple(q) for q in P]
        for i in range(n):
            lx, ly = L[i]
            px = py = 0.0
            hit = False
            for j, (ox, oy) in enumerate(others):
                dx, dy = lx - ox, ly - oy
                dist = math.sqrt(dx * dx + dy * dy)
                if j != i and dist < gap:  # pushed away by each one too close, the more the closer
                    m = max(dist, tiny)
                    px += dx / m * (gap - dist)
                    py += dy / m * (gap - dist)
                    hit = True
            if hit:
                if math.sqrt(px * px + py * py) < still:  # pushes that cancel: step outwards
                    px, py = u[i][0] * gap * 0.1, u[i][1] * gap * 0.1
                lx, ly = lx + 0.5 * px, ly + 0.5 * py
                moved = True
            qx, qy = lx - P[i][0], ly - P[i][1]
            far = math.sqrt(qx * qx + qy * qy)
            if far > reach:  # back to its reach (q / far * 3 * gap rounds as the guides drawn so far did)
                lx, ly = P[i][0] + qx / far * 3 * gap, P[i][1] + qy / far * 3 * gap
            L[i] = [lx, ly]
        if not moved:
            break
    return np.array(L, float).reshape(n, 2)


@dataclass
class MarkerLabels:
    """What :func:`markers_in_view` drew: the near markers' scatter (for a colour bar; None when
    none is near), the numbers, their leader lines (marker first) and the dots as symbols no
    label may cover ((2D point, points across) pairs, :func:`declutter`'s obstacles)."""

    scatter: object
    texts: list
    leaders: list
    dots: list

    def place(self, ax, droppable: list = (), obstacles: list = ()) -> None:
        """Place the numbers (and the ``droppable`` texts) where they cover no other label, no
        dot and none of ``obstacles`` (:func:`declutter`), and re-aim the leader lines at them."""
        declutter(ax, [], self.texts, list(droppable), self.dots + list(obstacles))
        for line, t in zip(self.leaders, self.texts, strict=True):
            xs, ys = line.get_data()
            x, y = t.get_position()
            line.set_data([xs[0], x], [ys[0], y])


def markers_in_view(ax, d: PlotData, B, span, colour=None, norm=None, cmap=None, size=60, view=None) -> MarkerLabels:
    """Numbered markers (1-based) with leader lines to labels spread apart; those the prop hides
    in this view (``d.hidden[view]``; without it, those whose base faces away) hollow and grey.
    :meth:`MarkerLabels.place` then settles the labels clear of each other and of the dots."""
    mp = d.marker_centres @ B.T
    if view is not None and view in d.hidden:
        facing = ~np.asarray(d.hidden[view], bool)
    else:
        facing = d.marker_normals @ B[2] > -1e-9
    lab = spread_labels(mp[:, :2], span)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    m = 0.03 * span  # keep every label inside its own view
    lab[:, 0] = np.clip(lab[:, 0], x0 + m, x1 - m)
    lab[:, 1] = np.clip(lab[:, 1], y0 + m, y1 - m)
    sc = None
    texts, leaders = [], []
    if d.standoff_text:  # each ball on its post, from the mark on the prop
        foot = d.marker_points @ B.T
        for i in range(len(mp)):
            ax.plot([foot[i, 0], mp[i, 0]], [foot[i, 1], mp[i, 1]], color="0.3" if facing[i] else "0.6", lw=1.8,
                    solid_capstyle="butt", zorder=4.5)  # fmt: skip
            if d.rings is not None and np.isfinite(d.rings[i]).all():  # the clamp's ring: its two faces
                for face in d.rings[i] @ B.T:
                    ax.plot(face[:, 0], face[:, 1], color="0.3" if facing[i] else "0.6", lw=0.8, zorder=4.5)
    for i in range(len(mp)):
        col = "k" if facing[i] else "0.55"
        leaders += ax.plot([mp[i, 0], lab[i, 0]], [mp[i, 1], lab[i, 1]], color=col, lw=0.5, zorder=4)
        texts.append(ax.text(lab[i, 0], lab[i, 1], str(i + 1), fontsize=8, ha="center", va="center", color=col, zorder=6,
                             bbox=dict(boxstyle="circle,pad=0.15", fc="white", ec=col, lw=0.6)))  # fmt: skip
    if colour is not None:
        sc = ax.scatter(mp[facing, 0], mp[facing, 1], c=colour[facing], cmap=cmap, norm=norm, s=size,
                        edgecolors="k", linewidths=0.7, zorder=5)  # fmt: skip
    else:
        ax.scatter(mp[facing, 0], mp[facing, 1], c="C3", s=size, edgecolors="k", linewidths=0.7, zorder=5)
    ax.scatter(mp[~facing, 0], mp[~facing, 1], facecolors="none", edgecolors="0.45", s=size, lw=0.7,
               linestyle=":", zorder=5)  # fmt: skip
    dot = size**0.5 + 1  # a dot's diameter (the scatter's size is its area in points squared) and its edge
    return MarkerLabels(sc, texts, leaders, [(p, dot) for p in mp[:, :2]])


#: points round each face of a clamp's ring as the views draw it
RING_DRAWN = 48


def clamp_rings(points, normals, rods_mm, rod_axes, half_width_m: float) -> np.ndarray | None:
    """(m, 2, RING_DRAWN, 3) the outer edges of each marker's clamp ring (the ring's two faces,
    ``half_width_m`` either side of the post's axis, placed by
    :func:`~starforge.props.clamp.ring_frame`), m; NaN for a marker on its foot; None when no
    marker is clamped."""
    from starforge.props.clamp import ring_frame

    rods = np.asarray(rods_mm, float)
    if not (rods > 0).any():
        return None
    out = np.full((len(rods), 2, RING_DRAWN, 3), np.nan)
    a = np.linspace(0.0, 2 * np.pi, RING_DRAWN)
    for i in np.flatnonzero(rods > 0):
        frame, _, outside = ring_frame(points[i], normals[i], rods[i], rod_axes[i])
        x, y, t, centre = frame[:3, 0], frame[:3, 1], frame[:3, 2], frame[:3, 3]
        rim = outside * (np.cos(a)[:, None] * x + np.sin(a)[:, None] * y)
        for k, side in enumerate((-1.0, 1.0)):
            out[i, k] = centre + side * half_width_m * t + rim
    return out


def symbol_box(ax, xy, size_pt: float):
    """The display box of a symbol ``size_pt`` points across, centred on data point ``xy`` (once
    the axes' aspect is applied)."""
    from matplotlib.transforms import Bbox

    x, y = ax.transData.transform(xy)
    h = size_pt / 2 * ax.figure.dpi / 72.0
    return Bbox.from_extents(x - h, y - h, x + h, y + h)


#: how far (in label heights) and in how many directions :func:`declutter` looks for a free spot
_REACH, _DIRECTIONS = 10, 24


def declutter(ax, fixed: list, movable: list, droppable: list, obstacles: list = ()) -> None:
    """Place the texts of ``movable`` and ``droppable`` (in ``ax``) where their boxes overlap no
    other text, none of ``fixed`` and none of ``obstacles`` (symbols no text may cover: (data
    point, size in points) pairs, :func:`symbol_box`), inside the axes.

    Greedy label placement: the movable texts (which must all show), then the droppable ones from
    the last listed to the first, each takes the free spot nearest its own position among rings
    of spots round it (:data:`_REACH` label heights out, :data:`_DIRECTIONS` directions).  A
    droppable text with no free spot is hidden; a movable one takes the spot it overlaps least.
    Each text's box (its frame's, :func:`~starforge.render._mpl.label_box`) is measured once, as
    an offset from its anchor, so the search is arithmetic on boxes."""
    fig = ax.figure
    r = fig.canvas.get_renderer()  # text extents need the renderer, not a drawing of the page
    ax.apply_aspect()
    fb = ax.get_window_extent(r)
    fixed = [t for t in fixed if t.get_visible()]
    placed = [label_box(t, r).extents for t in fixed] + [symbol_box(ax, xy, size).extents for xy, size in obstacles]
    placed = np.array(placed, float).reshape(-1, 4)
    rings = np.arange(_REACH + 1, dtype=float)
    ang = np.arange(_DIRECTIONS) * (2 * np.pi / _DIRECTIONS)
    unit = np.column_stack([np.cos(ang), np.sin(ang)])
    inv = ax.transData.inverted()
    todo = [(t, True) for t in movable if t.get_visible()] + [(t, False) for t in reversed(droppable) if t.get_visible()]
    for t, must in todo:
        anchor = ax.transData.transform(t.get_position())
        off = np.asarray(label_box(t, r).extents) - np.tile(anchor, 2)
        step = off[3] - off[1]  # one label height
        cand = anchor + np.vstack([np.zeros((1, 2)), (rings[1:, None, None] * step * unit[None]).reshape(-1, 2)])
        boxes = np.tile(cand, 2) + off
        inside = (boxes[:, 0] >= fb.x0 + 1) & (boxes[:, 1] >= fb.y0 + 1) & (boxes[:, 2] <= fb.x1 - 1) & (boxes[:, 3] <= fb.y1 - 1)
        ix = np.minimum(boxes[:, None, 2], placed[None, :, 2]) - np.maximum(boxes[:, None, 0], placed[None, :, 0])
        iy = np.minimum(boxes[:, None, 3], placed[None, :, 3]) - np.maximum(boxes[:, None, 1], placed[None, :, 1])
        clash = (np.clip(ix, 0, None) * np.clip(iy, 0, None) * ((ix > 0.5) & (iy > 0.5))).sum(axis=1)
        free = np.flatnonzero(inside & (clash == 0))
        if len(free):
            k = int(free[0])
        elif must:
            k = int(np.argmin(np.where(inside, clash, np.inf))) if inside.any() else 0
        else:
            t.set_visible(False)
            continue
        t.set_position(inv.transform(cand[k]))
        placed = np.vstack([placed, boxes[k]])


def frame(ax, proj, pad=1.25, half_width=None):
    """Frame the projected points ``proj`` in ``ax`` at one scale on both axes and return the
    frame's width (data units), to which the labels' offsets are scaled: a square ``pad`` times
    their largest extent (the depth's included, so that views of one prop framed so share one
    scale), or with ``half_width`` that half-width and the axes' own shape
    (:func:`shared_half_width`)."""
    allp = proj.reshape(-1, 3)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    c = (lo + hi) / 2
    hx = hy = float(np.max(hi - lo)) / 2 * pad
    if half_width is not None:
        hx, hy = half_width, half_width * box_aspect(ax)
    ax.set_xlim(c[0] - hx, c[0] + hx)
    ax.set_ylim(c[1] - hy, c[1] + hy)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    return 2 * hx


def box_aspect(ax) -> float:
    """The height of ``ax`` on its figure over its width."""
    pos = ax.get_position()
    w, h = ax.figure.get_size_inches()
    return (pos.height * h) / (pos.width * w)


def shared_half_width(points: np.ndarray, bases, aspect: float, pad: float) -> float:
    """The half-width (data units) of the frames that hold ``points`` (n, 3) seen in every view
    of ``bases``, ``pad`` times their extent, in axes ``aspect`` (height over width) times as
    tall as wide: one scale for all the views, as large as the tallest or widest of them allows."""
    need = 1e-9
    for B in bases:
        ext = np.ptp(points @ np.asarray(B)[:2].T, axis=0) / 2 * pad
        need = max(need, float(ext[0]), float(ext[1]) / aspect)
    return need


#: the views the pictures draw, by name: rows of (screen right, screen up, towards the viewer)
VIEWS = {
    "layout front": view_basis(20, -60),
    "layout back": view_basis(20, 120),
    "front (from -y)": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "side (from +x)": np.array([[0, 1.0, 0], [0, 0, 1], [1, 0, 0]]),
    "top (from +z)": np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]),
    "back (from +y)": np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),
}


def hidden_in_views(mesh, centres: np.ndarray, views: dict) -> dict:
    """View name -> (m,) bool: the prop (``mesh``, a PropMesh or a ``trimesh.Trimesh``) lies
    between the ball centre and the viewer (the sight line along the view's third row, from just
    off the centre, hits the mesh)."""
    from starforge.props.rays import ray_scene

    c = np.asarray(centres, float).reshape(-1, 3)
    d = np.vstack([np.repeat(np.asarray(B[2], float)[None], len(c), axis=0) for B in views.values()])
    hit = ray_scene(mesh).hits(np.tile(c, (len(views), 1)) + 1e-6 * d, d)
    return {name: hit[k * len(c) : (k + 1) * len(c)] for k, name in enumerate(views)}


def shade_grips(ax, d: PlotData, B, wrists: bool = True) -> None:
    """The grips, shaded by how many cover each spot: the fists, then the wrists fainter
    (unless ``wrists`` is false); then the prop's faces nearer the viewer than every grip drawn
    again over them, so that a part of the prop in front of the hand hides it (a hammer's head
    seen from above its handle)."""
    from starforge.props.hand import CAPSULE_COLUMNS

    drawn = []
    if d.hand is not None and len(d.hand):
        shade_hand(ax, d.hand, B)
        drawn.append(np.asarray(d.hand, float).reshape(-1, CAPSULE_COLUMNS))
    if wrists and d.wrists is not None and len(d.wrists):
        shade_hand(ax, d.wrists, B, deepest=0.2)
        drawn.append(np.asarray(d.wrists, float).reshape(-1, CAPSULE_COLUMNS))
    if drawn:
        c = np.vstack(drawn)
        # how far towards the viewer each reaches: a capsule its radius past its nearer end, a
        # band (a cylinder between its end circles) the reach of those circles seen along B[2]
        u = c[:, 3:6] - c[:, :3]
        u /= np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
        reach = np.where(c[:, 7] != 0, np.sqrt(np.clip(1.0 - (u @ B[2]) ** 2, 0.0, 1.0)), 1.0) * c[:, 6]
        nearest = float(np.max(np.maximum(c[:, :3] @ B[2], c[:, 3:6] @ B[2]) + reach))
        shaded(ax, d.triangles, d.face_normals, B, nearer_than=nearest, zorder=2.5)
