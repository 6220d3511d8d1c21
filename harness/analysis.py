"""Analysis of the long results table: pure functions (pandas/numpy), shared by ``app.py`` and
``harness report``: selecting rows, aligning runs on a common grid, smoothing, learning curves and final scores.
The statistics themselves are in ``harness.stats``, names and colours in ``harness.labels``, Table 1 in
``harness.tables`` and the run status in ``harness.run_status``.

Conventions
-----------
- A *run* is one (source, suite, env, algo, seed); its label is the ``run`` column that
  :func:`with_runs` adds (``<suite or source>/<seed>``). Runs of one method from several suites are never pooled:
  :func:`separate_suites` names them ``<algo> · <suite>`` first (the dashboard and ``harness report`` do).
  Our own rows have ``source == "harness"``; published curves (``harness.results.load_published``)
  keep their ``source`` (``earl_benchmark``, ``risc_paper``).
- **Common evaluation grid** (:func:`aligned`), per (source, env, algo):
  ``grid="common"`` keeps the steps that *every* run of that method evaluated at (the
  intersection; the curve ends where the shortest run ends). ``grid="interp"`` linearly
  interpolates each run onto the union of the evaluation steps inside the range that every run
  covers (no extrapolation). ``grid="auto"`` (default) uses ``common`` unless the intersection
  holds fewer than half of those union steps (runs evaluated at different steps, e.g. published
  curves of different lengths), in which case it interpolates.
- **Standard error** and **bootstrap CIs** over runs: see ``harness.stats``.
- **Smoothing**: trailing moving average over ``window`` consecutive evaluations of each run
  (``min_periods=1``), applied on the common grid before averaging over runs.
- **Final performance** (:func:`final_scores`): per run, the value at its last evaluation
  (or the mean of its last ``last_k`` evaluations); ``step=<int>`` uses the last evaluation at or
  before that step (runs that did not reach it are left out); ``step="matched"`` uses, per env,
  the largest step that every run of every method in that env reached.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from harness.labels import COHORT_SEP  # joins a method and its suite when a selection holds several suites of it
from harness.stats import bootstrap_mean_ci, standard_error

OURS = "harness"

#: metrics derived from the stored ones by :func:`derive_metrics`
DERIVED_METRICS = {"continuing_reward_rate": "continuing_reward / step (average reward per training step)"}


# --------------------------------------------------------------------------------------------
# preparation


def is_tuning(df: pd.DataFrame) -> pd.Series:
    """Rows of ``harness tune`` trials (``study`` metadata set, or a ``tune_<study>`` suite): they
    live under ``<results>/tuning/`` and are left out of the comparisons unless asked for."""
    mask = pd.Series(False, index=df.index)
    if "study" in df:
        mask |= df["study"].notna()
    if "suite" in df:
        mask |= df["suite"].astype(str).str.startswith("tune_")
    return mask


def with_runs(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with a ``source`` (default ``harness``) and a ``run`` label per (source, suite, seed,
    tuning trial)."""
    df = df.copy()
    if "source" not in df or df["source"].isna().all():
        df["source"] = OURS
    df["source"] = df["source"].fillna(OURS).astype(str)
    if "suite" in df:
        suite = df["suite"].astype(object).where(df["suite"].notna(), df["source"]).astype(str)
    else:
        suite = df["source"]
    df["run"] = suite + "/" + df["seed"].astype("int64").astype(str)
    if "trial" in df and df["trial"].notna().any():
        trial = df["trial"].astype("Int64").astype(str)
        df["run"] = df["run"].where(df["trial"].isna(), df["run"] + "/trial=" + trial)
    return df




