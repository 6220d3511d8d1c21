"""Tabs Runs, Learning curves and Table 1."""

from __future__ import annotations

import math

import streamlit as st

from harness import analysis as A
from harness.dashboard.charts import curves_grid
from harness.dashboard.data import (
    CURVE_METRICS,
    SOURCES,
    Sel,
    curves_for,
    evidence_for,
    filtered,
    load_published_curves,
    published_curves_for,
    table1_for,
)
from harness.labels import env_label
from harness.results import RETURN_ENVS
from harness.run_status import format_duration, run_status, status_counts
from harness.tables import PUBLISHED_TABLE1_SOURCE, table1_csv, table1_latex, table1_markdown


def tab_runs(root: str, tuning: bool) -> None:
    status = run_status(root, stale_after=st.session_state.get("stale_after", 15) * 60)
    if not tuning:
        status = status[~status["tuning"]]
    if status.empty:
        st.info("No run directories (status.json / evals.parquet) found.")
        return
    counts = status_counts(status)
    cols = st.columns(len(counts))
    for col, (state, n) in zip(cols, counts.items()):
        col.metric(state, n)
    view = status.copy()
    view["ETA"] = [format_duration(x) if s in ("running", "resumed", "stale") else "" for x, s in
                   zip(view["eta_s"], view["state"])]
    view["updated"] = [format_duration(x) + " ago" if not math.isnan(x) else "" for x in view["age_s"]]
    first = {"failed": 0, "stale": 1, "running": 2, "resumed": 3, "unknown": 4, "done": 5}  # what needs a look first
    view = view.assign(_o=view["state"].map(first).fillna(6)).sort_values(["_o", "suite", "env", "algo", "seed"])
    st.dataframe(
        view[["suite", "env", "algo", "seed", "state", "progress", "step", "total", "steps_per_s", "ETA",
              "last_success", "updated", "error"]],
        hide_index=True,
        column_config={
            "progress": st.column_config.ProgressColumn("progress", min_value=0.0, max_value=1.0, format="percent"),
            "steps_per_s": st.column_config.NumberColumn("steps/s", format="%.1f"),
            "step": st.column_config.NumberColumn("step", format="%d"),
            "total": st.column_config.NumberColumn("total", format="%d"),
            "last_success": st.column_config.NumberColumn("last success", format="%.2f"),
            "error": st.column_config.TextColumn("error line", width="large"),
        },
    )
    failed = status[status["state"] == "failed"]
    for _, r in failed.iterrows():
        st.error(f"**{r['env']}/{r['algo']} seed={r['seed']}** ({r['suite']}): {r['error'] or 'failed (no message)'}")
    st.caption("stale = running/resumed but status.json not updated for longer than the threshold "
               "(or 3 evaluation intervals at the current steps/s, whichever is longer).")
    st.number_input("stale after (minutes)", min_value=1, max_value=24 * 60, value=15, key="stale_after")


def tab_curves(root, sig, sel: Sel) -> None:
    c1, c2, c3, c4 = st.columns([2, 2, 2, 2])
    data = filtered(root, sig, sel)
    envs = set(sel.envs) or (set(data["env"].unique()) if len(data) else set())
    returns = bool(envs) and envs <= RETURN_ENVS  # kitchen, minitaur: the published curves are returns
    metric = c1.selectbox("metric", list(CURVE_METRICS), format_func=CURVE_METRICS.get, key="curve_metric",
                          index=list(CURVE_METRICS).index("deployed_return") if returns else 0)
    window = c2.slider("smoothing (moving average over evaluations)", 1, 25, 1, key="smooth")
    band_label = c3.radio("band", ["standard error", "95% bootstrap CI"], key="band", horizontal=True)
    grid = c4.selectbox("common grid", ["auto", "common", "interp"], key="grid",
                        help="common: steps every seed evaluated at; interp: linear interpolation onto the union "
                             "of steps inside the range all seeds cover; auto: common unless too sparse")
    p1, p2 = st.columns([3, 1])
    sources = p1.multiselect("overlay published curves (dashed)", SOURCES, key="sources",
                             default=["risc_paper"] + (["earl_benchmark"] if "kitchen" in envs else []))
    clip = p2.checkbox("clip published to our step range", value=True, key="clip")
    ci = band_label.startswith("95")
    c = curves_for(root, sig, sel, metric, window, grid, ci)
    if c.empty:
        st.info(f"No `{metric}` results for this selection.")
        return
    pub = None
    if sources:
        pub_all, err = load_published_curves()
        if pub_all is None:
            st.info(f"Published curves unavailable: {err}")
        else:
            pub = published_curves_for(tuple(sources), tuple(sorted(c["env"].unique())),
                                       tuple(sorted({A.base_algo(a) for a in c["algo"]})), metric, window, False)
            pub = A.same_pairs(pub, c)
            if clip and len(pub):
                xmax = c.groupby("env")["step"].max()
                pub = pub[pub["step"] <= pub["env"].map(xmax)]
            if pub.empty:
                st.caption("No published curves for these methods/envs/metric.")
    curves_grid(c, pub, metric, "ci" if ci else "se")
    modes = sorted(set(c["grid"]))
    st.caption(f"Mean over seeds, band = {'95% percentile bootstrap CI (1000 resamples, seed 0)' if ci else '±1 standard error'}; "
               f"grid used: {', '.join(modes)}; smoothing: trailing mean over {window} evaluation(s).")
    with st.expander("curve data"):
        st.dataframe(c, hide_index=True)


