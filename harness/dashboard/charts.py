"""The dashboard's charts (Altair, imported on the first chart so the first page load stays light): learning curves
of methods overlaid with the published ones, and a reproduction cell's seeds against the published seeds."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import pandas as pd
import streamlit as st

from harness.dashboard.data import CURVE_METRICS
from harness.labels import METHOD_COLORS, algo_label, env_label, method_colors, order_algos, order_envs

if TYPE_CHECKING:
    import altair as alt

DASH = {"ours": [1, 0], "risc_paper": [6, 3], "earl_benchmark": [2, 2]}


def palette(methods: list[str]) -> list[str]:
    """The report's fixed colour of each method label (harness.labels.METHOD_COLORS), so app and figures agree."""
    by_label = {algo_label(a): a for a in METHOD_COLORS}
    names = [by_label.get(m, m) for m in methods]
    colors = method_colors(names)
    return [colors[n] for n in names]


def curve_chart(c: pd.DataFrame, pub: pd.DataFrame | None, env: str, metric: str, band: str,
                methods: list[str], legend_columns: int = 2) -> alt.Chart:
    """Methods overlaid: mean line, band (SE or bootstrap CI), published curves dashed; the legend in
    ``legend_columns`` columns (every label whole at half the page's width)."""
    import altair as alt  # imported on first chart: keeps the first page load light
    c = c[c["env"] == env].copy()
    c["method"] = c["algo"].map(algo_label)
    c["curve"] = "ours"
    lo, hi = ("ci_lo", "ci_hi") if band == "ci" else (None, None)
    c["lo"] = c[lo] if lo else c["mean"] - c["se"]
    c["hi"] = c[hi] if hi else c["mean"] + c["se"]
    frames = [c]
    if pub is not None and len(pub):
        p = pub[pub["env"] == env].copy()
        p["method"] = p["algo"].map(algo_label)
        p["curve"] = p["source"]
        frames.append(p)
    d = pd.concat(frames, ignore_index=True)[["method", "curve", "step", "mean", "se", "n", "lo", "hi"]]
    d["n"] = d["n"].astype("float64")
    x = alt.X("step:Q", title="environment steps", axis=alt.Axis(format="~s"))
    color = alt.Color("method:N", scale=alt.Scale(domain=methods, range=palette(methods)),
                      legend=alt.Legend(title=None, orient="bottom", columns=legend_columns, labelLimit=300,
                                        symbolType="stroke", symbolOpacity=1, symbolStrokeWidth=3))
    dash_domain = [k for k in DASH if k in set(d["curve"])]
    dash = alt.StrokeDash("curve:N", scale=alt.Scale(domain=dash_domain, range=[DASH[k] for k in dash_domain]),
                          legend=alt.Legend(title=None, orient="top", direction="horizontal", labelLimit=300,
                                            symbolStrokeColor="gray"))
    y_title = CURVE_METRICS.get(metric, metric)
    scale = alt.Scale(domain=[0, 1]) if metric == "deployed_success" else alt.Scale(zero=False)
    base = alt.Chart(d)
    band_layer = base.transform_filter(alt.datum.curve == "ours").mark_area(opacity=0.18).encode(
        x=x, y=alt.Y("lo:Q", title=y_title, scale=scale), y2="hi:Q", color=color)
    line = base.mark_line(strokeWidth=2).encode(
        x=x, y=alt.Y("mean:Q", title=y_title, scale=scale), color=color, strokeDash=dash,
        tooltip=["method", "curve", "step", alt.Tooltip("mean:Q", format=".3f"), alt.Tooltip("se:Q", format=".3f"),
                 alt.Tooltip("n:Q", format="d")])
    return (band_layer + line).properties(title=env_label(env))


