"""Pictures of a marker placement: ``convergence.png`` and ``layout.png`` (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

_DPI = 100


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    import io

    from starforge.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})
    atomic_write_bytes(path, buf.getvalue())


def convergence_png(res, path: str | Path) -> Path:
    """Total cost per iteration for every restart (best run highlighted), temperature and marker count."""
    plt = _plt()
    runs = res.anneal.runs
    best = int(np.argmin(res.anneal.costs))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for k, r in enumerate(runs):
        it = np.arange(1, r.iterations + 1)
        if k == best:
            continue
        ax.plot(it, r.history_cost, color="0.75", lw=0.8)
    r = runs[best]
    it = np.arange(1, r.iterations + 1)
    ax.plot(it, r.history_cost, color="C0", lw=1.4, label=f"current (best of {len(runs)} runs)")
    ax.plot(it, r.history_best, color="C3", lw=1.0, ls="--", label="best so far")
    ax.set_ylabel("total cost")
    ax.set_title(f"{res.prop.name}: annealing, final cost {res.cost.total:.4f}")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    temps = [res.spec.chain.temperature(i) for i in range(r.iterations)]
    ax2.plot(it, temps, color="C2", lw=1.0, label="temperature")
    ax2.set_ylabel("t")
    ax3 = ax2.twinx()
    ax3.plot(it, r.history_n, color="C1", lw=0.8, label="markers")
    ax3.set_ylabel("markers")
    ax2.set_xlabel("iteration")
    ax2.grid(alpha=0.3)
    fig.subplots_adjust(left=0.1, right=0.9, top=0.92, bottom=0.1, hspace=0.08)
    _save(fig, Path(path))
    plt.close(fig)
    return Path(path)


def _view_basis(elev_deg: float, azim_deg: float) -> np.ndarray:
    """(3, 3) rows: screen right, screen up, towards the viewer, for a z-up orthographic view."""
    e, a = np.radians(elev_deg), np.radians(azim_deg)
    toward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(toward, right)
    return np.array([right, up, toward])


def layout_png(res, path: str | Path, max_faces: int = 20000) -> Path:
    """The prop (shaded, grey) in two orthographic views with its markers coloured by visibility.

    Drawn in 2D with the painter's algorithm (faces sorted by depth), which is much faster
    than matplotlib's 3D axes; hidden markers are drawn hollow.
    """
    plt = _plt()
    from matplotlib.collections import PolyCollection

    mesh = res.prop.mesh
    pts = res.marker_points
    nrm = res.marker_normals
    vis = res.marker_visibility
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.8))
    fig.subplots_adjust(left=0.04, right=0.86, top=0.88, bottom=0.06, wspace=0.08)
    light = np.array([0.3, -0.4, 0.85])
    light /= np.linalg.norm(light)
    tris_all = mesh.triangles
    fn = mesh.face_normals
    if len(tris_all) > max_faces:
        keep = np.linspace(0, len(tris_all) - 1, max_faces).astype(int)
        tris_all, fn = tris_all[keep], fn[keep]
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
        f"{res.prop.name}: {len(pts)} markers, mean visibility {res.cost.mean_visibility:.2f} "
        f"(hollow: on the far side)"
    )
    _save(fig, Path(path))
    plt.close(fig)
    return Path(path)
