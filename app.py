"""Results dashboard (Streamlit).

    streamlit run app.py                       # reads results/ (or $HARNESS_RESULTS)
    streamlit run app.py -- --results DIR      # any results directory

The directory can also be changed in the sidebar. Data are read through ``harness.results.load``
and cached; the cache key is the number and the latest modification time of the
``evals.parquet``/``status.json`` files, so a rerun (any interaction, the Refresh button, or the
auto-refresh option) picks up new results. All statistics come from ``harness.analysis`` and ``harness.stats``.
Tabs run lazily: only the selected tab's content is computed (``?tab=...`` in the URL selects one).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import pandas as pd
import streamlit as st

from harness import analysis as A
from harness.labels import ABLATIONS, METHOD_COLORS, algo_label, env_label, method_color, order_algos, order_envs
from harness.run_status import format_duration, run_status, status_counts
from harness.stats import aggregate_scores, common_envs, probability_of_improvement, scores_by_task
from harness.tables import PUBLISHED_TABLE1, PUBLISHED_TABLE1_SOURCE, table1, table1_csv, table1_latex, table1_markdown

if TYPE_CHECKING:
    import altair as alt
from harness.results import EVALS_FILE, STATUS_FILE, TRAIN_FILE, load, load_train

TABS = ["Runs", "Learning curves", "Table 1", "Aggregates", "Ablations", "Reproduction", "Diagnostics", "Tuning"]
SOURCES = ["risc_paper", "earl_benchmark"]
CURVE_METRICS = {
    "deployed_success": "Deployed success",
    "deployed_return": "Deployed return",
    "continuing_reward": "Continuing: cumulative training reward",
    "continuing_reward_rate": "Continuing: average reward per step",
    "interventions": "Interventions (resets)",
}
DASH = {"ours": [1, 0], "risc_paper": [6, 3], "earl_benchmark": [2, 2]}
HOWTO = """
**No results yet in `{root}`.** Produce some with the harness, then come back (this page refreshes
when files change):

```bash
harness run suite=smoke                       # every algorithm x every env, tiny budgets (< 3 min)
harness run suite=earl_sparse                 # Table 1 of the MEDAL paper (5 seeds, 3M/5M/8M steps)
harness run algo=medal env=sawyer_door seeds=3 steps=200000 results={root}
streamlit run app.py -- --results {root}      # this dashboard on another directory
```
Each run writes `<results>/<suite>/<env>/<algo>/seed=<k>/{{evals.parquet,run.yaml,status.json}}`.
"""


# ------------------------------------------------------------------------------------------
# data access (cached)


def default_results() -> str:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--results")
    args, _ = p.parse_known_args(sys.argv[1:])
    return args.results or os.environ.get("HARNESS_RESULTS") or "results"


def signature(root: str) -> tuple[int, float]:
    """(number of parquet/status files, their latest mtime): the cache key for ``root``."""
    n, latest = 0, 0.0
    r = Path(root)
    if not r.exists():
        return (0, 0.0)
    for name in (EVALS_FILE, STATUS_FILE, TRAIN_FILE):
        for p in r.rglob(name):
            try:
                latest = max(latest, p.stat().st_mtime)
                n += 1
            except OSError:
                pass
    return (n, latest)


@st.cache_resource(show_spinner="Loading results…", max_entries=4)
def load_results(root: str, sig: tuple) -> tuple[pd.DataFrame, list[str]]:
    """Everything under ``root`` (re-read when ``sig`` changes). A shared object, not a copy (no pickling of a
    large frame on every rerun): callers must not modify it in place."""
    warnings: list[str] = []
    df = load(root, warn=warnings.append)
    if len(df):
        df = A.derive_metrics(df)
        for c in ("suite", "env", "algo", "metric"):
            df[c] = df[c].astype(str)
    return df, warnings


@st.cache_data(show_spinner=False, max_entries=1)
def load_published_curves() -> tuple[pd.DataFrame | None, str]:
    try:
        from harness.results import load_published

        return load_published(), ""
    except Exception as e:  # noqa: BLE001 - optional overlay
        return None, " ".join(str(e).split())


class Sel(NamedTuple):
    """The sidebar's selection (hashable: a cache key)."""

    suite: str | None
    envs: tuple
    algos: tuple
    tuning: bool = False  # include `harness tune` trial runs