def step_option(prefix: str, key: str) -> tuple[int | str | None, int]:
    c1, c2, c3 = st.columns([3, 2, 2])
    how = c1.radio(f"{prefix} performance at", ["last evaluation", "matched step", "step N"], horizontal=True,
                   key=f"{key}_how", help="matched step: per env, the largest step every run of every selected "
                                          "method reached")
    step: int | str | None = None
    if how == "matched step":
        step = "matched"
    elif how == "step N":
        step = int(c2.number_input("step N", min_value=0, value=1_000_000, step=10_000, key=f"{key}_n"))
    last_k = int(c3.number_input("average of last k evaluations", 1, 50, 1, key=f"{key}_k"))
    return step, last_k


def tab_table1(root, sig, sel: Sel) -> None:
    step, last_k = step_option("final", "t1")
    published = st.toggle("show the paper's Table 1 beside ours", value=True, key="t1_pub")
    t = table1_for(root, sig, sel, step, last_k, published)
    if t.empty:
        st.info("No deployed_success results for this selection.")
        return
    st.markdown(table1_markdown(t, published=published))
    steps = t.dropna(subset=["step"]).groupby("env")["step"].agg(["min", "max"])
    same = [f"{env_label(e)} {int(r['max']):,}" for e, r in steps.iterrows() if r["min"] == r["max"]]
    st.caption("Ours: deployed success, mean (standard error, ddof=1) over seeds"
               + (f" at step {', '.join(same)}" if same else "")
               + ("; where an env's rows come from different steps, each says its own (@step)" if len(same) < len(steps)
                  else "") + ". A method with runs in several suites has a row per suite. Best per env in bold "
               "(ties after rounding). "
               + (f"Paper: {PUBLISHED_TABLE1_SOURCE}; Δ = ours − paper." if published else ""))
    d1, d2, d3 = st.columns(3)
    d1.download_button("CSV", table1_csv(t), "table1.csv", "text/csv", key="dl_csv")
    d2.download_button("Markdown", table1_markdown(t, published=published), "table1.md", "text/markdown",
                       key="dl_md")
    d3.download_button("LaTeX", table1_latex(t, published=published), "table1.tex", "application/x-tex",
                       key="dl_tex")
    with st.expander("numbers"):
        st.dataframe(t, hide_index=True)
    from harness.evidence import evidence_markdown

    st.subheader("Which cells the reproduction checks verify")
    st.markdown(evidence_markdown(evidence_for(root, sig)), unsafe_allow_html=True)
    st.caption("Per Table-1 cell, the reproduction cell that checks it (suites/reproduction.yaml, suites/table1.yaml) "
               "in this results directory, whatever the sidebar selects: its seeds and budget, the final-window "
               "verdicts, the whole-curve check (every 100k window) and the first-success check. verified: every "
               "check passes; fails: one fails; a calibration window is not evidence. Training tables: how many "
               "of the cell's seeds have their training diagnostics (train.parquet) beside their evaluations, the "
               "data a diagnosis can check. docs/reproduction.md.")
