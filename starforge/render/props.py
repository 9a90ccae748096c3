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

from starforge.render._mpl import discard, drawing, save_png, subplots
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


#: the tracked optimizer's candidates (:func:`starforge.props.tracked_optimizer.optimize`) as pictures name them
CANDIDATES = {
    "greedy_local_search": "greedy + swaps",
    "best_of_random": "best random layout",
    "best_of_random_polished": "best random + swaps",
    "held_out_polished": "leader, swapped on held-out poses",
    "held_out_polished_cheapest": "cheapest, swapped on held-out poses",
    "grown_from_start": "grown from fewer markers",
}


def candidate_label(name: str) -> str:
    """A candidate's name as the pictures print it (``chain_2_polished``: "chain 2 + swaps")."""
    if name.startswith("chain_"):
        return f"chain {name.split('_')[1]} + swaps"
    return CANDIDATES.get(name, name.replace("_", " "))


@drawing
def convergence_png(res, path: str | Path) -> Path:
    """Total cost per iteration for every restart (best run highlighted), temperature and marker
    count; for the tracked search without annealing chains (the default), :func:`search_png`."""
    d = plot_data(res)
    if d.search and all(len(c) <= 1 for c, _, _ in d.run_costs):
        return search_png(d, path)
    fig, (ax, ax2) = subplots(2, 1, figsize=(7, 5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
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
    discard(fig)
    return Path(path)


@drawing
def search_png(res, path: str | Path) -> Path:
    """:func:`search_figure` as a PNG."""
    fig = search_figure(res)
    save_png(fig, path, dpi=_DPI)
    discard(fig)
    return Path(path)


@drawing
def search_figure(res):
    """The tracked search without annealing chains: above, the greedy layout's cost after each
    added marker (numbered by the markers it then has) and after each swap that lowered it
    (log scale: a layout of one or two markers tracks nothing); below, the costs of the random
    layouts (their lower bounds: without the near-symmetry term) with every candidate's cost and
    held-out tracked fraction, the chosen one solid."""
    d = plot_data(res)
    srch = d.search
    from matplotlib.ticker import NullLocator

    fig, (ax, ax2) = subplots(2, 1, figsize=(7.5, 6.6), gridspec_kw={"height_ratios": [3, 2]})
    trace = np.asarray(srch["greedy_trace"], float)
    n_add = min(srch["greedy_additions"], len(trace))
    step = np.arange(1, len(trace) + 1)
    ax.plot(step, trace, color="0.6", lw=0.8, zorder=1)
    ax.plot(step[:n_add], trace[:n_add], "o", color="C0", ms=4, label="after adding a marker (label: markers)", zorder=2)
    for k in range(n_add):
        ax.annotate(str(k + 1), (step[k], trace[k]), xytext=(0, 5), textcoords="offset points", ha="center", fontsize=7)
    if len(trace) > n_add:
        ax.plot(step[n_add:], trace[n_add:], "s", color="C1", ms=3.5, label="after a swap that lowered it")
    cands = {n: (c, h) for n, c, h in srch["candidates"]}
    chosen = cands[srch["winner"]][0]
    ax.axhline(chosen, color="C3", lw=1.0, ls="--", label=f"chosen ({candidate_label(srch['winner'])})")
    if len(trace):
        ax.set_yscale("log")
        ax.yaxis.set_minor_locator(NullLocator())  # minor ticks cost a third of the drawing
    ax.set_xlabel("greedy search step", fontsize=8)
    ax.set_ylabel("total cost (lower is better)", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=7)
    lower = srch["random_lower"]
    title = f"{d.name}: greedy search, no annealing chain (--restarts 0); chosen cost {d.final_cost:.4f}"
    if lower is not None and len(lower):
        pos = lower[lower > 0]
        lo = min(float(pos.min()) if len(pos) else chosen, *(c for c, _ in cands.values()))
        hi = max(float(lower.max()), *(c for c, _ in cands.values()))
        bins = np.geomspace(max(lo, 1e-6) * 0.9, hi * 1.1, 40) if hi > lo > 0 else 40
        counts, edges = np.histogram(lower, bins=bins)
        ax2.stairs(counts, edges, fill=True, color="0.75", label=f"{len(lower)} random layouts (lower bounds)")
        if hi > lo > 0:
            ax2.set_xscale("log")
            ax2.xaxis.set_minor_locator(NullLocator())
        title += f"\n{srch['random_costlier_than_chosen']} of {len(lower)} random layouts cost more, even by their lower bound"
    for k, (name, (c, h)) in enumerate(cands.items()):
        win = name == srch["winner"]
        held = "" if h is None else f", held-out tracked {100 * h:.1f} %"
        ax2.axvline(
            c, color="C3" if win else f"C{(k % 6) + 4}", lw=1.6 if win else 1.0, ls="-" if win else "--",
            label=f"{candidate_label(name)}{' (chosen)' if win else ''}: {c:.4f}{held}",
        )  # fmt: skip
    ax2.set_xlabel("total cost", fontsize=8)
    ax2.set_ylabel("layouts", fontsize=8)
    ax2.grid(alpha=0.3)
    handles, labels = ax2.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.1, 0.0), fontsize=7, frameon=False)
    ax.set_title(title, fontsize=9)
    rows = len(labels)
    fig.subplots_adjust(left=0.1, right=0.97, top=0.9, bottom=0.08 + 0.03 * rows, hspace=0.35)
    return fig


