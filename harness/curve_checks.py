"""Whole-curve checks of a reproduction cell: every 100k window and the first-success step (docs/reproduction.md).

A final-window check (:mod:`harness.reproduction`) can pass a method whose curve is far from the published one
everywhere else: learning 2-3x faster and then sitting at the top, say. The two checks here look at the whole curve
up to the cell's budget, under one rule for every cell:

**Windows.** For each 100k window ``(lo, lo + 100k]`` up to the budget with at least :data:`MIN_SEEDS` published
seeds complete in it (all 10 evaluations), the band is the published per-seed window means' ``[min - w, max + w]``
(``w`` = the suite's ``widen``, 0.1). Our seed-mean of per-seed window means is *out* when outside the band. The check
passes when at most ``A`` windows are out, where the allowance ``A`` is the smallest number such that a faithful method
(below) has more than ``A`` windows out with probability at most ``alpha`` (0.05).

**First success.** Each seed's first evaluation with deployed success >= 0.5 (a seed that never gets there within the
budget counts as ``budget + eval_every``). The check passes when our seed-mean of those steps lies in the published
seeds' range widened on each side by ``fs_widen`` (50k), or by the smallest larger multiple of 10k that a faithful
method (below) leaves with probability at most ``alpha``; the published steps are censored at the same budget.

**A faithful method** is simulated by a rank-preserving smoothed bootstrap of the published seeds: a simulated seed
picks one published seed and, in every window, takes the published window-mean distribution's quantile (a Beta fitted
by moments, as the final-window criterion's model) at that seed's rank in the window, jittered uniformly within its
rank bin. A seed that was low stays low across windows (the published dips and late starts persist as they do), and
draws still fall between and beyond the published values. Where the metric is a return (kitchen, minitaur:
``CurveRule.bounded`` False) the window distribution is a Normal fitted by moments instead of the Beta, the band's
``widen`` is in return units, and there is no first-success check (a return has no success threshold). For the first-success step, a simulated seed takes a
published seed's step plus Gaussian noise (Silverman's bandwidth over the published steps; a censored step stays
censored). Both probabilities are Monte Carlo estimates with a fixed seed, so the allowance is a pure function of the
published data, the budget, the number of seeds and the rule.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

WINDOW = 100_000
MIN_SEEDS = 3  # published seeds complete in a window for it to be checked
ALPHA = 0.05  # the largest accepted false-fail probability of the whole-curve check
FS_THRESHOLD = 0.5  # "first success": the first evaluation at or above this
FS_WIDEN = 50_000  # the first-success band: published per-seed range +- this
DRAWS = 20_000


@dataclass(frozen=True)
class CurveRule:
    widen: float = 0.1
    alpha: float = ALPHA
    fs_widen: int = FS_WIDEN
    eval_every: int = 10_000
    bounded: bool = True  # the metric is a success rate in [0, 1] (Beta model, first success); False: a return


def window_table(curves: pd.DataFrame, steps: int, eval_every: int = 10_000) -> pd.DataFrame:
    """Per-seed means of every 100k window up to ``steps`` over seeds complete in it: index ``lo``, columns seeds
    (NaN where a seed lacks an evaluation of the window)."""
    c = curves[(curves["step"] > 0) & (curves["step"] <= steps)]
    c = c.assign(lo=(c["step"] - 1) // WINDOW * WINDOW)
    per_window = WINDOW // eval_every
    g = c.groupby(["lo", "seed"])["value"]
    means = g.mean().where(g.count() >= per_window)
    t = means.unstack("seed")
    return t.reindex(range(0, steps - WINDOW + 1, WINDOW))


def published_bands(published: pd.DataFrame, steps: int, widen: float) -> pd.DataFrame:
    """Per checked window (``lo``): the published per-seed window means' min, max and seeds, and the band."""
    t = window_table(published, steps)
    n = t.notna().sum(axis=1)
    t = t[n >= MIN_SEEDS]
    return pd.DataFrame({"min": t.min(axis=1), "max": t.max(axis=1), "seeds": n[n >= MIN_SEEDS],
                         "lower": t.min(axis=1) - widen, "upper": t.max(axis=1) + widen})


