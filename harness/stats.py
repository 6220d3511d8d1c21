"""Statistics over runs: pure functions (numpy; pandas only for the score tables of :func:`aggregate_scores`).

Conventions
-----------
- **Standard error**: ``std(ddof=1) / sqrt(n)`` over runs (``ddof`` is a parameter everywhere);
  0 when there is one run. Note: the published MEDAL/EARL numbers appear to use ``ddof=0``
  (naive RL on tabletop: 0.17 published; the released final values give 0.173 with ddof=0,
  0.193 with ddof=1).
- **Bootstrap CIs** of a mean over runs: percentile bootstrap, resampling runs with replacement,
  ``n_boot`` resamples, seeded (``numpy.random.default_rng(seed)``): same inputs, same interval.
- **IQM / probability of improvement** follow rliable (Agarwal et al., NeurIPS 2021): the IQM is
  the 25%-trimmed mean of all (run, env) scores pooled; 95% CIs come from a *stratified* bootstrap
  (runs resampled with replacement within each env), percentile method. Implemented here:
  ``rliable`` 1.2 does not import with pandas 3 (its dependency ``arch`` fails at import).
"""

from __future__ import annotations

import math
from typing import Callable, Iterable, Sequence

import numpy as np
import pandas as pd

from harness.labels import algo_label, order_algos, order_envs


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


def no_shared_env(scores: pd.DataFrame, algos: Iterable[str]) -> str:
    """Why no env is shared by every one of ``algos``: per env with results, the chosen methods it lacks
    (``point: lacks FBRL, MEDAL``)."""
    held = scores.groupby("env")["algo"].agg(set)
    return "; ".join(f"{e}: lacks {', '.join(algo_label(a) for a in lack)}" for e in order_envs(held.index)
                     if (lack := [a for a in order_algos(algos) if a not in held[e]]))


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

