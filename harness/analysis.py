"""Analysis of the long results table: pure functions (pandas/numpy), shared by ``app.py`` and
``harness report``.

Conventions
-----------
- A *run* is one (source, suite, env, algo, seed); its label is the ``run`` column that
  :func:`with_runs` adds (``<suite or source>/<seed>``), so results of several suites can be pooled.
  Our own rows have ``source == "harness"``; published curves (``harness.results.load_published``)
  keep their ``source`` (``earl_benchmark``, ``risc_paper``).
- **Common evaluation grid** (:func:`aligned`), per (source, env, algo):
  ``grid="common"`` keeps the steps that *every* run of that method evaluated at (the
  intersection; the curve ends where the shortest run ends). ``grid="interp"`` linearly
  interpolates each run onto the union of the evaluation steps inside the range that every run
  covers (no extrapolation). ``grid="auto"`` (default) uses ``common`` unless the intersection
  holds fewer than half of those union steps (runs evaluated at different steps, e.g. published
  curves of different lengths), in which case it interpolates.
- **Standard error**: ``std(ddof=1) / sqrt(n)`` over runs (``ddof`` is a parameter everywhere);
  0 when there is one run. Note: the published MEDAL/EARL numbers appear to use ``ddof=0``
  (naive RL on tabletop: 0.17 published; the released final values give 0.173 with ddof=0,
  0.193 with ddof=1).
- **Bootstrap CIs** of a mean over runs: percentile bootstrap, resampling runs with replacement,
  ``n_boot`` resamples, seeded (``numpy.random.default_rng(seed)``): same inputs, same interval.
- **Smoothing**: trailing moving average over ``window`` consecutive evaluations of each run
  (``min_periods=1``), applied on the common grid before averaging over runs.
- **Final performance** (:func:`final_scores`): per run, the value at its last evaluation
  (or the mean of its last ``last_k`` evaluations); ``step=<int>`` uses the last evaluation at or
  before that step (runs that did not reach it are left out); ``step="matched"`` uses, per env,
  the largest step that every run of every method in that env reached.
- **IQM / probability of improvement** follow rliable (Agarwal et al., NeurIPS 2021): the IQM is
  the 25%-trimmed mean of all (run, env) scores pooled; 95% CIs come from a *stratified* bootstrap
  (runs resampled with replacement within each env), percentile method. Implemented here:
  ``rliable`` 1.2 does not import with pandas 3 (its dependency ``arch`` fails at import).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import pandas as pd

OURS = "harness"
ENV_ORDER = ("tabletop_manipulation", "sawyer_door", "sawyer_peg")
ENV_LABELS = {
    "tabletop_manipulation": "Tabletop Organization",
    "sawyer_door": "Sawyer Door",
    "sawyer_peg": "Sawyer Peg",
}
ALGO_ORDER = ("naive", "fbrl", "r3l", "vaprl", "medal", "oracle")
ALGO_LABELS = {
    "naive": "naive RL",
    "fbrl": "FBRL",
    "r3l": "R3L",
    "vaprl": "VaPRL",
    "medal": "MEDAL",
    "oracle": "oracle RL (episodic)",
    "medal_logc": "MEDAL (log C reward)",
    "fbrl_vice": "FBRL + VICE",
    "bc": "BC",
    "gail_naive": "naive GAIL",
    "gail_oracle": "oracle GAIL",
    "risc": "RISC",
    "risc_no_tab": "RISC w/o TAB",
    "risc_no_timeout_bootstrap": "RISC w/o TAB",  # the RISC paper's name of the same ablation
    "risc_no_switching": "RISC w/o switching",
    "vaprl_risc": "VaPRL (RISC's re-implementation)",
}

#: One fixed colour per method, shared by `harness report` and the dashboard: the 8 Okabe-Ito colours and 7 of
#: Paul Tol's "muted" ones (both chosen to stay apart under the common colour-vision deficiencies), 15 in all, so
#: no two registered methods (nor the published-only RISC ablations) share one.
METHOD_COLORS: dict[str, str] = {
    "naive": "#000000", "fbrl": "#E69F00", "r3l": "#56B4E9", "vaprl": "#009E73", "medal": "#D55E00",
    "oracle": "#0072B2", "medal_logc": "#CC79A7", "fbrl_vice": "#F0E442", "bc": "#882255", "gail_naive": "#117733",
    "gail_oracle": "#332288", "risc": "#AA4499", "risc_no_tab": "#DDCC77", "vaprl_risc": "#44AA99",
    "risc_no_switching": "#88CCEE", "risc_no_timeout_bootstrap": "#DDCC77",  # the published name of risc_no_tab
}
#: for names outside the table (a suite's variants): a deterministic pick from these, by name
EXTRA_COLORS = ("#999933", "#CC6677", "#6699CC", "#997700", "#EE99AA", "#004488", "#994455", "#666666")


def method_color(name: str) -> str:
    """The fixed colour of method ``name`` (a registered algorithm, a published method, or a variant)."""
    import zlib

    return METHOD_COLORS.get(name) or EXTRA_COLORS[zlib.crc32(name.encode()) % len(EXTRA_COLORS)]


#: Table 1 of the MEDAL paper (Sharma, Ahmad, Finn, ICML 2022), as transcribed in
#: docs/algorithms.md section 15: deployed performance of the final policy, mean (standard
#: error) over 5 seeds. Keys: (algo, env) -> (mean, se).
PUBLISHED_TABLE1: dict[tuple[str, str], tuple[float, float]] = {
    ("naive", "tabletop_manipulation"): (0.32, 0.17),
    ("naive", "sawyer_door"): (0.00, 0.00),
    ("naive", "sawyer_peg"): (0.00, 0.00),
    ("fbrl", "tabletop_manipulation"): (0.94, 0.04),
    ("fbrl", "sawyer_door"): (1.00, 0.00),
    ("fbrl", "sawyer_peg"): (0.00, 0.00),
    ("r3l", "tabletop_manipulation"): (0.96, 0.04),
    ("r3l", "sawyer_door"): (0.54, 0.18),
    ("r3l", "sawyer_peg"): (0.00, 0.00),
    ("vaprl", "tabletop_manipulation"): (0.98, 0.02),
    ("vaprl", "sawyer_door"): (0.94, 0.05),
    ("vaprl", "sawyer_peg"): (0.00, 0.00),
    ("medal", "tabletop_manipulation"): (0.98, 0.02),
    ("medal", "sawyer_door"): (1.00, 0.00),
    ("medal", "sawyer_peg"): (0.40, 0.16),
    ("oracle", "tabletop_manipulation"): (0.80, 0.11),
    ("oracle", "sawyer_door"): (1.00, 0.00),
    ("oracle", "sawyer_peg"): (1.00, 0.00),
}
PUBLISHED_TABLE1_SOURCE = "MEDAL paper (Sharma et al., ICML 2022), Table 1, via docs/algorithms.md §15"

#: ablation groups shown by the dashboard when their algorithms have results
ABLATIONS: dict[str, tuple[str, ...]] = {
    "Imitation (BC / GAIL vs MEDAL)": ("bc", "gail_naive", "gail_oracle", "medal"),
    "State distribution (MEDAL vs FBRL + VICE)": ("medal", "fbrl_vice"),
    "Reward form (MEDAL vs log C)": ("medal", "medal_logc"),
}

#: metrics derived from the stored ones by :func:`derive_metrics`
DERIVED_METRICS = {"continuing_reward_rate": "continuing_reward / step (average reward per training step)"}


def env_label(env: str) -> str:
    return ENV_LABELS.get(env, env)


def algo_label(algo: str) -> str:
    return ALGO_LABELS.get(algo, algo)


def order_envs(envs: Iterable[str]) -> list[str]:
    envs = list(dict.fromkeys(envs))
    return [e for e in ENV_ORDER if e in envs] + sorted(e for e in envs if e not in ENV_ORDER)


def order_algos(algos: Iterable[str]) -> list[str]:
    algos = list(dict.fromkeys(algos))
    known = [a for a in ALGO_ORDER if a in algos]
    return known + sorted(a for a in algos if a not in ALGO_ORDER)


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
    pairs = pd.MultiIndex.from_frame(ours[["env", "algo"]].drop_duplicates())
    return df[pd.MultiIndex.from_frame(df[["env", "algo"]]).isin(pairs)]


# --------------------------------------------------------------------------------------------
# common grid, curves, smoothing, bootstrap


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


def standard_error(x: np.ndarray, axis: int = -1, ddof: int = 1) -> np.ndarray:
    """``std(ddof) / sqrt(n)`` along ``axis``; 0 where n <= ddof (a single run)."""
    x = np.asarray(x, dtype=float)
    n = x.shape[axis]
    if n <= ddof:
        return np.zeros(np.delete(x.shape, axis)) if x.ndim > 1 else np.float64(0.0)
    return np.std(x, axis=axis, ddof=ddof) / math.sqrt(n)


def bootstrap_mean_ci(
    x: np.ndarray, n_boot: int = 2000, alpha: float = 0.05, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile-bootstrap (1 - alpha) CI of the mean over the last axis (runs), resampling runs
    with replacement. ``x``: (..., n_runs). Returns (lo, hi) with shape ``x.shape[:-1]``."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=(n_boot, n))
    means = x[..., idx].mean(axis=-1)  # (..., n_boot)
    lo, hi = np.percentile(means, [100 * alpha / 2, 100 * (1 - alpha / 2)], axis=-1)
    return lo, hi


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
# final performance and Table 1


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


def table1(
    df: pd.DataFrame,
    metric: str = "deployed_success",
    step: int | str | None = None,
    last_k: int = 1,
    published: dict[tuple[str, str], tuple[float, float]] | None = PUBLISHED_TABLE1,
    ddof: int = 1,
    digits: int = 2,
) -> pd.DataFrame:
    """Our final performance beside the published Table 1: one row per (algo, env) with columns
    algo, env, ours_mean, ours_se, n, step, paper_mean, paper_se, diff (ours - paper),
    ours_best, paper_best (best per env after rounding to ``digits``, ties all best, as the paper
    bolds). Envs: those of our results (all three of the paper's when we have none); methods: ours,
    then the paper's (when ``published``)."""
    ours = final_performance(select(with_runs(df), source=OURS), metric, step, last_k, ddof)
    published = published or {}
    envs = order_envs(ours["env"]) or order_envs(e for _, e in published)
    algos = order_algos(list(ours["algo"]) + [a for a, e in published if e in envs])
    rows = []
    for env in envs:
        for algo in algos:
            o = ours[(ours["env"] == env) & (ours["algo"] == algo)]
            p = published.get((algo, env))
            if o.empty and p is None:
                continue
            r = {"algo": algo, "env": env}
            if o.empty:
                r.update(ours_mean=np.nan, ours_se=np.nan, n=0, step=np.nan)
            else:
                o = o.iloc[0]
                r.update(ours_mean=float(o["mean"]), ours_se=float(o["se"]), n=int(o["n"]), step=float(o["step"]))
            r["paper_mean"], r["paper_se"] = (p if p is not None else (np.nan, np.nan))
            r["diff"] = r["ours_mean"] - r["paper_mean"]
            rows.append(r)
    cols = ["algo", "env", "ours_mean", "ours_se", "n", "step", "paper_mean", "paper_se", "diff", "ours_best", "paper_best"]
    if not rows:
        return pd.DataFrame(columns=cols)
    t = pd.DataFrame(rows)
    for who in ("ours", "paper"):
        r = t[f"{who}_mean"].round(digits)
        best = r.groupby(t["env"]).transform("max")
        t[f"{who}_best"] = r.notna() & (r == best)
    t["n"] = t["n"].astype("int64")
    return t[cols]


def _fmt_ms(m: float, se: float, digits: int) -> str:
    if m is None or (isinstance(m, float) and math.isnan(m)):
        return "–"
    return f"{m:.{digits}f} ({se:.{digits}f})"


def _fmt_diff(d: float, digits: int) -> str:
    if d is None or math.isnan(d):
        return "–"
    return f"{0.0:.{digits}f}" if round(d, digits) == 0 else f"{d:+.{digits}f}"


def table1_display(t: pd.DataFrame, digits: int = 2, bold: Callable[[str], str] | None = None,
                   published: bool = True) -> pd.DataFrame:
    """Wide display table: one row per method, per env the columns ``<Env> ours``, ``<Env> paper``
    and ``<Env> Δ`` (strings, mean (SE), best wrapped by ``bold``). ``published=False`` keeps
    only ours."""
    bold = bold or (lambda s: s)
    envs = order_envs(t["env"])
    algos = order_algos(t["algo"])
    out = pd.DataFrame(index=pd.Index([algo_label(a) for a in algos], name="Method"))
    for env in envs:
        e = t[t["env"] == env].set_index("algo")
        lab = env_label(env)
        ours, paper, diff = [], [], []
        for a in algos:
            if a not in e.index:
                ours.append("–"), paper.append("–"), diff.append("–")
                continue
            r = e.loc[a]
            s = _fmt_ms(r["ours_mean"], r["ours_se"], digits)
            ours.append(bold(s) if r["ours_best"] and s != "–" else s)
            s = _fmt_ms(r["paper_mean"], r["paper_se"], digits)
            paper.append(bold(s) if r["paper_best"] and s != "–" else s)
            diff.append(_fmt_diff(r["diff"], digits))
        out[f"{lab} ours"] = ours
        if published:
            out[f"{lab} paper"] = paper
            out[f"{lab} Δ"] = diff
    return out


def table1_markdown(t: pd.DataFrame, digits: int = 2, published: bool = True) -> str:
    """GitHub Markdown of :func:`table1_display`, best entries in ``**bold**``."""
    w = table1_display(t, digits, lambda s: f"**{s}**", published)
    header = ["Method"] + list(w.columns)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + [":-:"] * len(w.columns)) + "|"]
    for name, row in w.iterrows():
        lines.append("| " + " | ".join([str(name)] + [str(v) for v in row]) + " |")
    return "\n".join(lines) + "\n"