def window_model(values: np.ndarray, rng: np.random.Generator, size, bounded: bool = True) -> np.ndarray:
    """Draws of a seed's window mean from the distribution fitted by moments to the published per-seed window means
    ``values``: a Beta for a success rate (values clipped to [0.005, 0.995], as the final-window model does), a Normal
    for a return (``bounded`` False)."""
    if not bounded:
        return rng.normal(values.mean(), values.std(ddof=1) if len(values) > 1 else 0.0, size=size)
    m = np.clip(values, 0.005, 0.995)
    mu, var = m.mean(), max(m.var(ddof=1), 1e-4)
    k = max(mu * (1 - mu) / var - 1, 1e-3)
    return rng.beta(mu * k, (1 - mu) * k, size=size)


def _quantiles(values: np.ndarray, u: np.ndarray, rng: np.random.Generator, bounded: bool) -> np.ndarray:
    """Quantiles ``u`` of :func:`window_model` fitted to ``values``."""
    sample = np.sort(window_model(values, rng, 4096, bounded))
    pos = u * (len(sample) - 1)  # np.quantile's linear rule, indexed directly
    i = np.minimum(pos.astype(np.int64), len(sample) - 2)
    return sample[i] + (pos - i) * (sample[i + 1] - sample[i])


def faithful_windows(published: pd.DataFrame, steps: int, n: int, draws: int = DRAWS, seed: int = 0,
                     bounded: bool = True) -> np.ndarray:
    """Simulated seed-means of a faithful method with ``n`` seeds: (draws, checked windows)."""
    rng = np.random.default_rng(seed)
    t = window_table(published, steps)
    t = t[t.notna().sum(axis=1) >= MIN_SEEDS]
    seeds = list(t.columns)
    pick = rng.integers(0, len(seeds), size=(draws, n))  # which published seed each simulated seed follows
    out = np.empty((draws, len(t)))
    for k, (_, row) in enumerate(t.iterrows()):
        vals = row.to_numpy(dtype=np.float64)
        have = ~np.isnan(vals)
        m = int(have.sum())
        # each seed's rank bin in this window, ties broken at random; a seed without this window: anywhere
        order = np.full(len(seeds), -1)
        order[have] = np.lexsort((rng.random(m), vals[have])).argsort()
        r = order[pick]
        u = np.where(r >= 0, (r + rng.random(r.shape)) / m, rng.random(r.shape))
        out[:, k] = _quantiles(vals[have], u, rng, bounded).mean(axis=1)
    return out


_MEMO: dict[str, object] = {}


def _memo(name: str, published: pd.DataFrame, *args):
    """A pure function of the published curves, memoised per process (the dashboard recomputes verdicts often) and
    on disk (``<state>/curve_checks.json``, :func:`harness.data.state_dir`), keyed by the published values, the
    arguments and this module's source: a report or a dashboard started anew answers at once."""
    key = repr((name, int(pd.util.hash_pandas_object(published[["seed", "step", "value"]], index=False).sum()),
                *args, _SOURCE))
    if key not in _MEMO:
        stored = _disk().get(key)
        if stored is None:
            stored = globals()[f"_{name}"](published, *args)
            _store(key, stored)
        _MEMO[key] = tuple(stored) if isinstance(stored, list) else stored
    return _MEMO[key]


def _source_hash() -> str:
    import hashlib

    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


_SOURCE = _source_hash()


def _disk_file() -> Path:
    from harness.data import state_dir

    return state_dir() / "curve_checks.json"


def _disk() -> dict:
    try:
        d = json.loads(_disk_file().read_text())
        return d if isinstance(d, dict) else {}
    except (OSError, ValueError):
        return {}


def _store(key: str, value) -> None:
    """Add one entry (entries of other code versions are dropped); a read-only state directory: kept in memory only."""
    from harness.data import atomic_write_bytes

    entries = {k: v for k, v in _disk().items() if _SOURCE in k}
    entries[key] = value
    try:
        atomic_write_bytes(_disk_file(), json.dumps(entries).encode())
    except OSError:
        pass


def allowance(published: pd.DataFrame, steps: int, n: int, rule: CurveRule = CurveRule()) -> tuple[int, float]:
    """(A, P(more than A windows out) for a faithful method with ``n`` seeds)."""
    return _memo("allowance", published, steps, n, rule)


