"""Pictures of a marker placement: ``convergence.png``, ``layout.png`` and the rigging guide
``guide.png`` / ``guide.pdf`` (matplotlib, Agg).

The functions take a :class:`PlotData` (plain arrays, picklable) or a placement result.
:class:`BackgroundRenderer` draws them in a forked child process that imports matplotlib while
the parent is still computing, which takes the plotting off the critical path of a CLI run.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.render._mpl import pyplot, save_png
from starforge.runtime.procs import fork_helper, release

_DPI = 100


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
    hand: np.ndarray = field(default=None, repr=False)  # (k, 7) capsules
    visibility_label: str = "visibility"


MAX_FACES = 20000


def plot_data(res, max_faces: int = MAX_FACES) -> PlotData:
    """:class:`PlotData` from a :class:`starforge.props.placement.PlacementResult`.

    Meshes with more than ``max_faces`` faces are drawn from an evenly spaced subset of faces.
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
    nf = len(res.prop.mesh.faces)
    keep = np.linspace(0, nf - 1, max_faces).astype(int) if nf > max_faces else np.arange(nf)
    from starforge.props.guide import landmarks
    from starforge.props.hand import capsule_arrays

    idx = list(res.marker_sites)
    seat = res.seat
    tracked = res.tracked is not None
    return PlotData(
        name=res.prop.name,
        final_cost=float(res.cost.total),
        mean_visibility=float(res.cost.mean_visibility),
        best=best,
        run_costs=tuple((r.history_cost, r.history_best, r.history_n) for r in runs),
        temperatures=temps,
        triangles=np.asarray(res.prop.mesh.triangles)[keep],
        face_normals=np.asarray(res.prop.mesh.face_normals)[keep],
        marker_points=res.marker_points,
        marker_normals=res.marker_normals,
        marker_visibility=res.marker_visibility,
        marker_centres=res.centres(),
        landmarks=tuple(m["text"] for m in landmarks(res.prop.mesh, res.marker_points, res.marker_normals)),
        contact=np.asarray(res.seat_report.contact)[idx],
        edge_mm=np.asarray(res.seat_report.edge_m)[idx] * 1000.0,
        bounds=np.asarray(res.prop.mesh.bounds, float),
        seat_text=(
            f"{seat.name}: {seat.ball_mm:g} mm ball, centre {seat.centre_height_mm:g} mm above a {seat.base_mm:g} mm base"
            if seat.base_mm > 0
            else f"{seat.ball_mm:g} mm ball on the surface"
        ),
        hand=capsule_arrays(res.capsules),
        visibility_label=(
            "fraction of scenarios seen by 2 surviving cameras" if tracked else "visibility (fraction of poses x pairs)"
        ),
    )


def convergence_png(res, path: str | Path) -> Path:
    """Total cost per iteration for every restart (best run highlighted), temperature and marker count."""
    d = plot_data(res)
    plt = pyplot()
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for k, (cost, _, _) in enumerate(d.run_costs):
        if k != d.best:
            ax.plot(np.arange(1, len(cost) + 1), cost, color="0.75", lw=0.8)
    cost, best_so_far, n_markers = d.run_costs[d.best]
    it = np.arange(1, len(cost) + 1)
    ax.plot(it, cost, color="C0", lw=1.4, label=f"current (best of {len(d.run_costs)} runs)")
    ax.plot(it, best_so_far, color="C3", lw=1.0, ls="--", label="best so far")
    ax.set_ylabel("total cost")
    ax.set_title(
        f"{d.name}: annealing, final cost {d.final_cost:.4f}"
        if len(cost) > 1
        else f"{d.name}: no annealing chain (--restarts 0), cost {d.final_cost:.4f}"
    )
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    ax2.plot(it, d.temperatures, color="C2", lw=1.0, label="temperature")
    ax2.set_ylabel("t")
    ax3 = ax2.twinx()
    ax3.plot(it, n_markers, color="C1", lw=0.8, label="markers")
    ax3.set_ylabel("markers")
    ax2.set_xlabel("iteration")
    ax2.grid(alpha=0.3)
    fig.subplots_adjust(left=0.1, right=0.9, top=0.92, bottom=0.1, hspace=0.08)
    save_png(fig, path, dpi=_DPI)
    plt.close(fig)
    return Path(path)


