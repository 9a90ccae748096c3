"""Pictures of a marker placement: ``convergence.png``, ``layout.png`` and the rigging guide
``guide.png`` / ``guide.pdf`` (matplotlib, Agg).

The functions take a :class:`starforge.render.prop_views.PlotData` (plain arrays, picklable) or a
placement result; the guide is drawn by :mod:`starforge.render.guide`.
:class:`BackgroundRenderer` draws them in a forked child process that imports matplotlib while
the parent is still computing, which takes the plotting off the critical path of a CLI run.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np

from starforge.render._mpl import pyplot, save_png
from starforge.render.guide import guide_files, load_fonts
from starforge.render.prop_views import (
    VIEWS,
    PlotData,
    frame,
    markers_in_view,
    plot_data,
    shade_grips,
    shaded,
)
from starforge.runtime.procs import fork_helper, release

_DPI = 100


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


def layout_png(res, path: str | Path) -> Path:
    """The prop (shaded, grey) in two orthographic views with its markers numbered (1-based,
    each number where it covers no other and no marker's dot) and coloured by visibility on the
    markers' own range, with a colour bar.

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
    fig.subplots_adjust(left=0.03, right=0.84, top=0.84, bottom=0.04, wspace=0.06)
    sc = None
    for ax, (elev, azim), title in zip(axes, [(20, -60), (20, 120)], ["front", "back"], strict=True):
        B = VIEWS[f"layout {title}"]
        proj = shaded(ax, d.triangles, d.face_normals, B)
        span = frame(ax, proj)
        shade_grips(ax, d, B)
        marks = markers_in_view(ax, d, B, span, vis, norm, "plasma", view=f"layout {title}")
        marks.place(ax)
        sc = marks.scatter or sc
        ax.set_title(f"{title} (elevation {elev}, azimuth {azim} deg)", fontsize=8)
    cax = fig.add_axes([0.86, 0.15, 0.022, 0.62])
    if sc is not None:
        # the bar spans the markers' own range: when that does not start at 0, it says so
        label = d.visibility_label if lo == 0 else f"{d.visibility_label}\n(scale from {lo:.2f}, not 0)"
        fig.colorbar(sc, cax=cax).set_label(label, fontsize=8)
    fig.suptitle(
        f"{d.name}: {len(vis)} markers (numbered), mean {d.mean_visibility:.3f}; hollow: hidden by the prop"
        + (f"\norange: the hand in its {len(d.hand)} grip(s), deeper where more of them cover; wrists fainter" if d.hand is not None and len(d.hand) else ""),
        fontsize=9,
    )
    save_png(fig, path, dpi=_DPI)
    plt.close(fig)
    return Path(path)


#: what each render process draws: the two placement pictures, and the rigging guide
_ROLES = ("pictures", "guide")
NAMES = {"pictures": ["convergence.png", "layout.png"], "guide": ["guide.png", "guide.pdf"]}


def _draw(role: str, data: PlotData, folder: Path, render_process: bool = False) -> None:
    """Draw ``role``'s pictures; ``render_process``: in a render process of their own (the guide
    then writes its PDF and PNG at once, :func:`starforge.render.guide.guide_files`)."""
    if role == "pictures":
        convergence_png(data, folder / "convergence.png")
        layout_png(data, folder / "layout.png")
    else:
        guide_files(data, folder, split=render_process)


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
    """What a render process does while the placement is still running: import pyplot and draw a
    little text (for the guide: in each of its text styles, into a PNG and a PDF), so that the
    font files are loaded and the font look-ups cached before the real pictures arrive (none of
    this changes them)."""
    import io

    plt = pyplot()
    fig = plt.figure(figsize=(1, 1))
    fig.text(0.5, 0.5, "0123456789 mm", fontsize=8)
    fig.text(0.5, 0.2, "0123456789 mm", fontsize=7.5, family="monospace")
    fig.savefig(io.BytesIO(), format="png", dpi=_DPI)
    plt.close(fig)
    if role == "guide":
        load_fonts()


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
            _draw(role, data, Path(folder), render_process=True)
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