def _allowance(published: pd.DataFrame, steps: int, n: int, rule: CurveRule) -> tuple[int, float]:
    bands = published_bands(published, steps, rule.widen)
    if bands.empty:
        return 0, 0.0
    sim = faithful_windows(published, steps, n, bounded=rule.bounded)
    out = ((sim < bands["lower"].to_numpy()) | (sim > bands["upper"].to_numpy())).sum(axis=1)
    a = 0
    while (p := float((out > a).mean())) > rule.alpha:  # ends: no draw has more than len(bands) windows out
        a += 1
    return a, p


def first_success(curves: pd.DataFrame, steps: int, eval_every: int = 10_000) -> pd.Series:
    """Per seed, the first evaluated step with value >= 0.5 within ``steps`` (``steps + eval_every`` if none). A seed
    with a gap in its evaluations before that step (or, without a success, before the last step it reached) is left
    out: a gap is not "no success yet" (one published MEDAL peg seed has no evaluations from 470k to 7.86M)."""
    c = curves[(curves["step"] > 0) & (curves["step"] <= steps)]
    out = {}
    for seed, g in c.groupby("seed"):
        s = np.sort(g["step"].to_numpy())
        hit = g.loc[g["value"] >= FS_THRESHOLD, "step"]
        upto = int(hit.min()) if len(hit) else int(s[-1])
        if np.count_nonzero(s <= upto) < upto // eval_every:
            continue  # evaluations missing before the first success (or the last step): unknown
        out[seed] = upto if len(hit) else steps + eval_every
    return pd.Series(out, dtype="int64").sort_index()


def first_success_band(published: pd.DataFrame, steps: int, rule: CurveRule = CurveRule(), n: int = 2) -> dict:
    """See :func:`_first_success_band` (memoised)."""
    return _memo("first_success_band", published, steps, rule, n)


def _first_success_band(published: pd.DataFrame, steps: int, rule: CurveRule, n: int) -> dict:
    """The published per-seed first-success steps (censored at the budget), the accepted band for the mean of ``n``
    seeds (the published range widened by the smallest multiple of ``eval_every``, at least ``fs_widen``, that a
    faithful method leaves with probability at most ``alpha``) and that probability."""
    f = first_success(published, steps, rule.eval_every).to_numpy(dtype=np.float64)
    censor = steps + rule.eval_every
    rng = np.random.default_rng(0)
    h = 1.06 * (f.std(ddof=1) if len(f) > 1 else 0.0) * len(f) ** -0.2  # Silverman's bandwidth
    x = f[rng.integers(0, len(f), size=(DRAWS, n))]
    x = np.where(x >= censor, censor, np.clip(x + rng.normal(0, h, size=x.shape), rule.eval_every, censor))
    m = x.mean(axis=1)
    widen = rule.fs_widen
    while True:
        lower, upper = f.min() - widen, f.max() + widen
        p = float(((m < lower) | (m > upper)).mean())
        if p <= rule.alpha:
            break
        widen += rule.eval_every
    return {"published": [int(v) for v in f], "widen": int(widen), "lower": float(lower), "upper": float(upper),
            "p_false_fail": p}