def _view_basis(elev_deg: float, azim_deg: float) -> np.ndarray:
    """(3, 3) rows: screen right, screen up, towards the viewer, for a z-up orthographic view."""
    e, a = np.radians(elev_deg), np.radians(azim_deg)
    toward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(toward, right)
    return np.array([right, up, toward])


def _shaded(ax, tris, fn, B, light=None):
    """Draw the prop's faces seen along ``B[2]`` (painter's algorithm); return the projection."""
    from matplotlib.collections import PolyCollection

    if light is None:
        light = np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85])
    proj = tris @ B.T
    front = fn @ B[2] > 0
    order = np.argsort(proj[front][:, :, 2].mean(axis=1))
    shade = np.clip(np.abs(fn[front] @ B[2]), 0, 1) * 0.35 + np.clip(fn[front] @ light, 0, 1) * 0.2 + 0.4
    polys = proj[front][order][:, :, :2]
    cols = np.repeat(shade[order][:, None], 3, axis=1)
    ax.add_collection(PolyCollection(polys, facecolors=cols, edgecolors=cols, linewidths=0.2))
    return proj


def _hand_outline(ax, hand, B):
    """The hand's capsules as dashed outlines (their silhouette: a stadium per capsule)."""
    for c in np.asarray(hand).reshape(-1, 7):
        a, b, r = c[:3] @ B.T, c[3:6] @ B.T, c[6]
        d = b[:2] - a[:2]
        L = float(np.hypot(*d))
        ang = np.arctan2(d[1], d[0]) if L > 1e-12 else 0.0
        t = np.linspace(-np.pi / 2, np.pi / 2, 24)
        u = np.array([np.cos(ang), np.sin(ang)])
        v = np.array([-u[1], u[0]])
        cap1 = b[:2] + r * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
        cap0 = a[:2] + r * (-np.cos(t)[:, None] * u - np.sin(t)[:, None] * v)
        ring = np.vstack([cap1, cap0, cap1[:1]])
        ax.plot(ring[:, 0], ring[:, 1], color="C1", ls="--", lw=0.9, zorder=2)


def spread_labels(points: np.ndarray, span: float, rounds: int = 200) -> np.ndarray:
    """(n, 2) label positions near ``points`` (n, 2) that keep apart from each other and from
    every point: each starts one step out from the points' centre and is pushed by the
    others until no two are closer than ``0.07 * span`` (or ``rounds`` pass)."""
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
    u = np.where(norm[:, None] > 1e-9 * span, d / np.maximum(norm, 1e-300)[:, None], fallback)
    lab = pts + 1.2 * gap * u
    for _ in range(rounds):
        moved = False
        others = np.vstack([lab, pts])
        for i in range(n):
            diff = lab[i] - others
            dist = np.linalg.norm(diff, axis=1)
            dist[i] = np.inf
            close = dist < gap
            if close.any():
                push = (diff[close] / np.maximum(dist[close], 1e-9 * span)[:, None] * (gap - dist[close])[:, None]).sum(0)
                if np.linalg.norm(push) < 1e-12 * span:
                    push = u[i] * gap * 0.1
                lab[i] += 0.5 * push
                moved = True
            pull = lab[i] - pts[i]
            far = np.linalg.norm(pull)
            if far > 3 * gap:
                lab[i] = pts[i] + pull / far * 3 * gap
        if not moved:
            break
    return lab