def filtered(root: str, sig: tuple, sel: Sel) -> pd.DataFrame:
    df, _ = load_results(root, sig)
    if df.empty:
        return df
    if not sel.tuning:
        df = df[~A.is_tuning(df)]
    # runs of one method from several suites are shown side by side (MEDAL · reproduction, MEDAL · smoke), never
    # averaged as seeds of one method
    return A.separate_suites(A.select(df, suite=sel.suite, env=list(sel.envs), algo=list(sel.algos)))


@st.cache_data(show_spinner=False, max_entries=32)
def curves_for(root, sig, sel: Sel, metric, window, grid, ci) -> pd.DataFrame:
    return A.learning_curves(filtered(root, sig, sel), metric, window=window, grid=grid, ci=ci)


@st.cache_data(show_spinner=False, max_entries=32)
def published_curves_for(sources, envs, algos, metric, window, ci) -> pd.DataFrame:
    pub, _ = load_published_curves()
    if pub is None or not sources:
        return pd.DataFrame(columns=["source", "env", "algo", "step", "mean", "se", "ci_lo", "ci_hi"])
    d = A.select(pub, metric, source=list(sources), env=list(envs), algo=list(algos))
    return A.learning_curves(d, metric, window=window, ci=ci)


@st.cache_data(show_spinner=False, max_entries=32)
def table1_for(root, sig, sel: Sel, step, last_k, published) -> pd.DataFrame:
    return table1(filtered(root, sig, sel), step=step, last_k=last_k,
                  published=PUBLISHED_TABLE1 if published else None)


@st.cache_data(show_spinner="Checking the reproduction cells…", max_entries=4)
def evidence_for(root, sig) -> pd.DataFrame:
    from harness.evidence import table1_evidence

    df, _ = load_results(root, sig)
    return table1_evidence(df, load_published_curves()[0])


@st.cache_data(show_spinner=False, max_entries=32)
def scores_for(root, sig, sel: Sel, step, last_k) -> pd.DataFrame:
    return A.final_scores(filtered(root, sig, sel), "deployed_success", step=step, last_k=last_k)


@st.cache_data(show_spinner=False, max_entries=32)
def aggregates_for(root, sig, sel: Sel, step, last_k, reps) -> pd.DataFrame:
    s = scores_for(root, sig, sel, step, last_k)
    return aggregate_scores(s, algos=list(sel.algos), envs=list(sel.envs), reps=reps)


# ------------------------------------------------------------------------------------------
# charts




def palette(methods: list[str]) -> list[str]:
    """The report's fixed colour of each method label (harness.labels.METHOD_COLORS), so app and figures agree."""
    by_label = {algo_label(a): a for a in METHOD_COLORS}
    return [method_color(by_label.get(m, m)) for m in methods]


def curve_chart(c: pd.DataFrame, pub: pd.DataFrame | None, env: str, metric: str, band: str,
                methods: list[str]) -> alt.Chart:
    """Methods overlaid: mean line, band (SE or bootstrap CI), published curves dashed."""
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
                      legend=alt.Legend(title=None, orient="bottom", columns=3, labelLimit=300,
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
    for i in range(0, len(envs), ncols):
        cols = st.columns(ncols)
        for col, env in zip(cols, envs[i:i + ncols]):
            with col:
                # Streamlit's default height="content" squashes layered charts: give the height here
                st.altair_chart(curve_chart(c, pub, env, metric, band, methods), width="stretch", height=430)


# ------------------------------------------------------------------------------------------
# tabs


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
    metric = c1.selectbox("metric", list(CURVE_METRICS), format_func=CURVE_METRICS.get, key="curve_metric")
    window = c2.slider("smoothing (moving average over evaluations)", 1, 25, 1, key="smooth")
    band_label = c3.radio("band", ["standard error", "95% bootstrap CI"], key="band", horizontal=True)
    grid = c4.selectbox("common grid", ["auto", "common", "interp"], key="grid",
                        help="common: steps every seed evaluated at; interp: linear interpolation onto the union "
                             "of steps inside the range all seeds cover; auto: common unless too sparse")
    p1, p2 = st.columns([3, 1])
    sources = p1.multiselect("overlay published curves (dashed)", SOURCES, default=["risc_paper"], key="sources")
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
               "check passes; fails: one fails; a calibration window is not evidence. docs/reproduction.md.")