def whole_curve_verdict(ours: pd.DataFrame, published: pd.DataFrame, steps: int, seeds: tuple[int, ...],
                        rule: CurveRule = CurveRule()) -> dict:
    """Both whole-curve checks of one cell from our curves (seed, step, value) and the published ones.

    ``status`` is pass / fail / running (running until every seed has evaluated its whole budget); ``out`` lists the
    windows (lo) whose seed-mean is outside the band so far, with the side; ``first_success`` is ours per seed."""
    if published.empty:
        raise ValueError("no published curves to compare with (check the cell's published source and method)")
    bands = published_bands(published, steps, rule.widen)
    a, p = allowance(published, steps, len(seeds), rule)
    ours = ours[ours["seed"].isin(seeds)]
    t = window_table(ours, steps, rule.eval_every).reindex(columns=list(seeds))
    mean = t.mean(axis=1, skipna=False).reindex(bands.index)  # a window counts once every seed has it
    low, high = mean < bands["lower"], mean > bands["upper"]
    out = [(int(lo), "low" if low[lo] else "high") for lo in bands.index if low[lo] or high[lo]]
    reached = min((int(ours.loc[ours["seed"] == s, "step"].max()) if (ours["seed"] == s).any() else 0) for s in seeds)
    furthest = max((int(ours.loc[ours["seed"] == s, "step"].max()) if (ours["seed"] == s).any() else 0) for s in seeds)
    done = reached >= steps and not mean.isna().any()  # a window with a missing evaluation is not "in band"
    status = "running" if not done else ("pass" if len(out) <= a else "fail")
    if not done and len(out) > a:
        status = "fail"  # more windows out than allowed already: nothing to come can mend it
    verdict = {"status": status, "windows": len(bands), "allowance": a, "p_false_fail": p, "out": out,
               "reached": reached, "furthest": furthest}
    if not rule.bounded:  # a return: no success threshold, so no first-success check
        return {**verdict, "first_success_status": "n/a", "first_success": [], "first_success_published": []}
    fsb = first_success_band(published, steps, rule, len(seeds))
    censor = steps + rule.eval_every
    fs = first_success(ours, steps, rule.eval_every).reindex(list(seeds)).fillna(censor)
    at = {s: (int(ours.loc[ours["seed"] == s, "step"].max()) if (ours["seed"] == s).any() else 0) for s in seeds}
    # a seed that has not succeeded yet and is still running will at the earliest at its next evaluation, at the
    # latest never (censor): the seed-mean's bounds, as the final-window check's running verdict
    least = np.mean([min(at[s] + rule.eval_every, censor) if fs[s] >= censor else fs[s] for s in seeds])
    most = float(fs.mean())
    lo_fs, hi_fs = fsb["lower"], fsb["upper"]
    if least == most or lo_fs <= least <= most <= hi_fs:
        fs_status = "pass" if lo_fs <= most <= hi_fs else "fail"
    elif most < lo_fs or least > hi_fs:
        fs_status = "fail"
    else:
        fs_status = "running"
    fs_mean = most if least == most else float("nan")
    return {**verdict, "first_success": [None if v >= censor else int(v) for v in fs],
            "first_success_mean": fs_mean, "first_success_least": float(least), "first_success_band": (fsb["lower"], fsb["upper"]),
            "first_success_published": fsb["published"], "first_success_p_false_fail": fsb["p_false_fail"],
            "first_success_status": fs_status, "still_running": [at[s] < steps for s in seeds]}


def whole_curve_text(v: dict) -> str:
    """``pass (1 of 10 windows out, 2 allowed)``, ``fail (too strong at 100k-300k)``..."""
    lows = [lo for lo, side in v["out"] if side == "low"]
    highs = [lo for lo, side in v["out"] if side == "high"]

    def spans(los):
        return ", ".join(f"{lo // 1000}k-{(lo + WINDOW) // 1000}k" for lo in los)

    where = "; ".join(x for x in (f"too strong at {spans(highs)}" if highs else "",
                                  f"too weak at {spans(lows)}" if lows else "") if x)
    counted = f"{len(v['out'])} of {v['windows']} windows out, {v['allowance']} allowed"
    if v["status"] == "running" and not v["furthest"]:
        return "not started"
    span = f"{v['reached']:,}" if v["reached"] == v["furthest"] else f"{v['reached']:,}-{v['furthest']:,}"
    head = v["status"] if v["status"] != "running" else f"running (at {span})"
    return f"{head}: {counted}" + (f"; {where}" if where else "")


def first_success_text(v: dict) -> str:
    if v["first_success_status"] == "n/a":
        return "n/a: the metric is a return (no success threshold)"
    lo, hi = v["first_success_band"]
    if v["first_success_status"] == "running" and not v["furthest"]:
        return f"not started; accepted mean {max(lo, 0) / 1000:.0f}k-{hi / 1000:.0f}k"
    running = v.get("still_running") or [v["first_success_status"] == "running"] * len(v["first_success"])
    # a seed without a success says "none yet" while it runs (a verdict may be decided before: nothing to come can
    # turn it), "never" once it finished its budget
    ours = ", ".join(("none yet" if r else "never") if s is None else f"{s // 1000}k"
                     for s, r in zip(v["first_success"], running))
    pub = ", ".join(f"{s // 1000}k" for s in sorted(v["first_success_published"]))
    side = ""
    if v["first_success_status"] == "fail":
        side = " (too early)" if v["first_success_least"] < lo else " (too late)"
    return (f"{v['first_success_status']}{side}: ours {ours}; accepted mean {max(lo, 0) / 1000:.0f}k-{hi / 1000:.0f}k "
            f"(published {pub})")