def _markers_in_view(ax, d: PlotData, B, span, colour=None, norm=None, cmap=None, size=60):
    """Numbered markers (1-based) with leader lines to labels that do not overlap; those on the
    far side hollow and grey."""
    mp = d.marker_centres @ B.T
    facing = d.marker_normals @ B[2] > -1e-9
    lab = spread_labels(mp[:, :2], span)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    m = 0.03 * span  # keep every label inside its own view
    lab[:, 0] = np.clip(lab[:, 0], x0 + m, x1 - m)
    lab[:, 1] = np.clip(lab[:, 1], y0 + m, y1 - m)
    sc = None
    for i in range(len(mp)):
        col = "k" if facing[i] else "0.55"
        ax.plot([mp[i, 0], lab[i, 0]], [mp[i, 1], lab[i, 1]], color=col, lw=0.5, zorder=4)
        ax.text(lab[i, 0], lab[i, 1], str(i + 1), fontsize=8, ha="center", va="center", color=col, zorder=6,
                bbox=dict(boxstyle="circle,pad=0.15", fc="white", ec=col, lw=0.6))  # fmt: skip
    if colour is not None:
        sc = ax.scatter(mp[facing, 0], mp[facing, 1], c=colour[facing], cmap=cmap, norm=norm, s=size,
                        edgecolors="k", linewidths=0.7, zorder=5)  # fmt: skip
    else:
        ax.scatter(mp[facing, 0], mp[facing, 1], c="C3", s=size, edgecolors="k", linewidths=0.7, zorder=5)
    ax.scatter(mp[~facing, 0], mp[~facing, 1], facecolors="none", edgecolors="0.45", s=size, lw=0.7,
               linestyle=":", zorder=5)  # fmt: skip
    return sc


def _frame(ax, proj, pad=1.25):
    allp = proj.reshape(-1, 3)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    c, h = (lo + hi) / 2, float(np.max(hi - lo)) / 2 * pad
    ax.set_xlim(c[0] - h, c[0] + h)
    ax.set_ylim(c[1] - h, c[1] + h)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    return 2 * h


def layout_png(res, path: str | Path) -> Path:
    """The prop (shaded, grey) in two orthographic views with its markers numbered (1-based,
    labels kept apart) and coloured by visibility on the markers' own range, with a colour bar.

    Drawn in 2D with the painter's algorithm (faces sorted by depth), which is much faster
    than matplotlib's 3D axes; markers on the far side are drawn hollow.
    """
    d = plot_data(res)
    plt = pyplot()
    from matplotlib.colors import Normalize

    vis = d.marker_visibility
    lo, hi = (float(vis.min()), float(vis.max())) if len(vis) else (0.0, 1.0)
    if hi - lo < 0.02:
        lo, hi = max(0.0, lo - 0.01), min(1.0, hi + 0.01)
    norm = Normalize(lo, hi)
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.8))
    fig.subplots_adjust(left=0.03, right=0.84, top=0.86, bottom=0.04, wspace=0.06)
    sc = None
    for ax, (elev, azim), title in zip(axes, [(20, -60), (20, 120)], ["front", "back"], strict=True):
        B = _view_basis(elev, azim)
        proj = _shaded(ax, d.triangles, d.face_normals, B)
        span = _frame(ax, proj)
        if d.hand is not None and len(d.hand):
            _hand_outline(ax, d.hand, B)
        sc = _markers_in_view(ax, d, B, span, vis, norm, "plasma") or sc
        ax.set_title(f"{title} (elevation {elev}, azimuth {azim} deg)", fontsize=8)
    cax = fig.add_axes([0.86, 0.15, 0.022, 0.62])
    if sc is not None:
        fig.colorbar(sc, cax=cax).set_label(d.visibility_label, fontsize=8)
    fig.suptitle(
        f"{d.name}: {len(vis)} markers (numbered), mean {d.mean_visibility:.3f}; hollow: far side"
        + ("; dashed: the hand" if d.hand is not None and len(d.hand) else ""),
        fontsize=10,
    )
    save_png(fig, path, dpi=_DPI)
    plt.close(fig)
    return Path(path)


