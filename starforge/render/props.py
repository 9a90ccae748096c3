"""Pictures of a marker placement: ``convergence.png`` and ``layout.png`` (matplotlib, Agg).

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


MAX_FACES = 20000


def plot_data(res, max_faces: int = MAX_FACES) -> PlotData:
    """:class:`PlotData` from a :class:`starforge.props.placement.PlacementResult`.

    Meshes with more than ``max_faces`` faces are drawn from an evenly spaced subset of faces.
    """
    if isinstance(res, PlotData):
        return res
    runs = res.anneal.runs
    best = int(np.argmin(res.anneal.costs))
    temps = np.array([res.spec.chain.temperature(i) for i in range(runs[best].iterations)])
    nf = len(res.prop.mesh.faces)
    keep = np.linspace(0, nf - 1, max_faces).astype(int) if nf > max_faces else np.arange(nf)
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
    ax.set_title(f"{d.name}: annealing, final cost {d.final_cost:.4f}")
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


def layout_png(res, path: str | Path) -> Path:
    """The prop (shaded, grey) in two orthographic views with its markers coloured by visibility.

    Drawn in 2D with the painter's algorithm (faces sorted by depth), which is much faster
    than matplotlib's 3D axes; hidden markers are drawn hollow.
    """
    d = plot_data(res)
    plt = pyplot()
    from matplotlib.collections import PolyCollection

    pts = d.marker_points
    nrm = d.marker_normals
    vis = d.marker_visibility
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.8))
    fig.subplots_adjust(left=0.04, right=0.86, top=0.88, bottom=0.06, wspace=0.08)
    light = np.array([0.3, -0.4, 0.85])
    light /= np.linalg.norm(light)
    tris_all = d.triangles
    fn = d.face_normals
    sc = None
    for ax, (elev, azim), title in zip(axes, [(20, -60), (20, 120)], ["front", "back"], strict=True):
        B = _view_basis(elev, azim)
        proj = tris_all @ B.T
        front = fn @ B[2] > 0
        order = np.argsort(proj[front][:, :, 2].mean(axis=1))
        shade = np.clip(fn[front] @ light, 0, 1) * 0.5 + 0.4
        polys = proj[front][order][:, :, :2]
        cols = np.repeat(shade[order][:, None], 3, axis=1)
        ax.add_collection(PolyCollection(polys, facecolors=cols, edgecolors=cols, linewidths=0.2))
        mp = pts @ B.T
        facing = nrm @ B[2] > 0
        sc = ax.scatter(
            mp[facing, 0],
            mp[facing, 1],
            c=vis[facing],
            cmap="viridis",
            vmin=0,
            vmax=1,
            s=45,
            edgecolors="k",
            zorder=3,
        )
        ax.scatter(
            mp[~facing, 0],
            mp[~facing, 1],
            facecolors="none",
            edgecolors="k",
            s=45,
            lw=0.6,
            linestyle=":",
            zorder=3,
        )
        for i, q in enumerate(mp):
            ax.annotate(str(i), q[:2], xytext=(4, 4), textcoords="offset points", fontsize=7, zorder=4)
        allp = proj.reshape(-1, 3)
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        c, h = (lo + hi) / 2, float(np.max(hi - lo)[..., None].max()) / 2 * 1.08
        ax.set_xlim(c[0] - h, c[0] + h)
        ax.set_ylim(c[1] - h, c[1] + h)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{title} (elevation {elev}, azimuth {azim} deg)", fontsize=8)
    cax = fig.add_axes([0.88, 0.15, 0.025, 0.65])
    fig.colorbar(sc, cax=cax, label="visibility (fraction of poses x pairs)")
    fig.suptitle(
        f"{d.name}: {len(pts)} markers, mean visibility {d.mean_visibility:.2f} (hollow: on the far side)"
    )
    save_png(fig, path, dpi=_DPI)
    plt.close(fig)
    return Path(path)


class BackgroundRenderer:
    """Draw ``convergence.png`` and ``layout.png`` in a forked child process.

    Entering forks a child that imports matplotlib at once (start-up cost that then overlaps the
    parent's own imports and computation on a second core) and waits.  :meth:`submit` hands it
    the plot data and the folder; :meth:`wait` collects it and raises if drawing failed.
    Without ``os.fork`` (or when other threads run, where forking is unsafe) the same pictures are
    drawn in-process by :meth:`wait`.  The pictures are byte-identical either way.
    """

    def __init__(self, enabled: bool = True):
        import threading

        self._fork = enabled and hasattr(os, "fork") and threading.active_count() == 1
        self._pid: int | None = None
        self._w: int | None = None
        self._job: tuple | None = None

    def __enter__(self) -> BackgroundRenderer:
        if self._fork:
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:  # child: never returns
                os.close(w)
                _child(r)
            os.close(r)
            self._pid, self._w = pid, w
        return self

    def submit(self, res, folder: str | Path) -> None:
        """Start drawing the pictures of ``res`` into ``folder``."""
        data, folder = plot_data(res), Path(folder)
        if self._pid is None:
            self._job = (data, folder)
            return
        job = folder / ".render.pkl"
        job.write_bytes(pickle.dumps((data, str(folder)), protocol=pickle.HIGHEST_PROTOCOL))
        os.write(self._w, str(job).encode())
        os.close(self._w)
        self._w = None

    def wait(self) -> list[str]:
        """Wait for the pictures; return their file names."""
        names = ["convergence.png", "layout.png"]
        if self._pid is None:
            if self._job is not None:
                data, folder = self._job
                convergence_png(data, folder / names[0])
                layout_png(data, folder / names[1])
                self._job = None
            return names
        _, status = os.waitpid(self._pid, 0)
        self._pid = None
        if status != 0:
            raise RuntimeError("drawing convergence.png and layout.png failed in the render process")
        return names

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._w is not None:
            os.close(self._w)  # the child sees end-of-file and leaves
            self._w = None
        if self._pid is not None:
            if exc_type is not None:
                import signal

                os.kill(self._pid, signal.SIGKILL)
            os.waitpid(self._pid, 0)
            self._pid = None


def _child(read_fd: int) -> None:
    """Body of the render process: import matplotlib, wait for a job, draw it, exit."""
    code = 1
    try:
        pyplot()
        with os.fdopen(read_fd, "rb") as fh:
            message = fh.read()
        if not message:
            code = 0
        else:
            job = Path(message.decode())
            data, folder = pickle.loads(job.read_bytes())
            job.unlink()
            convergence_png(data, Path(folder) / "convergence.png")
            layout_png(data, Path(folder) / "layout.png")
            code = 0
    except BaseException:  # reported by the parent through the exit status
        code = 1
    finally:
        os._exit(code)
