"""The reproduction ladder as a figure (``harness report``'s ``reproduction.png``): one panel per cell, our seeds and
the published ones, each check's window shaded, the verdicts in the titles."""

from __future__ import annotations

import pandas as pd

from harness.reproduction import Cell, Ladder, our_curves, published_curves, seed_mean, verdict, verdict_text


def plot_ladder(ladder: Ladder, ours: pd.DataFrame, published: pd.DataFrame | None, ncols: int = 3):
    """A matplotlib Figure, one panel per cell: our seeds (thin) and mean (thick), the published seeds (thin, grey)
    and mean (thick, dashed), each check's window shaded, the verdicts in the title."""
    import math

    import matplotlib
    from matplotlib.figure import Figure

    cells = ladder.cells
    ncols = min(ncols, len(cells))
    nrows = math.ceil(len(cells) / ncols)
    with matplotlib.rc_context({"font.size": 8, "axes.titlesize": 8.5, "axes.spines.top": False,
                                "axes.spines.right": False, "pdf.fonttype": 42}):
        fig = Figure(figsize=(3.6 * ncols, 2.6 * nrows + 0.4), layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
        for ax, cell in zip(axes, cells):
            draw_cell(ax, ladder, cell, ours, published)
        for ax in axes[len(cells):]:
            ax.set_visible(False)
    return fig


def draw_cell(ax, ladder: Ladder, cell: Cell, ours: pd.DataFrame, published: pd.DataFrame | None) -> None:
    scale = 1e6 if cell.steps >= 1e6 else 1e3
    unit = "M" if scale == 1e6 else "k"
    ours_c = our_curves(ours, ladder.suite, cell)
    if published is not None and cell.checks:
        pub = published_curves(published, cell.checks[0], cell.env)
        pub = pub[pub["step"] <= cell.steps]
        for _, g in pub.groupby("seed"):
            ax.plot(g["step"] / scale, g["value"], color="0.6", lw=0.6, alpha=0.7)
        m = pub.groupby("step")["value"].mean()
        if len(m):
            ax.plot(m.index / scale, m.values, color="0.25", lw=1.8, dashes=(4, 2), label="published (mean)")
    for _, g in ours_c.groupby("seed"):
        g = g.sort_values("step")
        ax.plot(g["step"] / scale, g["value"], color="tab:blue", lw=0.9, alpha=0.7)
    m = seed_mean(ours_c)
    if len(m):
        ax.plot(m.index / scale, m.values, color="tab:blue", lw=1.8, label="ours (mean)")
    verdicts = []
    for check in cell.checks:
        ax.axvspan(check.lo / scale, check.hi / scale, color="tab:orange", alpha=0.12, lw=0)
        w = ladder.widen_of(cell)  # the accepted band of the window's seed-mean
        ax.hlines([check.min - w, check.max + w], check.lo / scale, check.hi / scale, colors="tab:orange", lw=1.2)
        text = verdict_text(verdict(ours_c, cell, check, ladder.widen_of(cell)), check, cell.steps, short=True)
        verdicts.append(f"{check.lo // 1000:,}k-{check.hi // 1000:,}k: {text}")
    ax.set_xlim(0, cell.steps / scale)
    if cell.bounded:
        ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel(f"Environment steps ({unit})")
    ax.set_ylabel("Deployed success" if cell.bounded else "Deployed return")
    ax.grid(alpha=0.25, lw=0.5)
    ax.set_title(f"{cell.name} / {cell.env}\n" + "\n".join(verdicts))