#: the guide's orthographic views: name, rows of (screen right, screen up, towards the viewer)
GUIDE_VIEWS = (
    ("front (from -y)", np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])),
    ("side (from +x)", np.array([[0, 1.0, 0], [0, 0, 1], [1, 0, 0]])),
    ("top (from +z)", np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]])),
    ("back (from +y)", np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]])),
)


def guide_figure(res):
    """The one-page rigging guide: four orthographic views with the numbered markers and the
    bounding box a person measures from, and per marker its position from the box's sides."""
    d = plot_data(res)
    plt = pyplot()
    fig = plt.figure(figsize=(11.69, 8.27))  # A4 landscape
    lo, hi = d.bounds
    names = "xyz"
    for k, (title, B) in enumerate(GUIDE_VIEWS):
        ax = fig.add_axes([0.01 + 0.245 * k, 0.45, 0.235, 0.47])
        proj = _shaded(ax, d.triangles, d.face_normals, B)
        span = _frame(ax, proj, pad=1.35)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) @ B.T
        x0, y0 = corners[:, 0].min(), corners[:, 1].min()
        x1, y1 = corners[:, 0].max(), corners[:, 1].max()
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="C0", lw=0.7, ls="-", zorder=1.5)
        ax_r, ax_u = int(np.argmax(np.abs(B[0]))), int(np.argmax(np.abs(B[1])))
        sr, su = np.sign(B[0][ax_r]), np.sign(B[1][ax_u])
        fs = 6.5
        ax.text(x0, y0 - 0.03 * span, f"{names[ax_r]}-{'min' if sr > 0 else 'max'}", fontsize=fs, color="C0", ha="left", va="top")
        ax.text(x1, y0 - 0.03 * span, f"{names[ax_r]}-{'max' if sr > 0 else 'min'}", fontsize=fs, color="C0", ha="right", va="top")
        ax.text(x0 - 0.02 * span, y0, f"{names[ax_u]}-{'min' if su > 0 else 'max'}", fontsize=fs, color="C0", ha="right", va="bottom", rotation=90)
        ax.text(x0 - 0.02 * span, y1, f"{names[ax_u]}-{'max' if su > 0 else 'min'}", fontsize=fs, color="C0", ha="right", va="top", rotation=90)
        ext_r = (hi - lo)[ax_r] * 1000
        ext_u = (hi - lo)[ax_u] * 1000
        ax.text((x0 + x1) / 2, y1 + 0.02 * span, f"{ext_r:.1f} mm", fontsize=fs, color="C0", ha="center", va="bottom")
        ax.text(x1 + 0.02 * span, (y0 + y1) / 2, f"{ext_u:.1f} mm", fontsize=fs, color="C0", ha="left", va="center", rotation=90)
        if d.hand is not None and len(d.hand):
            _hand_outline(ax, d.hand, B)
        _markers_in_view(ax, d, B, span, size=40)
        ax.set_title(title, fontsize=9)
        for sp in ax.spines.values():
            sp.set_visible(False)
    lines = [
        f"{i + 1:>2}. {t}   (base contact {100 * c:.0f} %, edge {e:.1f} mm)" if np.isfinite(e)
        else f"{i + 1:>2}. {t}   (base contact {100 * c:.0f} %, no sharp edge)"
        for i, (t, c, e) in enumerate(zip(d.landmarks, d.contact, d.edge_mm, strict=True))
    ]  # fmt: skip
    fig.text(0.02, 0.965, f"Rigging guide: {d.name}, {len(lines)} markers", fontsize=13, weight="bold", va="top")
    size = " x ".join(f"{(hi - lo)[k] * 1000:.1f}" for k in range(3))
    head = (
        f"Marker: {d.seat_text}.  Prop bounding box {size} mm (x, y, z).  Each marker's base centre is given by its distance "
        "from the nearer side of the box on each axis (a ruler or square against the box's sides)."
    )
    fig.text(0.02, 0.43, head, fontsize=8, va="top", wrap=True)
    ncol = 1 if len(lines) <= 12 else 2
    per = -(-len(lines) // ncol)
    for c in range(ncol):
        fig.text(0.02 + 0.49 * c, 0.39, "\n".join(lines[c * per : (c + 1) * per]), fontsize=7.5 if ncol == 1 else 6.5,
                 family="monospace", va="top")  # fmt: skip
    fig.text(0.02, 0.015, "Filled: on the near side of that view; hollow, grey: on the far side.  Dashed orange: the hand "
             "that holds the prop (no markers under it).  Blue: the bounding box.", fontsize=7)  # fmt: skip
    return fig, plt


def guide_files(res, folder: str | Path) -> list[str]:
    """Write ``guide.png`` and ``guide.pdf`` (the same page) into ``folder``."""
    import io

    from starforge.io import atomic_write_bytes

    fig, plt = guide_figure(res)
    save_png(fig, Path(folder) / "guide.png", dpi=110)
    buf = io.BytesIO()
    with _pdf_fonts(fig):
        fig.savefig(buf, format="pdf", metadata={"Creator": None, "Producer": None, "CreationDate": None})
    atomic_write_bytes(Path(folder) / "guide.pdf", buf.getvalue())
    plt.close(fig)
    return ["guide.png", "guide.pdf"]


def _pdf_fonts(fig):
    """The PDF's text in PDF's standard fonts (Helvetica, Courier: every reader has them) rather
    than embedded subsets of DejaVu: no fontTools import and no subsetting (about 0.3-0.5 s of
    a CLI run's critical path) and a file a third the size.  Only where every string on the
    page is Latin-1 (what the standard fonts cover); otherwise the embedded fonts as before."""
    import contextlib
    import logging

    import matplotlib

    texts = [t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text") and hasattr(a, "get_fontname"))]
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


#: what each render process draws: the two placement pictures, and the rigging guide
_ROLES = ("pictures", "guide")
NAMES = {"pictures": ["convergence.png", "layout.png"], "guide": ["guide.png", "guide.pdf"]}


def _draw(role: str, data: PlotData, folder: Path) -> None:
    if role == "pictures":
        convergence_png(data, folder / "convergence.png")
        layout_png(data, folder / "layout.png")
    else:
        guide_files(data, folder)


class BackgroundRenderer:
    """Draw the pictures in two forked render processes: ``convergence.png`` and ``layout.png``
    in one, the rigging guide in the other (they draw at the same time on two cores).

    Entering forks the first render process, which imports matplotlib at once (start-up cost
    that then overlaps the parent's own imports and computation), loads its fonts, and only
    then forks the second from itself, which so starts with matplotlib already imported (one
    import for the two, not two competing with the parent for the cores).  Both wait for
    :meth:`submit`, which hands them the plot data and the folder; :meth:`wait` collects them
    (the first reports the second's outcome in its own exit status) and raises if drawing
    failed.  Without ``os.fork`` (or when other threads run that are not marked ``fork_safe``,
    where forking is unsafe) the same pictures are drawn in-process by :meth:`wait`.  The pictures are byte-identical either way.
    """

    def __init__(self, enabled: bool = True):
        from starforge.runtime.procs import can_fork

        self._fork = enabled and can_fork()
        self._pid: int | None = None  # the first render process
        self._writes: list[int] = []  # write end of each role's pipe, open until submitted
        self._job: tuple | None = None
        self._sent: Path | None = None

    def __enter__(self) -> BackgroundRenderer:
        if self._fork:
            pipes = [os.pipe() for _ in _ROLES]
            # the render processes form one process group, ended as a whole with the command
            pid = fork_helper(group=True)
            if pid == 0:  # render process: never returns
                for _, w in pipes:
                    os.close(w)
                _first([r for r, _ in pipes])
            for r, _ in pipes:
                os.close(r)
            self._pid, self._writes = pid, [w for _, w in pipes]
        return self

    @property
    def submitted(self) -> bool:
        """Whether :meth:`submit` was called (the pictures are being drawn or wait for :meth:`wait`)."""
        return self._job is not None or self._sent is not None

    def submit(self, res, folder: str | Path) -> None:
        """Start drawing the pictures of ``res`` into ``folder``."""
        data, folder = plot_data(res), Path(folder)
        if self._pid is None:
            self._job = (data, folder)
            return
        job = folder / ".render.pkl"
        job.write_bytes(pickle.dumps((data, str(folder)), protocol=pickle.HIGHEST_PROTOCOL))
        self._sent = job
        for w in self._writes:
            try:
                os.write(w, str(job).encode())
            except OSError:  # that process is gone: wait() reports the failure
                pass
            os.close(w)
        self._writes = []

    def wait(self) -> list[str]:
        """Wait for the pictures; return their file names."""
        names = [n for role in _ROLES for n in NAMES[role]]
        if self._pid is None:
            if self._job is not None:
                data, folder = self._job
                for role in _ROLES:
                    _draw(role, data, folder)
                self._job = None
            return names
        _, status = os.waitpid(self._pid, 0)
        release(self._pid)
        self._pid = None
        if self._sent is not None:
            self._sent.unlink(missing_ok=True)  # both render processes have read it
            self._sent = None
        if status != 0:
            raise RuntimeError("drawing the placement pictures failed in a render process")
        return names

    def __exit__(self, exc_type, exc, tb) -> None:
        for w in self._writes:
            os.close(w)  # the render processes see end-of-file and leave
        self._writes = []
        if self._pid is not None:
            if exc_type is not None:
                import signal

                # both render processes, before they draw into a stage the caller removes
                try:
                    os.killpg(self._pid, signal.SIGKILL)
                except OSError:
                    os.kill(self._pid, signal.SIGKILL)
            os.waitpid(self._pid, 0)
            release(self._pid)
            self._pid = None


def _warm(role: str) -> None:
    """What a render process does while the placement is still running: import pyplot (and the
    PDF backend for the guide) and draw a little text, so that the font files are loaded and
    the glyph caches filled before the real pictures arrive (none of this changes them)."""
    import io

    plt = pyplot()
    fig = plt.figure(figsize=(1, 1))
    fig.text(0.5, 0.5, "0123456789 mm", fontsize=8)
    fig.text(0.5, 0.2, "0123456789 mm", fontsize=7.5, family="monospace")
    fig.savefig(io.BytesIO(), format="png", dpi=_DPI)
    if role == "guide":
        import matplotlib.backends.backend_pdf  # noqa: F401
    plt.close(fig)


def _serve(read_fd: int, role: str, warm: bool = True) -> int:
    """Wait for a job on ``read_fd`` and draw ``role``'s part of it; 0 when done (or when the
    parent closed the pipe without a job), 1 when drawing failed."""
    try:
        if warm:
            _warm(role)
        with os.fdopen(read_fd, "rb") as fh:
            message = fh.read()
        if message:
            job = Path(message.decode())
            data, folder = pickle.loads(job.read_bytes())
            _draw(role, data, Path(folder))
        return 0
    except BaseException:  # reported by the parent through the exit status
        return 1


def _first(reads: list[int]) -> None:
    """Body of the first render process: warm up, fork one process for each further role
    (matplotlib already imported), draw its own role, and exit 0 only if every role drew."""
    code = 1
    try:
        _warm(_ROLES[0])
        kids = []
        for k in range(1, len(_ROLES)):
            pid = fork_helper()  # in this group; killed with the first if that one dies
            if pid == 0:
                for j, r in enumerate(reads):
                    if j != k:
                        os.close(r)
                os._exit(_serve(reads[k], _ROLES[k]))
            os.close(reads[k])
            kids.append(pid)
        code = _serve(reads[0], _ROLES[0], warm=False)
        for pid in kids:
            code |= int(os.waitpid(pid, 0)[1] != 0)
    except BaseException:
        code = 1
    finally:
        os._exit(code)