def tab_aggregates(root, sig, sel: Sel) -> None:
    import altair as alt  # imported on first chart: keeps the first page load light
    step, last_k = step_option("score", "agg")
    scores = scores_for(root, sig, sel, step, last_k)
    if scores.empty:
        st.info("No deployed_success results for this selection.")
        return
    have = order_algos(scores["algo"].unique())
    chosen = st.multiselect("methods", have, default=have, format_func=algo_label, key="agg_algos")
    shared = common_envs(scores, chosen) if chosen else []
    if not chosen or not shared:
        st.info("Choose methods that share at least one env.")
        return
    left_out = sorted(set(scores["env"]) - set(shared))
    agg = aggregates_for(root, sig, sel._replace(envs=tuple(shared), algos=tuple(chosen)), step, last_k, 2000)
    st.markdown(f"**IQM and mean of deployed success across {len(shared)} env(s)** "
                f"({', '.join(env_label(e) for e in shared)}); 95% stratified-bootstrap CIs, 2000 resamples.")
    if left_out:
        st.caption(f"Envs not shared by all chosen methods are left out: {', '.join(left_out)}.")
    view = agg.assign(method=agg["algo"].map(algo_label))
    chart = alt.Chart(view).mark_rule(strokeWidth=3).encode(
        y=alt.Y("method:N", sort=list(view["method"]), title=None), x=alt.X("iqm_lo:Q", title="IQM (deployed success)",
                                                                             scale=alt.Scale(domain=[0, 1])),
        x2="iqm_hi:Q", color=alt.Color("method:N", legend=None)) + alt.Chart(view).mark_point(
        filled=True, size=80, color="black").encode(y=alt.Y("method:N", sort=list(view["method"])), x="iqm:Q",
                                                    tooltip=["method", alt.Tooltip("iqm:Q", format=".3f"),
                                                             alt.Tooltip("iqm_lo:Q", format=".3f"),
                                                             alt.Tooltip("iqm_hi:Q", format=".3f")])
    st.altair_chart(chart, width="stretch", height=40 * len(view) + 80)
    st.dataframe(view[["method", "iqm", "iqm_lo", "iqm_hi", "mean", "mean_lo", "mean_hi", "n_envs", "n_runs"]],
                 hide_index=True)

    st.subheader("Probability of improvement")
    if len(have) < 2:
        st.info("Needs results of two methods.")
        return
    c1, c2 = st.columns(2)
    x = c1.selectbox("X", have, index=have.index("medal") if "medal" in have else 0, format_func=algo_label,
                     key="poi_x")
    y = c2.selectbox("Y", [a for a in have if a != x], format_func=algo_label, key="poi_y")
    envs_xy = common_envs(scores, [x, y])
    if not envs_xy:
        st.info("These two methods share no env.")
        return
    p, lo, hi = probability_of_improvement(scores_by_task(scores, x, envs_xy), scores_by_task(scores, y, envs_xy))
    st.metric(f"P({algo_label(x)} > {algo_label(y)})", f"{p:.2f}", help="average over envs of "
              "P(X_run > Y_run) + ½ P(=); 95% stratified-bootstrap CI")
    st.caption(f"95% CI [{lo:.2f}, {hi:.2f}] over {len(envs_xy)} env(s): {', '.join(env_label(e) for e in envs_xy)}.")


def tab_ablations(root, sig, sel: Sel) -> None:
    df = filtered(root, sig, sel)
    have = set(df["algo"].unique()) if len(df) else set()
    shown = 0
    for title, group in ABLATIONS.items():
        present = [a for a in group if a in have]
        if len(present) < 2:
            continue
        shown += 1
        st.subheader(title)
        sub = tuple(sorted(present))
        c = curves_for(root, sig, sel._replace(algos=sub), "deployed_success", 1, "auto", False)
        curves_grid(c, None, "deployed_success", "se", ncols=3)
        fp = A.final_performance(A.select(df, algo=list(present)))
        fp["final (mean (SE))"] = [f"{m:.2f} ({s:.2f})" for m, s in zip(fp["mean"], fp["se"])]
        wide = fp.pivot(index="algo", columns="env", values="final (mean (SE))")
        wide.index = [algo_label(a) for a in wide.index]
        wide.columns = [env_label(e) for e in wide.columns]
        st.dataframe(wide)
    if not shown:
        lines = "\n".join(f"- {t}: {', '.join(g)}" for t, g in ABLATIONS.items())
        st.info("No ablation has results for two or more of its methods yet. The groups:\n" + lines +
                "\n\nRun e.g. `harness run algos=medal,medal_logc,fbrl_vice,bc,gail_naive,gail_oracle envs=... seeds=5`.")


