"""Results dashboard (Streamlit).

    streamlit run app.py                       # reads results/ (or $HARNESS_RESULTS)
    streamlit run app.py -- --results DIR      # any results directory

The directory can also be changed in the sidebar. Data are read through ``harness.results.load``
and cached; the cache key is the number and the latest modification time of the
``evals.parquet``/``status.json`` files, so a rerun (any interaction, the Refresh button, or the
auto-refresh option) picks up new results. All statistics come from ``harness.analysis`` and ``harness.stats``.
Tabs run lazily: only the selected tab's content is computed (``?tab=...`` in the URL selects one). The page is
here; its data, charts and tabs live in ``harness/dashboard/``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import streamlit as st

from harness import analysis as A
from harness.dashboard.analysis_tabs import tab_ablations, tab_aggregates, tab_diagnostics
from harness.dashboard.data import OWN, Sel, default_results, load_results, signature, tab_view
from harness.dashboard.reproduction_tabs import tab_reproduction, tab_tuning
from harness.dashboard.results_tabs import tab_curves, tab_runs, tab_table1
from harness.labels import algo_label, env_label, order_algos, order_envs
from harness.run_status import format_duration

TABS = ["Runs", "Learning curves", "Table 1", "Aggregates", "Ablations", "Reproduction", "Diagnostics", "Tuning"]
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


def main() -> None:
    st.set_page_config(page_title="EARL results", page_icon=":material/monitoring:", layout="wide")
    if "results_dir" not in st.session_state:
        st.session_state["results_dir"] = default_results()
    with st.sidebar:
        st.header("Results")
        root = os.path.expanduser(st.text_input("results directory", key="results_dir").strip() or "results")
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
        suite_choice = st.selectbox("suite", [OWN, "all"] + suites, key="suite",
                                    help=f"{OWN}: Table 1 and Aggregates show the Table-1 cells from the runs that "
                                         "check them, Learning curves the latest suite, Ablations a suite per group; "
                                         "all: every suite (a method run in several is split by suite, never pooled)")
        suite = None if suite_choice in ("all", OWN) else suite_choice
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

    own = suite_choice == OWN
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
            elif name == "Ablations":
                tab_ablations(root, sig, sel, best_suite_only=own)
            else:
                view, caption = tab_view(root, sig, df, name) if own else (suite, "")
                if caption:
                    st.caption(caption)
                {"Learning curves": tab_curves, "Table 1": tab_table1, "Aggregates": tab_aggregates}[name](
                    root, sig, sel._replace(suite=view))
    st.sidebar.caption(f"rendered in {time.perf_counter() - t0:.2f} s")
    if auto:
        time.sleep(30)
        st.rerun()


main()
