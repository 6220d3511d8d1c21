"""The dashboard's data: results, published curves, diagnostics and tuning studies read through the harness and
cached by Streamlit (the cache key of a results directory is :func:`signature`), and the derived tables each tab shows.
All statistics come from :mod:`harness.analysis`, :mod:`harness.stats` and :mod:`harness.tables`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import NamedTuple

import pandas as pd
import streamlit as st

from harness import analysis as A
from harness.evidence import table1_cell_rows, table1_cells
from harness.results import EVALS_FILE, STATUS_FILE, TRAIN_FILE, load, load_train
from harness.run_status import run_status
from harness.stats import aggregate_scores
from harness.tables import PUBLISHED_TABLE1, table1

SOURCES = ["risc_paper", "earl_benchmark"]
CURVE_METRICS = {
    "deployed_success": "Deployed success",
    "deployed_return": "Deployed return",
    "continuing_reward": "Continuing: cumulative training reward",
    "continuing_reward_rate": "Continuing: average reward per step",
    "interventions": "Interventions (resets)",
}


def default_results() -> str:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--results")
    args, _ = p.parse_known_args(sys.argv[1:])
    return os.path.expanduser(args.results or os.environ.get("HARNESS_RESULTS") or "results")


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


#: the sidebar's first suite choice (the default): each tab shows the view that suits it (:func:`tab_view`)
OWN = "each tab's own"
#: ``Sel.suite`` of Table 1's view: each Table-1 cell's runs from the suite whose cell checks it
TABLE1_CELLS = "Table-1 cells"


class Sel(NamedTuple):
    """The sidebar's selection (hashable: a cache key). ``suite``: one suite, ``None`` (all) or
    :data:`TABLE1_CELLS`."""

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
    if sel.suite == TABLE1_CELLS:  # one suite per (method, env): nothing to pool, names stay the methods'
        return A.select(table1_cell_rows(df, table1_cells_cached()), env=list(sel.envs), algo=list(sel.algos))
    # runs of one method from several suites are shown side by side (MEDAL · reproduction, MEDAL · smoke), never
    # averaged as seeds of one method
    return A.separate_suites(A.select(df, suite=sel.suite, env=list(sel.envs), algo=list(sel.algos)))


@st.cache_data(show_spinner=False)
def table1_cells_cached() -> dict[tuple[str, str], str]:
    return table1_cells()


@st.cache_data(show_spinner=False, max_entries=4)
def latest_suites(root: str, sig: tuple) -> list[str]:
    """The suites under ``root``, the most recently updated first (status.json's ``updated``)."""
    status = run_status(root)
    status = status[~status["tuning"] & status["suite"].notna()]
    if status.empty:
        return []
    return list(status.groupby("suite")["age_s"].min().sort_values(kind="stable").index)


def main_suite(df: pd.DataFrame) -> str:
    """The suite of ``df`` (ours, not empty) with the largest budget reached (ties: the most runs, then the name)."""
    runs = df.drop_duplicates(["suite", "env", "algo", "seed"]).groupby("suite").size().rename("runs")
    g = df.groupby("suite")["step"].max().to_frame().join(runs)
    return str(g.sort_values(["step", "runs"], ascending=False, kind="stable").index[0])


def tab_view(root: str, sig: tuple, df: pd.DataFrame, tab: str) -> tuple[str | None, str]:
    """The default view of ``tab`` (the sidebar's :data:`OWN`): ``(Sel.suite, what it shows)``. Table 1 and Aggregates:
    the Table-1 cells from the runs that check them (:func:`harness.evidence.table1_cell_rows`), or without any, the
    suite with the largest budget; Learning curves: the most recently updated suite; every other tab: all suites
    (Ablations then picks a suite per group)."""
    if df.empty or tab not in ("Table 1", "Aggregates", "Learning curves"):
        return None, ""
    if tab == "Learning curves":
        have = set(df["suite"])
        suite = next((s for s in latest_suites(root, sig) if s in have), None) or main_suite(df)
        return suite, (f"Suite **{suite}**, the most recently updated; choose another (or all) in the sidebar.")
    if len(table1_cell_rows(df, table1_cells_cached())):
        return TABLE1_CELLS, ("The Table-1 cells, each from the runs of the reproduction cell that checks it (suites "
                              "reproduction and table1); choose a suite in the sidebar to see another.")
    suite = main_suite(df)
    return suite, f"Suite **{suite}**, the one with the largest budget; choose another (or all) in the sidebar."


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
    from harness.results import runs_holding

    df, _ = load_results(root, sig)
    return table1_evidence(df, load_published_curves()[0], runs_holding(root))


@st.cache_data(show_spinner=False, max_entries=32)
def scores_for(root, sig, sel: Sel, step, last_k) -> pd.DataFrame:
    return A.final_scores(filtered(root, sig, sel), "deployed_success", step=step, last_k=last_k)


@st.cache_data(show_spinner=False, max_entries=32)
def aggregates_for(root, sig, sel: Sel, step, last_k, reps) -> pd.DataFrame:
    s = scores_for(root, sig, sel, step, last_k)
    return aggregate_scores(s, algos=list(sel.algos), envs=list(sel.envs), reps=reps)


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


@st.cache_resource(show_spinner="Loading training diagnostics…", max_entries=2)
def load_diagnostics(root: str, sig: tuple) -> pd.DataFrame:
    """Every ``train.parquet`` under ``root`` (re-read when ``sig`` changes); shared, not to be modified."""
    df = load_train(root, warn=lambda msg: None)
    for c in ("suite", "env", "algo", "metric"):
        df[c] = df[c].astype(str)
    return df