@st.cache_data(show_spinner=False, max_entries=16)
def read_study(path: str, mtime: float) -> list[dict]:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(path))
    out = []
    for name in optuna.get_all_study_names(storage):
        study = optuna.load_study(study_name=name, storage=storage)
        trials = study.trials_dataframe()
        done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
        info = {"name": name, "directions": [d.name.lower() for d in study.directions], "n_trials": len(study.trials),
                "n_complete": len(done), "trials": trials, "best": [], "importance": None, "importance_error": ""}
        if done:
            best = study.best_trials
            info["best"] = [{"number": t.number, "values": t.values, "params": t.params} for t in best]
            try:
                info["importance"] = optuna.importance.get_param_importances(study)
            except Exception as e:  # noqa: BLE001 - too few trials, single param value, ...
                info["importance_error"] = f"{type(e).__name__}: {e}"
        out.append(info)
    return out


def tab_tuning(root: str) -> None:
    import altair as alt  # imported on first chart: keeps the first page load light
    tdir = Path(root) / "tuning"
    files = sorted(p for p in tdir.rglob("*") if p.suffix in (".log", ".journal") and p.is_file()) if tdir.exists() else []
    if not files:
        st.info(f"No Optuna studies found under `{tdir}` (journal files `*.log` / `*.journal`).")
        return
    try:
        import optuna  # noqa: F401
    except ImportError:
        st.info(f"Found {len(files)} study journal(s) under `{tdir}`; install Optuna (`pip install optuna`) to "
                "see best trials and parameter importances here.")
        return
    for f in files:
        try:
            studies = read_study(str(f), f.stat().st_mtime)
        except Exception as e:  # noqa: BLE001 - foreign *.log files
            st.warning(f"Skipping `{f}`: not a readable Optuna journal ({type(e).__name__}).")
            continue
        for s in studies:
            st.subheader(f"{s['name']}")
            st.caption(f"`{f}` · {s['n_complete']} complete of {s['n_trials']} trials · "
                       f"direction(s): {', '.join(s['directions'])}")
            if not s["best"]:
                st.info("No completed trial yet.")
                continue
            best = pd.DataFrame([{"trial": b["number"], **{f"value {i}": v for i, v in enumerate(b["values"])},
                                  **b["params"]} for b in s["best"]])
            st.markdown("**Best trial" + ("s (Pareto front)**" if len(s["directions"]) > 1 else "**"))
            st.dataframe(best, hide_index=True)
            if s["importance"]:
                imp = pd.DataFrame({"parameter": list(s["importance"]), "importance": list(s["importance"].values())})
                st.altair_chart(alt.Chart(imp).mark_bar().encode(
                    x=alt.X("importance:Q"), y=alt.Y("parameter:N", sort="-x")).properties(
                    title="parameter importances (fANOVA)"), width="stretch", height=30 * len(imp) + 90)
            elif s["importance_error"]:
                st.caption(f"Parameter importances unavailable: {s['importance_error']}")
            with st.expander("all trials"):
                st.dataframe(s["trials"], hide_index=True)


