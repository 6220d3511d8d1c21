"""Tabs Reproduction (the ladder and Table-1 cells against the published curves) and Tuning (Optuna studies)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import streamlit as st

from harness.dashboard.charts import cell_chart
from harness.dashboard.data import load_published_curves, load_results, read_study, reproduction_suites


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
    f = R.value_text
    view = t.assign(ours_per_seed=[", ".join(f(x, m) for x in v) for v, m in zip(t["ours_per_seed"], t["metric"])],
                    published=[f(x, m) for x, m in zip(t["published"], t["metric"])],
                    ours=[f(x, m) for x, m in zip(t["ours"], t["metric"])],
                    published_range=[R.range_text(a, b, m) for a, b, m in zip(t["published_min"], t["published_max"],
                                                                               t["metric"])],
                    accepted=[R.range_text(a, b, m) for (a, b), m in zip(t["band"], t["metric"])])
    whole = ["curve", "first_success"] if "curve" in t else []
    st.dataframe(view[["method", "env", "metric", "budget", "seeds", "window", "published", "published_range", "accepted", "ours",
                       "ours_per_seed", "verdict", *whole]], hide_index=True,
                 column_config={"published": st.column_config.TextColumn("published mean"),
                                "ours": st.column_config.TextColumn("ours: seed mean"),
                                "budget": st.column_config.NumberColumn("budget", format="%d"),
                                "verdict": st.column_config.TextColumn("final window"),
                                "curve": st.column_config.TextColumn("whole curve (every 100k window)"),
                                "first_success": st.column_config.TextColumn("first success (>= 0.5)")})
    own = sorted({f"{c.env} {c.widen:g}" for c in ladder.cells if c.widen is not None})
    suite_w = any(c.widen is None for c in ladder.cells)
    widen = ", ".join(([f"{ladder.widen:g}"] if suite_w else []) + ([f"in return units: {', '.join(own)}"] if own else []))
    st.caption(f"A check passes when our seed-mean of the window means lies in [published min - w, published max + w], "
               f"w = {widen} (the per-seed range of the published seeds, widened); it is running "
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
