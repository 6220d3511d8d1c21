"""Tabs Aggregates (IQM, probability of improvement), Ablations and Diagnostics (training diagnostics)."""

from __future__ import annotations

import pandas as pd
import streamlit as st

from harness import analysis as A
from harness.dashboard.charts import curves_grid
from harness.dashboard.data import Sel, aggregates_for, curves_for, filtered, load_diagnostics, scores_for
from harness.dashboard.results_tabs import step_option
from harness.labels import ABLATIONS, algo_label, env_label, order_algos, order_envs
from harness.stats import common_envs, no_shared_env, probability_of_improvement, scores_by_task
from harness.tables import EARLY, TABLE1_BUDGET, short_steps


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
    if not chosen:
        st.info("Choose at least one method.")
        return
    if not shared:
        st.info(f"No env has results of every chosen method ({no_shared_env(scores, chosen)}): leave out a method "
                "(or add an env the sidebar leaves out).")
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
    st.caption("Scores from step " + steps_used(scores[scores["algo"].isin(chosen) & scores["env"].isin(shared)])
               + f"; {EARLY} before half of the paper's Table-1 budget: not a final number.")

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


def steps_used(scores: pd.DataFrame) -> str:
    """``MEDAL: Tabletop Organization 1.5M, Sawyer Peg 540k†; ...``: the step of each method's scores per env (the
    largest of its runs), marked where it is before half of the paper's budget."""
    parts = []
    for algo in order_algos(scores["algo"].unique()):
        s = scores[scores["algo"] == algo].groupby("env")["step"].max()
        s = s[order_envs(s.index)]
        parts.append(f"{algo_label(algo)}: " + ", ".join(
            f"{env_label(e)} {short_steps(v)}{EARLY if v < TABLE1_BUDGET.get(e, 0) / 2 else ''}" for e, v in s.items()))
    return "; ".join(parts)


def _mean_se(mean: float, se: float, n: int, step: float) -> str:
    return (f"{mean:.2f} (1 seed)" if n == 1 else f"{mean:.2f} ({se:.2f})") + f" @{int(step):,}"


def tab_ablations(root, sig, sel: Sel, best_suite_only: bool = False) -> None:
    """Each ablation group (:data:`harness.labels.ABLATIONS`) from each suite that holds two or more of its methods,
    a suite at a time (runs of two suites are never pooled). ``best_suite_only`` (the sidebar's default view): only the
    suite with the largest budget (ties: the most of the group's methods), so a real ablation run wins over a smoke
    test."""
    df = filtered(root, sig, sel)
    if len(df):  # one suite at a time below: undo the per-suite names of a selection of all suites
        df = df.assign(algo=df["algo"].map(A.base_algo))
    shown = 0
    for title, group in ABLATIONS.items():
        d = df[df["algo"].isin(group)] if len(df) else df
        if d.empty:
            continue
        per = d.groupby("suite").agg(n=("algo", "nunique"), step=("step", "max"))
        per = per[per["n"] >= 2].sort_values(["step", "n"], ascending=False, kind="stable")
        for suite in per.index[:1] if best_suite_only else per.index:
            shown += 1
            ds = d[d["suite"] == suite]
            present = order_algos(ds["algo"].unique())
            st.subheader(title if best_suite_only or len(per) == 1 else f"{title} · {suite}")
            st.caption(f"Suite **{suite}**: {len(present)} of the group's {len(group)} methods, evaluations up to "
                       f"step {int(per.loc[suite, 'step']):,}."
                       + (" Other suites with two or more: " + ", ".join(per.index[1:]) + " (choose one in the "
                          "sidebar)." if best_suite_only and len(per) > 1 else ""))
            c = curves_for(root, sig, sel._replace(suite=suite, algos=tuple(sorted(present))), "deployed_success", 1,
                           "auto", False)
            curves_grid(c, None, "deployed_success", "se", ncols=3)
            fp = A.final_performance(ds)
            fp["final"] = [_mean_se(*v) for v in zip(fp["mean"], fp["se"], fp["n"], fp["step"])]
            wide = fp.pivot(index="algo", columns="env", values="final")
            wide.index = [algo_label(a) for a in wide.index]
            wide.columns = [env_label(e) for e in wide.columns]
            st.dataframe(wide)
    if not shown:
        lines = "\n".join(f"- {t}: {', '.join(g)}" for t, g in ABLATIONS.items())
        st.info("No suite has results for two or more methods of an ablation yet. The groups:\n" + lines +
                "\n\nRun e.g. `harness run algos=medal,medal_logc,fbrl_vice,bc,gail_naive,gail_oracle envs=... seeds=5`.")
    else:
        st.caption("Final: deployed success at each run's last evaluation, mean (standard error, ddof=1) over seeds, "
                   "@ the largest step used.")


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