def reproduction_suites() -> list[str]:
    """Suites in suites/ whose runs are checked against the published curves (they have ``cells``)."""
    from harness.suites import list_suites, load_suite

    out = []
    for name in list_suites():
        try:
            if "cells" in load_suite(name)[1]:
                out.append(name)
        except Exception:  # noqa: BLE001 - a broken suite file is reported by `harness run`, not here
            pass
    return sorted(out, key=lambda n: (n != "reproduction", n))


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
    windows = pd.DataFrame([{"lo": c.lo, "hi": c.hi} for c in cell.checks])
    layers = [alt.Chart(windows).mark_rect(opacity=0.15, color="#ff7f0e").encode(x="lo:Q", x2="hi:Q")] if len(windows) else []
    if frames:
        d = pd.concat(frames, ignore_index=True)[["step", "value", "curve", "line", "thick"]]
        color = alt.Color("curve:N", scale=alt.Scale(domain=["ours", "published"], range=["#1f77b4", "#555555"]),
                          legend=alt.Legend(title=None, orient="bottom"))
        base = alt.Chart(d).encode(x=x, y=alt.Y("value:Q", title="deployed success", scale=alt.Scale(domain=[0, 1])),
                                   color=color, detail="line:N",
                                   tooltip=["line", "step", alt.Tooltip("value:Q", format=".2f")])
        layers += [base.transform_filter(~alt.datum.thick).mark_line(strokeWidth=0.8, opacity=0.45),
                   base.transform_filter(alt.datum.thick).mark_line(strokeWidth=2.5).encode(
                       strokeDash=alt.StrokeDash("curve:N", scale=alt.Scale(domain=["ours", "published"],
                                                                            range=[[1, 0], [6, 3]]), legend=None))]
    title = alt.TitleParams(f"{algo_label(cell.name)} · {env_label(cell.env)}", subtitle=verdicts)
    return alt.layer(*layers).properties(title=title, height=260)


def tab_reproduction(root: str, sig: tuple) -> None:
    from harness import ladder_provenance as P
    from harness import reproduction as R

    suites = reproduction_suites()
    if not suites:
        st.info("No suite with `cells` in suites/ (see docs/reproduction.md).")
        return
    name = st.selectbox("reproduction suite", suites, key="repro_suite")
    ladder = R.load_ladder(name)
    df, _ = load_results(root, sig)
    ours = df if len(df) else pd.DataFrame(columns=["suite", "env", "algo", "seed", "step", "metric", "value"])
    pub, err = load_published_curves()
    t = R.ladder_table(ladder, ours, published=pub)
    done = t["status"].isin(["pass", "fail"])
    c1, c2, c3, c4 = st.columns(4)
    c1.metric("final-window checks", len(t))
    c2.metric("pass", int((t["status"] == "pass").sum()))
    c3.metric("fail", int((t["status"] == "fail").sum()))
    c4.metric("running", int((~done).sum()))
    if "curve_status" in t:
        cells = t.drop_duplicates(["method", "env", "config"])
        st.caption("Whole-curve checks, per cell: " + ", ".join(
            f"{int((cells[c] == s).sum())} {s}" for c in ("curve_status",) for s in ("pass", "fail", "running"))
            + "; first success: " + ", ".join(f"{int((cells['first_success_status'] == s).sum())} {s}"
                                              for s in ("pass", "fail", "running")))
    view = t.assign(ours_per_seed=[", ".join("-" if math.isnan(x) else f"{x:.2f}" for x in v) for v in t["ours_per_seed"]],
                    published_range=[f"{a:.2f}-{b:.2f}" for a, b in zip(t["published_min"], t["published_max"])],
                    accepted=[f"{a:.2f}-{b:.2f}" for a, b in t["band"]])
    whole = ["curve", "first_success"] if "curve" in t else []
    st.dataframe(view[["method", "env", "budget", "seeds", "window", "published", "published_range", "accepted", "ours",
                       "ours_per_seed", "verdict", *whole]], hide_index=True,
                 column_config={"published": st.column_config.NumberColumn("published mean", format="%.2f"),
                                "ours": st.column_config.NumberColumn("ours: seed mean", format="%.2f"),
                                "budget": st.column_config.NumberColumn("budget", format="%d"),
                                "verdict": st.column_config.TextColumn("final window"),
                                "curve": st.column_config.TextColumn("whole curve (every 100k window)"),
                                "first_success": st.column_config.TextColumn("first success (>= 0.5)")})
    st.caption(f"A check passes when our seed-mean of the window means lies in [published min - {ladder.widen:g}, "
               f"published max + {ladder.widen:g}] (the per-seed range of the published seeds, widened); it is running "
               "until every seed has all its evaluations in the window (\"pass whatever the rest scores\": no outcome of "
               "the evaluations still to come can turn it). The whole-curve check applies the same band to every 100k "
               "window up to the budget and allows as many windows out as a faithful method exceeds with probability "
               f"<= {ladder.rule.alpha:g}; the first-success check compares the seed-mean step of the first evaluation "
               ">= 0.5 with the published seeds'. docs/reproduction.md explains the rules.")
    with st.expander("What the runs cost"):
        cost = P.ladder_cost(ladder, ours)
        st.dataframe(cost, hide_index=True, column_config={
            "started": st.column_config.NumberColumn("seeds started"),
            "steps": st.column_config.NumberColumn("env steps", format="%d"),
            "process_hours": st.column_config.NumberColumn("process-hours", format="%.1f"),
            "steps_per_s": st.column_config.NumberColumn("steps/s per seed (median)", format="%.0f")})
        st.caption(f"{cost['process_hours'].sum():.1f} process-hours in all: each seed's last wall_s over the seeds "
                   "sharing its process (core-hours on a CPU with one torch thread per process); rows redone after a "
                   "lost checkpoint count once.")
    with st.expander("Which commits produced the rows"):
        commits = P.ladder_commits(ladder, ours)
        st.dataframe(commits.assign(commits=commits["commits"].map(P.commits_text)), hide_index=True,
                     column_config={"commits": st.column_config.TextColumn("commits (steps evaluated)")})
        st.caption("The git SHA each evaluation row carries: a run resumed across commits lists each commit with the "
                   "steps it evaluated; -dirty marks a tree with uncommitted changes.")
    if pub is None:
        st.info(f"Published curves unavailable (no whole-curve verdicts): {err}")
    for i in range(0, len(ladder.cells), 3):
        cols = st.columns(3)
        for col, cell in zip(cols, ladder.cells[i:i + 3]):
            rows = t[(t["method"] == cell.name) & (t["env"] == cell.env)]
            verdicts = [f"{w}: {v}" for w, v in zip(rows["window"], rows["verdict"])]
            if "curve" in rows and len(rows):
                verdicts += [f"whole curve: {rows['curve'].iloc[0]}", f"first success: {rows['first_success'].iloc[0]}"]
            with col:
                st.altair_chart(cell_chart(ladder, cell, ours, pub, verdicts), width="stretch", height=330)