@drawing
def layout_png(res, path: str | Path) -> Path:
    """The prop (shaded, grey) in two orthographic views with its markers numbered (1-based,
    each number where it covers no other and no marker's dot) and coloured by visibility on the
    markers' own range, with a colour bar.

    Drawn in 2D with the painter's algorithm (faces sorted by depth), which is much faster
    than matplotlib's 3D axes; markers on the far side are drawn hollow.
    """
    d = plot_data(res)
    from matplotlib.colors import Normalize

    vis = d.marker_visibility
    lo, hi = (float(vis.min()), float(vis.max())) if len(vis) else (0.0, 1.0)
    if hi - lo < 0.02:
        lo, hi = max(0.0, lo - 0.01), min(1.0, hi + 0.01)
    norm = Normalize(lo, hi)
    fig, axes = subplots(1, 2, figsize=(9, 4.8))
    fig.subplots_adjust(left=0.03, right=0.84, top=0.84, bottom=0.04, wspace=0.06)
    sc = None
    for ax, (elev, azim), title in zip(axes, [(20, -60), (20, 120)], ["front", "back"], strict=True):
        B = VIEWS[f"layout {title}"]
        proj = shaded(ax, d.triangles, d.face_normals, B)
        balls = d.marker_centres @ B.T if d.standoff_text else np.zeros((0, 3))  # posts hold them off the prop
        span = frame(ax, np.vstack([proj.reshape(-1, 3), balls]))
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
    discard(fig)
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


@drawing
def _warm(role: str) -> None:
    """What a render process does while the placement is still running: import matplotlib and draw
    a small figure with the kinds of artist the pictures draw (a log scale, whose tick labels
    are mathtext, a legend, a colour bar, ...) and a little text (for the guide: in each of its
    text styles, into a PNG and a PDF), so that matplotlib's first-use work (the mathtext
    parser, the font files and look-ups) is done before the real pictures arrive; none of this
    changes them."""
    import io

    from matplotlib.collections import PolyCollection

    fig, (ax, ax2) = subplots(2, 1, figsize=(2, 2))
    ax.plot([1, 2], [1, 10], "o-", label="0123456789")
    ax.set_yscale("log")
    ax.annotate("1", (1, 1), xytext=(0, 5), textcoords="offset points", fontsize=7)
    ax.axhline(2, ls="--")
    ax.legend(fontsize=8)
    fig.colorbar(ax2.scatter([0, 1], [0, 1], c=[0, 1]), ax=ax2)
    ax2.fill([0, 1, 1], [0, 0, 1])
    ax2.add_collection(PolyCollection([[(0, 0), (1, 0), (0, 1)]], facecolors="0.5"))
    ax2.text(0.5, 0.5, "1", bbox={"boxstyle": "circle,pad=0.15", "fc": "white"})
    fig.suptitle("0123456789 mm", fontsize=8)
    fig.text(0.5, 0.2, "0123456789 mm", fontsize=7.5, family="monospace")
    fig.savefig(io.BytesIO(), format="png", dpi=_DPI)
    discard(fig)
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
