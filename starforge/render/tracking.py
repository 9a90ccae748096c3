"""Tracking plots: identification rates against noise (``check.png``) and capacity curves
(``sweep.png``); matplotlib with the Agg backend, imported inside the functions."""

from __future__ import annotations

from pathlib import Path

from starforge.render._mpl import discard, drawing, save_png, subplots, wrap_to_width

_DPI = 100


@drawing
def rates_plot(check_doc: dict, path: Path) -> Path:
    """Identification and wrong body or pose rates against marker noise (sigma per axis, mm),
    under the rule the check's headline names (``curve.rule``)."""
    c = check_doc["curve"]
    s = check_doc["settings"]
    fig, ax = subplots(figsize=(6.4, 4.2))
    try:
        ax.plot(c["noise_mm"], [100 * v for v in c["identification_rate"]], "o-", label="identified")
        ax.plot(
            c["noise_mm"],
            [100 * v for v in c["mislabel_rate"]],
            "s-",
            color="C3",
            label="wrong body or wrong pose",
        )
        ax.axvline(s["noise_mm"], color="0.6", ls=":", lw=1)
        ax.set_xlabel("marker noise sigma per axis [mm]")
        ax.set_ylabel("share of bodies [%]")
        ax.set_ylim(-2, 102)
        title = ax.set_title(
            f"{check_doc['input']['bodies']} bodies, {s.get('world', 'open')} world, drop {s['drop']} "
            f"({s['drop_mode']}), ghosts {s['ghosts']}, match {s['match_mm']:.3g} mm,\n"
            f"rule {c.get('rule', check_doc.get('headline_rule', 'fit'))} (the headline's), "
            f"{c['frames']:,} frames a point",
            fontsize=8,
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="center right")
        wrap_to_width(fig, title)
        fig.tight_layout()
        save_png(fig, path, dpi=_DPI)
    finally:
        discard(fig)
    return Path(path)


@drawing
def sweep_plot(rows: list[dict], path: Path, marker_mm: float) -> Path:
    """Number of stars against cube size, one colour per minimal variation, one panel per rule
    (cells with no star are left out of the log plot).

    Exhaustive cells are points joined by lines; interval cells are vertical bars from the
    verified family (lower end) to the certified upper bound, never joined into a curve.
    """
    rules = sorted({r["rule"] for r in rows})
    fig, axes = subplots(1, len(rules), figsize=(6.0 * len(rules), 4.4), squeeze=False)
    try:
        for ax, rule in zip(axes[0], rules, strict=True):
            deltas = sorted({r["delta_mm"] for r in rows if r["rule"] == rule})
            for k, d in enumerate(deltas):
                rr = sorted(
                    (r for r in rows if r["rule"] == rule and r["delta_mm"] == d and r["stars"] > 0),
                    key=lambda r: r["cube_mm"],
                )
                if not rr:
                    continue
                col = f"C{k % 10}"
                ex = [r for r in rr if r["method"] == "exhaustive"]
                iv = [r for r in rr if r["method"] == "interval"]
                if ex:
                    ax.plot(
                        [r["cube_mm"] for r in ex],
                        [r["stars"] for r in ex],
                        "o-",
                        color=col,
                        label=f"delta {d:g} mm",
                    )
                for j, r in enumerate(iv):
                    ax.vlines(
                        r["cube_mm"],
                        r["stars"],
                        r["upper_bound"],
                        color=col,
                        lw=2,
                        label=None if ex or j else f"delta {d:g} mm",
                    )
                    ax.plot([r["cube_mm"]], [r["stars"]], "_", color=col, ms=8)
            ax.set_yscale("log")
            ax.set_xlabel("cube side [mm]")
            ax.set_ylabel("stars")
            ax.set_title(f"{rule} rule, {marker_mm:g} mm markers (bars: certified intervals)", fontsize=9)
            ax.grid(alpha=0.3, which="both")
            if ax.get_legend_handles_labels()[0]:  # cells that found no star draw nothing to name
                ax.legend(fontsize=7)
        fig.tight_layout()
        save_png(fig, path, dpi=_DPI)
    finally:
        discard(fig)
    return Path(path)