def _tex(s: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"),
                 ("Δ", r"$\Delta$"), ("±", r"$\pm$"), ("–", "--")):
        s = s.replace(a, b)
    return s


def table1_latex(t: pd.DataFrame, digits: int = 2, published: bool = True, caption: str | None = None) -> str:
    """A booktabs LaTeX table of :func:`table1_display` (best entries in ``\\textbf``)."""
    w = table1_display(t, digits, lambda s: "\x00" + s + "\x01", published)
    envs = order_envs(t["env"])
    sub = ["ours", "paper", r"$\Delta$"] if published else ["ours"]
    k = len(sub)
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             r"\begin{tabular}{l" + ("c" * k * len(envs)) + "}", r"\toprule"]
    lines.append("Method & " + " & ".join(rf"\multicolumn{{{k}}}{{c}}{{{_tex(env_label(e))}}}" for e in envs) + r" \\")
    if k > 1:
        lines.append("".join(rf"\cmidrule(lr){{{2 + i * k}-{1 + (i + 1) * k}}}" for i in range(len(envs))))
        lines.append(" & " + " & ".join(sub * len(envs)) + r" \\")
    lines.append(r"\midrule")
    for name, row in w.iterrows():
        cells = [_tex(str(v)).replace("\x00", r"\textbf{").replace("\x01", "}") for v in row]
        lines.append(_tex(str(name)) + " & " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    cap = caption or ("Deployed success of the final policy, mean (standard error) over seeds; "
                      "paper: " + PUBLISHED_TABLE1_SOURCE.split(", via")[0] + "; $\\Delta$ = ours $-$ paper.")
    lines += [rf"\caption{{{_tex(cap) if caption else cap}}}", r"\label{tab:table1}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def table1_csv(t: pd.DataFrame) -> str:
    """The long numeric table (no formatting) as CSV text."""
    return t.to_csv(index=False)


# --------------------------------------------------------------------------------------------
# aggregates across envs (rliable-style)


def iqm(x: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (``scipy.stats.trim_mean(x, 0.25)``: drops
    ``int(0.25 n)`` values at each end after sorting)."""
    x = np.asarray(x, dtype=float)
    if axis is None:
        x, axis = x.ravel(), 0
    x = np.sort(x, axis=axis)
    n = x.shape[axis]
    k = int(0.25 * n)
    return np.take(x, np.arange(k, n - k), axis=axis).mean(axis=axis)


def stratified_bootstrap(
    scores_by_task: Sequence[np.ndarray],
    statistic: Callable[[np.ndarray], np.ndarray] = iqm,
    reps: int = 2000,
    alpha: float = 0.05,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(point, lo, hi): ``statistic`` of the pooled scores and its (1 - alpha) percentile CI from
    a stratified bootstrap, runs resampled with replacement within each task. ``statistic`` takes
    a (reps, n_total) array and reduces axis 1 (:func:`iqm` and ``np.mean`` do)."""
    tasks = [np.asarray(s, dtype=float).ravel() for s in scores_by_task if len(s)]
    if not tasks:
        return (math.nan, math.nan, math.nan)
    rng = np.random.default_rng(seed)
    pooled = np.concatenate(tasks)
    point = float(_stat(statistic, pooled[None, :])[0])
    boot = np.concatenate([t[rng.integers(0, len(t), size=(reps, len(t)))] for t in tasks], axis=1)
    vals = _stat(statistic, boot)
    lo, hi = np.percentile(vals, [100 * alpha / 2, 100 * (1 - alpha / 2)])
    return point, float(lo), float(hi)


def _stat(statistic, x: np.ndarray) -> np.ndarray:
    try:
        return np.asarray(statistic(x, axis=1), dtype=float)
    except TypeError:
        return np.array([statistic(row) for row in x], dtype=float)


def _prob_improvement_task(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + 0.5 P(X = Y) over all run pairs (the Mann-Whitney U statistic / (n m))."""
    x, y = np.asarray(x, dtype=float)[:, None], np.asarray(y, dtype=float)[None, :]
    return float(((x > y).sum() + 0.5 * (x == y).sum()) / (x.size * y.size))


def probability_of_improvement(
    x_by_task: Sequence[np.ndarray],
    y_by_task: Sequence[np.ndarray],
    reps: int = 2000,
    alpha: float = 0.05,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(P(X > Y), lo, hi): the average over tasks of P(X_task > Y_task) + 0.5 P(=), with a
    stratified-bootstrap percentile CI (runs of X and of Y resampled within each task)."""
    pairs = [(np.asarray(a, float).ravel(), np.asarray(b, float).ravel()) for a, b in zip(x_by_task, y_by_task)
             if len(a) and len(b)]
    if not pairs:
        return (math.nan, math.nan, math.nan)
    point = float(np.mean([_prob_improvement_task(a, b) for a, b in pairs]))
    rng = np.random.default_rng(seed)
    acc = np.zeros(reps)
    for a, b in pairs:
        xa = a[rng.integers(0, len(a), size=(reps, len(a)))][:, :, None]
        yb = b[rng.integers(0, len(b), size=(reps, len(b)))][:, None, :]
        acc += ((xa > yb).sum(axis=(1, 2)) + 0.5 * (xa == yb).sum(axis=(1, 2))) / (len(a) * len(b))
    vals = acc / len(pairs)
    lo, hi = np.percentile(vals, [100 * alpha / 2, 100 * (1 - alpha / 2)])
    return point, float(lo), float(hi)


def scores_by_task(scores: pd.DataFrame, algo: str, envs: Sequence[str]) -> list[np.ndarray]:
    """Per env (in ``envs`` order) the array of ``algo``'s run scores (from :func:`final_scores`)."""
    s = scores[scores["algo"] == algo]
    return [s.loc[s["env"] == e, "score"].to_numpy(dtype=float) for e in envs]


def common_envs(scores: pd.DataFrame, algos: Iterable[str]) -> list[str]:
    """The envs where every one of ``algos`` has at least one run."""
    algos = list(algos)
    have = [set(scores.loc[scores["algo"] == a, "env"]) for a in algos]
    inter = set.intersection(*have) if have else set()
    return order_envs(inter)


def aggregate_scores(
    scores: pd.DataFrame,
    algos: Sequence[str] | None = None,
    envs: Sequence[str] | None = None,
    reps: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """IQM and mean across envs with 95% stratified-bootstrap CIs, per algo, over ``envs``
    (default: the envs all ``algos`` share). Columns: algo, iqm, iqm_lo, iqm_hi, mean, mean_lo,
    mean_hi, n_envs, n_runs."""
    algos = order_algos(algos if algos is not None else scores["algo"].unique())
    envs = list(envs) if envs is not None else common_envs(scores, algos)
    rows = []
    for a in algos:
        t = scores_by_task(scores, a, envs)
        if not any(len(x) for x in t):
            continue
        i = stratified_bootstrap(t, iqm, reps, seed=seed)
        m = stratified_bootstrap(t, np.mean, reps, seed=seed)
        rows.append({"algo": a, "iqm": i[0], "iqm_lo": i[1], "iqm_hi": i[2], "mean": m[0], "mean_lo": m[1],
                     "mean_hi": m[2], "n_envs": sum(1 for x in t if len(x)), "n_runs": int(sum(len(x) for x in t))})
    return pd.DataFrame(rows, columns=["algo", "iqm", "iqm_lo", "iqm_hi", "mean", "mean_lo", "mean_hi", "n_envs", "n_runs"])


# --------------------------------------------------------------------------------------------
# run status


STATUS_COLUMNS = ["suite", "env", "algo", "seed", "tuning", "state", "step", "total", "progress", "steps_per_s", "eta_s",
                  "last_success", "error", "updated", "age_s", "dir"]


def parts_of(run_dir: Path, root: Path) -> tuple[str, ...]:
    return run_dir.relative_to(root).parts if run_dir != root else ()


def _ident_from_path(run_dir: Path, root: Path) -> dict[str, Any]:
    parts = parts_of(run_dir, root)
    ident: dict[str, Any] = {"suite": None, "env": None, "algo": None, "seed": None}
    if parts and parts[-1].startswith("seed="):
        try:
            ident["seed"] = int(parts[-1].split("=", 1)[1])
        except ValueError:
            pass
        rest = parts[:-1]
        for k, v in zip(("algo", "env", "suite"), reversed(rest)):
            ident[k] = v
        if len(rest) > 3:  # nested under another folder: keep the full prefix as the suite label
            ident["suite"] = "/".join(rest[:-2])
    return ident


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def run_status(results: str | Path, now: float | None = None, stale_after: float = 900.0) -> pd.DataFrame:
    """One row per run directory under ``results`` (any folder with a ``status.json`` or an
    ``evals.parquet``). ``state`` is the status file's (running / done / failed / resumed), or
    ``unknown`` without one; a running or resumed run whose status was last updated more than
    ``max(stale_after, 3 x (eval interval from run.yaml) / steps_per_s)`` seconds ago is marked
    ``stale``. ``error`` is the first line of the recorded error; ``tuning`` marks the trial runs of
    ``harness tune`` (under ``<results>/tuning/``)."""
    from harness.results import EVALS_FILE, RUN_FILE, STATUS_FILE

    root = Path(results)
    now = time.time() if now is None else now
    dirs = sorted({p.parent for name in (STATUS_FILE, EVALS_FILE) for p in root.rglob(name)})
    rows = []
    for d in dirs:
        r = _ident_from_path(d, root)
        st: dict[str, Any] = {}
        p = d / STATUS_FILE
        if p.exists():
            try:
                st = json.loads(p.read_text())
            except (OSError, ValueError) as e:
                st = {"state": "unknown", "error": f"unreadable status.json: {type(e).__name__}: {e}"}
            if not isinstance(st, dict):
                st = {"state": "unknown", "error": "status.json is not a JSON object"}
        state = str(st.get("state") or "unknown")
        updated = _num(st.get("updated"))
        if math.isnan(updated) and p.exists():
            updated = p.stat().st_mtime
        age = now - updated if not math.isnan(updated) else math.nan
        step, total, rate = _num(st.get("step")), _num(st.get("total")), _num(st.get("steps_per_s"))
        if state in ("running", "resumed") and not math.isnan(age):
            limit = stale_after
            eval_every = _eval_every(d / RUN_FILE)
            if eval_every and rate > 0:
                limit = max(limit, 3 * eval_every / rate)
            if age > limit:
                state = "stale"
        err = st.get("error")
        err = str(err).strip().splitlines()[0] if err else ""
        rows.append({**r, "tuning": bool(parts_of(d, root)[:1] == ("tuning",)), "state": state, "step": step, "total": total,
                     "progress": step / total if total and total > 0 and not math.isnan(step) else math.nan,
                     "steps_per_s": rate, "eta_s": _num(st.get("eta_s")), "last_success": _num(st.get("last_success")),
                     "error": err, "updated": updated, "age_s": age, "dir": str(d)})
    out = pd.DataFrame(rows, columns=STATUS_COLUMNS)
    return out.astype({"seed": "Int64"}) if len(out) else out


def _eval_every(run_yaml: Path) -> float | None:
    if not run_yaml.exists():
        return None
    try:
        import yaml

        v = (yaml.safe_load(run_yaml.read_text()) or {}).get("eval_every")
        return float(v) if v else None
    except Exception:  # noqa: BLE001 - status display only
        return None


def status_counts(status: pd.DataFrame) -> dict[str, int]:
    """Runs per state, in a fixed order (only states present)."""
    order = ["running", "resumed", "stale", "done", "failed", "unknown"]
    c = status["state"].value_counts()
    return {s: int(c[s]) for s in order + sorted(set(c.index) - set(order)) if s in c.index}


def format_duration(s: float) -> str:
    """``1h02m``, ``3m05s``, ``?`` for unknown/infinite."""
    if s is None or not math.isfinite(s):
        return "?"
    s = int(max(s, 0))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"