@st.cache_resource(show_spinner="Loading training diagnostics…", max_entries=2)
def load_diagnostics(root: str, sig: tuple) -> pd.DataFrame:
    """Every ``train.parquet`` under ``root`` (re-read when ``sig`` changes); shared, not to be modified."""
    df = load_train(root, warn=lambda msg: None)
    for c in ("suite", "env", "algo", "metric"):
        df[c] = df[c].astype(str)
    return df


def tab_diagnostics(root: str, sig: tuple, sel: Sel) -> None:
    df = load_diagnostics(root, sig)
    if df.empty:
        st.info("No training diagnostics (`train.parquet`) under this directory: runs write them every `log_every` "
                "steps (default 1,000) since the harness logs them.")
        return
    df = A.select(df, suite=sel.suite, env=list(sel.envs), algo=list(sel.algos)) if len(sel.envs) else df
    if df.empty:
        st.info("No training diagnostics for this selection.")
        return
    runs = df[["suite", "env", "algo", "seed"]].drop_duplicates().sort_values(["suite", "env", "algo", "seed"])
    labels = [f"{r.suite} / {r.env} / {r.algo} / seed {r.seed}" for r in runs.itertuples()]
    c1, c2, c3 = st.columns([3, 2, 1])
    picked = c1.multiselect("runs", labels, default=labels[: min(4, len(labels))], key="diag_runs")
    metrics = sorted(df["metric"].unique())
    default = "forward/critic_loss" if "forward/critic_loss" in metrics else "sac/critic_loss" \
        if "sac/critic_loss" in metrics else metrics[0]
    metric = c2.selectbox("metric", metrics, index=metrics.index(default), key="diag_metric",
                          help="forward/*, backward/*, sac/*: SAC update diagnostics of that agent while it acted; "
                               "discriminator/*, rnd/*, success_critic/*, value_critic/*: the method's own model; "
                               "phase/*, episode/*, curriculum/*, switch/*: controller state")
    window = c3.slider("smoothing", 1, 50, 1, key="diag_smooth")
    keep = runs.iloc[[labels.index(p) for p in picked]] if picked else runs.iloc[:0]
    d = df[df["metric"] == metric].merge(keep, on=["suite", "env", "algo", "seed"])
    if d.empty:
        st.info(f"`{metric}` was not logged by the selected runs.")
        return
    d = d.sort_values("step").assign(run=lambda x: x["env"] + "/" + x["algo"] + " seed " + x["seed"].astype(str))
    d["value"] = d.groupby("run")["value"].transform(lambda v: v.rolling(window, min_periods=1).mean())
    import altair as alt

    chart = alt.Chart(d[["run", "step", "value"]]).mark_line(strokeWidth=1.5).encode(
        x=alt.X("step:Q", title="environment steps", axis=alt.Axis(format="~s")),
        y=alt.Y("value:Q", title=metric, scale=alt.Scale(zero=False)),
        color=alt.Color("run:N", legend=alt.Legend(title=None, orient="bottom", labelLimit=400)),
        tooltip=["run", "step", alt.Tooltip("value:Q", format=".4g")])
    st.altair_chart(chart, width="stretch", height=420)
    st.caption(f"Means over each logging period (every `log_every` steps) of what the updates returned; "
               f"smoothing: trailing mean over {window} period(s).")