def separate_suites(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` where each method whose own runs come from more than one suite is split by suite (on every env): its
    ``algo`` becomes ``<algo> · <suite>``, so runs of different suites (other budgets, other settings: a 400-step smoke run
    beside 1.5M-step ladder runs) are never averaged as seeds of one method. Published rows and methods from one suite
    keep their names. Undo with :func:`base_algo`."""
    if df.empty or "suite" not in df:
        return df
    ours = df["source"].fillna(OURS).eq(OURS) if "source" in df else pd.Series(True, index=df.index)
    suites = df[ours].groupby("algo")["suite"].nunique()  # per method over the whole selection: one name on every env
    mixed = suites[suites > 1].index
    if mixed.empty:
        return df
    hit = ours & df["algo"].isin(mixed)
    df = df.copy()
    df["algo"] = df["algo"].astype(object)
    df.loc[hit, "algo"] = df.loc[hit, "algo"].astype(str) + COHORT_SEP + df.loc[hit, "suite"].astype(str)
    return df


def base_algo(name: str) -> str:
    """The method of a name made by :func:`separate_suites` (the name itself otherwise)."""
    return name.split(COHORT_SEP, 1)[0]


def derive_metrics(df: pd.DataFrame) -> pd.DataFrame:
    """Append the derived metrics (:data:`DERIVED_METRICS`) as extra rows."""
    cr = df[(df["metric"] == "continuing_reward") & (df["step"] > 0)]
    if cr.empty:
        return df
    rate = cr.assign(metric="continuing_reward_rate", value=cr["value"] / cr["step"])
    return pd.concat([df, rate], ignore_index=True)


def select(df: pd.DataFrame, metric: str | None = None, **eq: Any) -> pd.DataFrame:
    """Rows with ``metric`` and column == value (or ``in`` a list/tuple/set) for each keyword."""
    mask = np.ones(len(df), dtype=bool)
    if metric is not None:
        mask &= (df["metric"] == metric).to_numpy()
    for col, v in eq.items():
        if v is None:
            continue
        if isinstance(v, (list, tuple, set, frozenset)):
            mask &= df[col].isin(list(v)).to_numpy()
        else:
            mask &= (df[col] == v).to_numpy()
    return df[mask]


def same_pairs(df: pd.DataFrame, ours: pd.DataFrame) -> pd.DataFrame:
    """Rows of ``df`` (e.g. published curves) whose (env, algo) pair also occurs in ``ours``: a method run on one
    env only is not drawn from the paper on the others."""
    o = ours[["env", "algo"]].drop_duplicates()
    pairs = pd.MultiIndex.from_frame(o.assign(algo=o["algo"].astype(str).map(base_algo)))
    return df[pd.MultiIndex.from_frame(df[["env", "algo"]]).isin(pairs)]


# --------------------------------------------------------------------------------------------
# common grid, curves, smoothing


def _wide(g: pd.DataFrame) -> pd.DataFrame:
    """steps x runs (mean if a (run, step) repeats)."""
    return g.pivot_table(index="step", columns="run", values="value", aggfunc="mean").sort_index()


def align_wide(wide: pd.DataFrame, grid: str = "auto") -> tuple[pd.DataFrame, str]:
    """One method's steps x runs table on its common grid; returns (table, mode used)."""
    if grid not in ("auto", "common", "interp"):
        raise ValueError(f"grid must be auto, common or interp, got {grid!r}")
    if wide.shape[1] <= 1:
        return wide.dropna(), "common"
    common = wide.dropna(how="any")
    lo = max(wide[c].first_valid_index() for c in wide)
    hi = min(wide[c].last_valid_index() for c in wide)
    union = wide.index[(wide.index >= lo) & (wide.index <= hi)]
    if grid == "common" or (grid == "auto" and len(common) >= 0.5 * len(union)):
        return common, "common"
    steps = union.to_numpy()
    out = {}
    for c in wide:
        s = wide[c].dropna()
        out[c] = np.interp(steps, s.index.to_numpy(dtype=float), s.to_numpy(dtype=float))
    return pd.DataFrame(out, index=pd.Index(steps, name="step")), "interp"


def aligned(df: pd.DataFrame, metric: str, grid: str = "auto") -> pd.DataFrame:
    """Long table ``source, env, algo, run, step, value`` of ``metric`` on each method's common
    grid (see the module docstring), plus ``grid`` (the mode used)."""
    d = with_runs(select(df, metric))
    parts = []
    for (src, env, algo), g in d.groupby(["source", "env", "algo"], sort=False):
        w, mode = align_wide(_wide(g), grid)
        long = w.reset_index().melt(id_vars="step", var_name="run", value_name="value")
        parts.append(long.assign(source=src, env=env, algo=algo, grid=mode))
    if not parts:
        return pd.DataFrame(columns=["source", "env", "algo", "run", "step", "value", "grid"])
    return pd.concat(parts, ignore_index=True)[["source", "env", "algo", "run", "step", "value", "grid"]]


def smooth_wide(wide: pd.DataFrame, window: int) -> pd.DataFrame:
    """Trailing moving average over ``window`` evaluations of each run (column)."""
    if window is None or window <= 1:
        return wide
    return wide.rolling(int(window), min_periods=1).mean()


def smooth(df: pd.DataFrame, window: int) -> pd.DataFrame:
    """Trailing moving average of ``value`` over ``window`` evaluations within each run of a long
    table (grouped by source/suite/env/algo/seed/metric as present, ordered by step)."""
    if window is None or window <= 1 or df.empty:
        return df
    keys = [c for c in ("source", "suite", "env", "algo", "seed", "run", "metric") if c in df]
    out = df.sort_values(keys + ["step"]).copy()
    out["value"] = out.groupby(keys, sort=False, dropna=False)["value"].transform(
        lambda s: s.rolling(int(window), min_periods=1).mean()
    )
    return out


def learning_curves(
    df: pd.DataFrame,
    metric: str = "deployed_success",
    window: int = 1,
    grid: str = "auto",
    ci: bool = False,
    n_boot: int = 1000,
    seed: int = 0,
    ddof: int = 1,
) -> pd.DataFrame:
    """Mean and standard error over runs per (source, env, algo, step) on the common grid, after
    smoothing; with ``ci`` also the 95% percentile-bootstrap CI of the mean (``ci_lo``, ``ci_hi``).
    Columns: source, env, algo, step, mean, se, n, ci_lo, ci_hi, grid."""
    d = with_runs(select(df, metric))
    rows = []
    for (src, env, algo), g in d.groupby(["source", "env", "algo"], sort=False):
        w, mode = align_wide(_wide(g), grid)
        if w.empty:
            continue
        w = smooth_wide(w, window)
        x = w.to_numpy(dtype=float)
        n = x.shape[1]
        part = pd.DataFrame({
            "source": src, "env": env, "algo": algo, "step": w.index.to_numpy(),
            "mean": x.mean(axis=1), "se": standard_error(x, axis=1, ddof=ddof), "n": n, "grid": mode,
        })
        if ci:
            part["ci_lo"], part["ci_hi"] = bootstrap_mean_ci(x, n_boot=n_boot, seed=seed)
        else:
            part["ci_lo"] = part["ci_hi"] = np.nan
        rows.append(part)
    cols = ["source", "env", "algo", "step", "mean", "se", "n", "ci_lo", "ci_hi", "grid"]
    if not rows:
        return pd.DataFrame(columns=cols)
    return pd.concat(rows, ignore_index=True)[cols]


# --------------------------------------------------------------------------------------------
# final performance (Table 1 itself: harness.tables)


def matched_steps(df: pd.DataFrame, metric: str = "deployed_success") -> dict[str, int]:
    """Per env: the largest step every run of every method reached (min over runs of max step)."""
    d = with_runs(select(df, metric))
    last = d.groupby(["env", "algo", "run"])["step"].max()
    return {env: int(s.min()) for env, s in last.groupby(level="env")}


def final_scores(
    df: pd.DataFrame,
    metric: str = "deployed_success",
    step: int | str | None = None,
    last_k: int = 1,
) -> pd.DataFrame:
    """One score per run: columns source, env, algo, run, seed, step, score.

    ``step=None``: each run's last evaluation; ``step=<int>``: the last evaluation at or before
    it (runs that stopped earlier are left out); ``step="matched"``: per env, the largest step that
    every run there reached (:func:`matched_steps`). ``last_k`` > 1 averages the last k
    evaluations up to that step."""
    d = with_runs(select(df, metric))
    cols = ["source", "env", "algo", "run", "seed", "step", "score"]
    if d.empty:
        return pd.DataFrame(columns=cols)
    d = d.groupby(["source", "env", "algo", "run", "seed", "step"], as_index=False)["value"].mean()
    if step is not None:
        if step == "matched":
            cut = d["env"].map(matched_steps(d.assign(metric=metric), metric))
        else:
            cut = pd.Series(int(step), index=d.index)
        reached = d.groupby(["source", "env", "algo", "run"])["step"].transform("max") >= cut
        d = d[reached & (d["step"] <= cut)]
    d = d.sort_values("step")
    tail = d.groupby(["source", "env", "algo", "run", "seed"], sort=False).tail(max(int(last_k), 1))
    out = tail.groupby(["source", "env", "algo", "run", "seed"], as_index=False).agg(
        step=("step", "max"), score=("value", "mean")
    )
    return out[cols]


def final_performance(
    df: pd.DataFrame,
    metric: str = "deployed_success",
    step: int | str | None = None,
    last_k: int = 1,
    ddof: int = 1,
) -> pd.DataFrame:
    """Mean and standard error over runs of :func:`final_scores` per (source, env, algo):
    columns source, env, algo, mean, se, n, step (largest step used)."""
    s = final_scores(df, metric, step, last_k)
    cols = ["source", "env", "algo", "mean", "se", "n", "step"]
    if s.empty:
        return pd.DataFrame(columns=cols)
    g = s.groupby(["source", "env", "algo"], sort=False)
    out = g.agg(mean=("score", "mean"), n=("score", "size"), step=("step", "max")).reset_index()
    out["se"] = g["score"].apply(lambda v: float(standard_error(v.to_numpy(), ddof=ddof))).to_numpy()
    return out[cols]