def curves_grid(c: pd.DataFrame, pub: pd.DataFrame | None, metric: str, band: str, ncols: int = 2) -> None:
    envs = order_envs(c["env"])
    algos = order_algos(list(c["algo"]) + (list(pub["algo"]) if pub is not None else []))
    methods = [algo_label(a) for a in algos]
    legend_columns = 2 if ncols <= 2 else 1
    height = 340 + 18 * math.ceil(len(methods) / legend_columns)  # the plot keeps its height however long the legend
    for i in range(0, len(envs), ncols):
        cols = st.columns(ncols)
        for col, env in zip(cols, envs[i:i + ncols]):
            with col:
                # Streamlit's default height="content" squashes layered charts: give the height here
                st.altair_chart(curve_chart(c, pub, env, metric, band, methods, legend_columns), width="stretch",
                                height=height)


def cell_chart(ladder, cell, ours: pd.DataFrame, pub: pd.DataFrame | None, verdicts: list[str]) -> alt.Chart:
    """Our seeds (thin) and mean (thick), the published seeds (thin) and mean (thick, dashed), windows shaded."""
    import altair as alt

    from harness import reproduction as R

    frames = []
    o = R.our_curves(ours, ladder.suite, cell)
    if len(o):
        frames += [o.assign(curve="ours", line="seed " + o["seed"].astype(str), thick=False),
                   o.groupby("step", as_index=False)["value"].mean().assign(curve="ours", line="ours: mean", thick=True)]
    if pub is not None and cell.checks:
        p = R.published_curves(pub, cell.checks[0], cell.env)
        p = p[p["step"] <= cell.steps]
        if len(p):
            frames += [p.assign(curve="published", line="published seed " + p["seed"].astype(str), thick=False),
                       p.groupby("step", as_index=False)["value"].mean().assign(curve="published",
                                                                               line="published: mean", thick=True)]
    x = alt.X("step:Q", title="environment steps", axis=alt.Axis(format="~s"), scale=alt.Scale(domain=[0, cell.steps]))
    w = ladder.widen_of(cell)  # each window's accepted band of the seed-mean, drawn as two lines across the window
    windows = pd.DataFrame([{"lo": c.lo, "hi": c.hi, "lower": c.min - w, "upper": c.max + w} for c in cell.checks])
    layers = [alt.Chart(windows).mark_rect(opacity=0.15, color="#ff7f0e").encode(x="lo:Q", x2="hi:Q")] if len(windows) else []
    y_title = "deployed success" if cell.bounded else "deployed return"
    layers += [alt.Chart(windows).mark_rule(color="#ff7f0e", strokeWidth=1.5, clip=True).encode(
        x="lo:Q", x2="hi:Q", y=alt.Y(f"{edge}:Q", title=y_title)) for edge in ("lower", "upper")] if len(windows) else []
    if frames:
        d = pd.concat(frames, ignore_index=True)[["step", "value", "curve", "line", "thick"]]
        color = alt.Color("curve:N", scale=alt.Scale(domain=["ours", "published"], range=["#1f77b4", "#555555"]),
                          legend=alt.Legend(title=None, orient="bottom"))
        y = (alt.Y("value:Q", title=y_title, scale=alt.Scale(domain=[0, 1])) if cell.bounded
             else alt.Y("value:Q", title=y_title, scale=alt.Scale(zero=False)))
        base = alt.Chart(d).encode(x=x, y=y, color=color, detail="line:N",
                                   tooltip=["line", "step", alt.Tooltip("value:Q", format=".2f" if cell.bounded else ".0f")])
        layers += [base.transform_filter(~alt.datum.thick).mark_line(strokeWidth=0.8, opacity=0.45),
                   base.transform_filter(alt.datum.thick).mark_line(strokeWidth=2.5).encode(
                       strokeDash=alt.StrokeDash("curve:N", scale=alt.Scale(domain=["ours", "published"],
                                                                            range=[[1, 0], [6, 3]]), legend=None))]
    title = alt.TitleParams(f"{algo_label(cell.name)} · {env_label(cell.env)}", subtitle=verdicts)
    return alt.layer(*layers).properties(title=title, height=260)