# ------------------------------------------------------------------------------------------
# page


def main() -> None:
    st.set_page_config(page_title="EARL results", page_icon=":material/monitoring:", layout="wide")
    if "results_dir" not in st.session_state:
        st.session_state["results_dir"] = default_results()
    with st.sidebar:
        st.header("Results")
        root = st.text_input("results directory", key="results_dir").strip() or "results"
        if st.button("Refresh"):
            st.rerun()
        auto = st.checkbox("auto-refresh every 30 s", value=False, key="auto_refresh")
    t0 = time.perf_counter()
    sig = signature(root)
    st.title("Reset-free RL on EARL: results")
    if not Path(root).exists():
        st.warning(f"Results directory `{root}` does not exist.")
        st.markdown(HOWTO.format(root=root))
        return
    df, warnings = load_results(root, sig)
    for w in warnings:
        st.warning(w)
    has_status = sig[0] > 0 or (Path(root) / "tuning").exists()
    if df.empty and not has_status:
        st.markdown(HOWTO.format(root=root))
        return

    with st.sidebar:
        tuning = st.checkbox("include `harness tune` trials", value=False, key="tuning_runs",
                             help="trial runs under <results>/tuning/ (suites tune_<study>); off: left out of "
                                  "every tab but Tuning")
        if len(df) and not tuning:
            df = df[~A.is_tuning(df)]
        suites = sorted(df["suite"].unique()) if len(df) else []
        suite_choice = st.selectbox("suite", ["all"] + suites, key="suite")
        suite = None if suite_choice == "all" else suite_choice
        sub = A.select(df, suite=suite) if len(df) else df
        env_opts = order_envs(sub["env"].unique()) if len(sub) else []
        algo_opts = order_algos(sub["algo"].unique()) if len(sub) else []
        scope = f"{suite_choice}:{tuning}"  # a fresh selection (everything) per suite
        envs = tuple(st.multiselect("envs", env_opts, default=env_opts, format_func=env_label, key=f"envs:{scope}"))
        algos = tuple(st.multiselect("methods", algo_opts, default=algo_opts, format_func=algo_label,
                                     key=f"algos:{scope}"))
        n_runs = sub.groupby(["suite", "env", "algo", "seed", "trial"], dropna=False).ngroups if len(sub) else 0
        sel = Sel(suite, envs, algos, tuning)
        st.caption(f"{n_runs} runs with results · {len(df):,} rows · files changed "
                   f"{format_duration(time.time() - sig[1])} ago")

    tabs = st.tabs(TABS, key="tab", on_change="rerun", bind="query-params")
    for tab, name in zip(tabs, TABS):
        if tab.open is False:
            continue
        with tab:
            if name == "Runs":
                tab_runs(root, sel.tuning)
            elif name == "Tuning":
                tab_tuning(root)
            elif name == "Reproduction":
                tab_reproduction(root, sig)
            elif name == "Diagnostics":
                tab_diagnostics(root, sig, sel)
            elif not len(df) or not envs or not algos:
                st.info("No evaluations for this selection yet (see the Runs tab).")
            elif name == "Learning curves":
                tab_curves(root, sig, sel)
            elif name == "Table 1":
                tab_table1(root, sig, sel)
            elif name == "Aggregates":
                tab_aggregates(root, sig, sel)
            elif name == "Ablations":
                tab_ablations(root, sig, sel)
    st.sidebar.caption(f"rendered in {time.perf_counter() - t0:.2f} s")
    if auto:
        time.sleep(30)
        st.rerun()


main()
