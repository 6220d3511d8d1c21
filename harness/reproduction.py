"""The reproduction check: do our runs learn as published? (docs/reproduction.md)

A suite with ``cells`` (``suites/reproduction.yaml``) lists, per cell, a method, an env, a budget, seeds and
``checks``: a window of evaluations ``(lo, hi]`` and the published per-seed window means of that method (mean, min,
max over the published seeds). The suite's ``criterion: {widen: w}`` is one rule for every check:

    pass  when  min - w  <=  mean over our seeds of (each seed's mean deployed success in the window)  <=  max + w

A check is ``running`` until every seed of the cell has all its evaluations in the window. The metric is the one the
env's published curves measure (:func:`metric_of`): deployed success on the Sawyer tasks and tabletop, the deployed
return on kitchen and minitaur, where a cell gives its own ``widen`` in return units. Everything here is pure
(DataFrames in, DataFrames out); :func:`load_ladder` reads the suite file.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from algorithms.api import parse_int
from harness import curve_checks as C
from harness.curve_checks import CurveRule
from harness.envs import ENVS
from harness.results import RETURN_ENVS
from harness.suites import ConfigError, load_suite

METRIC = "deployed_success"


def metric_of(env: str) -> str:
    """What ``env``'s published curves measure (``EnvInfo.published_metric``): ``deployed_success``, or
    ``deployed_return`` (kitchen, minitaur)."""
    info = ENVS.get(env)
    if info is None:  # dhand_lightbulb: EARL published its returns but never released it
        return "deployed_return" if env in RETURN_ENVS else METRIC
    return info.published_metric


@dataclass(frozen=True)
class Check:
    lo: int
    hi: int
    source: str
    algo: str  # the published method compared with
    mean: float
    min: float
    max: float
    calibration: bool = False  # the window a configuration was chosen on: a calibration, not independent evidence


@dataclass(frozen=True)
class Cell:
    name: str  # the method's name in our results (a variant's name, else the algorithm)
    algo: str  # registry key
    env: str
    steps: int
    seeds: tuple[int, ...]
    checks: tuple[Check, ...]
    config: tuple[tuple[str, object], ...] = ()  # a variant's config overrides, (key, value) pairs
    widen: float | None = None  # the band's widening in the metric's units; None: the suite's criterion widen

    @property
    def metric(self) -> str:
        return metric_of(self.env)

    @property
    def bounded(self) -> bool:
        """The metric is a success rate in [0, 1] (else a return, unbounded)."""
        return self.metric == METRIC


@dataclass(frozen=True)
class Ladder:
    suite: str
    cells: tuple[Cell, ...]
    widen: float
    rule: CurveRule = field(default_factory=CurveRule)  # the whole-curve checks' rule (harness.curve_checks)

    def widen_of(self, cell: Cell) -> float:
        return self.widen if cell.widen is None else cell.widen

    def rule_of(self, cell: Cell) -> CurveRule:
        """The whole-curve rule of one cell: the suite's, in the cell's metric (its widen; Normal model for returns)."""
        return replace(self.rule, widen=self.widen_of(cell), bounded=cell.bounded)


def _seed_list(v) -> tuple[int, ...]:
    if isinstance(v, (list, tuple)):
        return tuple(int(x) for x in v)
    return tuple(range(int(v)))


def load_ladder(suite: str) -> Ladder:
    """The cells and checks of a suite with ``cells`` (a name in ``suites/`` or a path)."""
    name, d = load_suite(suite)
    if "cells" not in d:
        raise ConfigError(f"suite {name!r} has no 'cells': it is not a reproduction suite")
    crit = d.get("criterion") or {}
    if not isinstance(crit, dict) or set(crit) - {"widen", "curve_alpha", "first_success_widen"}:
        raise ConfigError(f"suite {name!r}: criterion must be {{widen: <number>}}, optionally with curve_alpha: "
                          "<probability> and first_success_widen: <steps>")
    try:
        widen = float(crit.get("widen", 0.1))
        rule = CurveRule(widen, float(crit.get("curve_alpha", CurveRule.alpha)),
                         parse_int("first_success_widen", crit.get("first_success_widen", CurveRule.fs_widen)),
                         parse_int("eval_every", d.get("eval_every", 10_000)))
    except (TypeError, ValueError) as e:
        raise ConfigError(f"suite {name!r}: criterion: {e}") from None
    if not (0 <= widen <= 1 and 0 < rule.alpha < 1 and rule.fs_widen >= 0):
        raise ConfigError(f"suite {name!r}: criterion needs 0 <= widen <= 1, 0 < curve_alpha < 1, "
                          "first_success_widen >= 0")
    cells = []
    for n, c in enumerate(d["cells"]):
        checks = []
        for k in c.get("checks") or []:
            try:
                lo, hi = (int(x) for x in k["window"])
                p = k["published"]
                checks.append(Check(lo, hi, str(p["source"]), str(p.get("algo", c["algo"])), float(p["mean"]),
                                    float(p["min"]), float(p["max"]), bool(k.get("calibration", False))))
            except (KeyError, TypeError, ValueError) as e:
                raise ConfigError(f"suite {name!r}, cell {n + 1}: a check needs window: [lo, hi] and published: "
                                  f"{{source, mean, min, max}} ({type(e).__name__}: {e})") from None
            if not 0 <= lo < hi <= int(c["steps"]):
                raise ConfigError(f"suite {name!r}, cell {n + 1}: window {lo}-{hi} is not inside the budget {c['steps']}")
        metric = metric_of(str(c["env"]))
        cell_widen = c.get("widen")
        if cell_widen is None and metric != METRIC:
            raise ConfigError(f"suite {name!r}, cell {n + 1}: env {c['env']}'s published curves are {metric}: give the "
                              "cell its own widen, in return units")
        if cell_widen is not None:
            try:
                cell_widen = float(cell_widen)
            except (TypeError, ValueError):
                raise ConfigError(f"suite {name!r}, cell {n + 1}: widen must be a number, got {cell_widen!r}") from None
            if not (0 <= cell_widen <= (1 if metric == METRIC else float("inf"))):
                raise ConfigError(f"suite {name!r}, cell {n + 1}: widen {cell_widen:g} is out of range for {metric} "
                                  f"({'0 to 1' if metric == METRIC else 'at least 0'})")
        cells.append(Cell(str(c.get("name") or c["algo"]), str(c["algo"]), str(c["env"]), int(c["steps"]),
                          _seed_list(c.get("seeds", d.get("seeds", 1))), tuple(checks),
                          tuple(sorted((c.get("config") or {}).items())), cell_widen))
    return Ladder(name, tuple(cells), widen, rule)


def window_means(curves: pd.DataFrame, lo: int, hi: int) -> pd.Series:
    """Mean of ``value`` over evaluations lo < step <= hi, per seed (seeds with no evaluation there are absent)."""
    w = curves[(curves["step"] > lo) & (curves["step"] <= hi)]
    return w.groupby("seed")["value"].mean()


def published_curves(published: pd.DataFrame, check: Check, env: str) -> pd.DataFrame:
    """The published per-seed curves a check compares with (in ``env``'s metric): seed, step, value."""
    p = published[(published["source"] == check.source) & (published["env"] == env)
                  & (published["algo"] == check.algo) & (published["metric"] == metric_of(env))]
    return p[["seed", "step", "value"]]


def cell_rows(ours: pd.DataFrame, suite: str, cell: Cell) -> pd.DataFrame:
    """Every result row of a cell's seeds."""
    return ours[(ours["suite"] == suite) & (ours["env"] == cell.env) & (ours["algo"] == cell.name)
                & ours["seed"].isin(cell.seeds)]


def our_curves(ours: pd.DataFrame, suite: str, cell: Cell) -> pd.DataFrame:
    """Our per-seed curves of a cell in its metric: seed, step, value (the cell's seeds only)."""
    o = cell_rows(ours, suite, cell)
    return o.loc[o["metric"] == cell.metric, ["seed", "step", "value"]]


def verdict(curves: pd.DataFrame, cell: Cell, check: Check, widen: float, eval_every: int = 10_000) -> dict:
    """The check's outcome from our curves (seed, step, value): ``status`` pass / fail / running, our seed-mean and
    per-seed window means, the accepted band, and how far the slowest seed got."""
    need = set(range(check.lo + eval_every, check.hi + 1, eval_every))
    by_seed = [int(curves.loc[curves["seed"] == s, "step"].max()) if (curves["seed"] == s).any() else 0
               for s in cell.seeds]
    reached = min(by_seed)
    per_seed = window_means(curves, check.lo, check.hi)
    complete = all(need <= set(curves.loc[curves["seed"] == s, "step"].astype(int)) for s in cell.seeds)
    lower, upper = check.min - widen, check.max + widen
    mean = float(per_seed.reindex(list(cell.seeds)).mean()) if len(per_seed) else float("nan")
    # The seed-mean's bounds if every window evaluation still to come scores 0, or every one 1 (success is in [0, 1]):
    # a running check whose bounds both lie on one side of the band's edges is already decided. A return has no
    # bounds: its check is decided when its window is complete.
    least, most = (0.0, 0.0) if cell.bounded else (-np.inf, np.inf)
    for s in cell.seeds if cell.bounded else ():
        w = curves[(curves["seed"] == s) & (curves["step"] > check.lo) & (curves["step"] <= check.hi)]
        missing = len(need - set(w["step"].astype(int)))
        least += w["value"].sum() / (len(w) + missing) / len(cell.seeds)
        most += (w["value"].sum() + missing) / (len(w) + missing) / len(cell.seeds)
    if not complete:
        status = "running"
    else:
        status = "pass" if lower <= mean <= upper else "fail"
    decided = ("pass" if lower <= least and most <= upper
               else "fail" if most < lower or least > upper else None)
    return {"status": status, "ours": mean, "ours_per_seed": [float(per_seed.get(s, np.nan)) for s in cell.seeds],
            "lower": lower, "upper": upper, "reached": reached, "furthest": max(by_seed),
            "started": sum(r > 0 for r in by_seed), "seeds": len(by_seed), "bounds": (float(least), float(most)),
            "decided": decided if status == "running" else None}


def verdict_text(v: dict, check: Check, steps: int, short: bool = False) -> str:
    """The verdict in words; ``short``: brief enough for a panel title ("at 90,000 of 300,000 steps"). A running
    check that the evaluations still to come cannot turn says so ("...; pass whatever the rest scores")."""
    if v["status"] == "running" and v.get("decided"):
        d = v["decided"] + ("" if v["decided"] == "pass" else
                            " (too weak)" if v["bounds"][1] < v["lower"] else " (too strong)")
        running = verdict_text({**v, "decided": None}, check, steps, short)
        return f"{running}, {d} already" if short else f"{running}; {d} whatever the rest scores"
    if v["status"] == "running":
        if v["reached"] and v["reached"] < v["furthest"]:
            if short:
                return f"{v['seeds']} seeds at {v['reached']:,}-{v['furthest']:,} of {steps:,} steps"
            return (f"running: {v['seeds']} seeds, the slowest at {v['reached']:,}, the furthest at "
                    f"{v['furthest']:,} of {steps:,} steps")
        if v["reached"]:
            return f"{'at' if short else 'running: reached'} {v['reached']:,} of {steps:,} steps"
        if v.get("started"):
            seeds = f"{v['started']} of {v['seeds']} seeds"
            if short:
                return f"{seeds} at {v['furthest']:,} of {steps:,} steps"
            return f"running: {seeds} started, the furthest at {v['furthest']:,} of {steps:,} steps"
        return "not started"
    side = "" if v["status"] == "pass" else (" (too weak)" if v["ours"] < v["lower"] else " (too strong)")
    return f"{v['status']}{side}" + (" (calibration: not independent evidence)" if check.calibration and not short
                                     else " (calibration)" if check.calibration else "")


def cell_published(published: pd.DataFrame, cell: Cell) -> pd.DataFrame:
    """The published per-seed curves a cell's whole-curve checks compare with (its checks' source and method)."""
    source, algo = (cell.checks[0].source, cell.checks[0].algo) if cell.checks else ("risc_paper", cell.algo)
    return published_curves(published, Check(0, 0, source, algo, 0, 0, 0), cell.env)


def ladder_table(ladder: Ladder, ours: pd.DataFrame, eval_every: int = 10_000,
                 published: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per (cell, check): method, env, window, published mean (min-max), ours (per seed), verdict; with the
    published curves also the cell's whole-curve verdicts (``curve``, ``first_success``: texts; ``curve_status``,
    ``first_success_status``), repeated on each row of the cell."""
    rows = []
    for cell in ladder.cells:
        curves = our_curves(ours, ladder.suite, cell)
        whole = {}
        if published is not None:
            try:
                w = C.whole_curve_verdict(curves, cell_published(published, cell), cell.steps, cell.seeds,
                                          ladder.rule_of(cell))
                whole = {"curve": C.whole_curve_text(w), "curve_status": w["status"],
                         "first_success": C.first_success_text(w), "first_success_status": w["first_success_status"]}
            except ValueError as e:  # no published curves for this cell: say so, no verdict
                whole = {"curve": f"none: {e}", "curve_status": "none", "first_success": "none",
                         "first_success_status": "none"}
        for check in cell.checks:
            v = verdict(curves, cell, check, ladder.widen_of(cell), eval_every)
            rows.append({
                "method": cell.name, "env": cell.env, "metric": cell.metric, "budget": cell.steps, "seeds": len(cell.seeds),
                "config": " ".join(f"{k}={_yaml_value(v)}" for k, v in cell.config),
                "window": f"{check.lo // 1000}k-{check.hi // 1000}k", "lo": check.lo, "hi": check.hi,
                "published": check.mean, "published_min": check.min, "published_max": check.max,
                "ours": v["ours"], "ours_per_seed": v["ours_per_seed"], "band": (v["lower"], v["upper"]),
                "reached": v["reached"], "furthest": v["furthest"], "status": v["status"],
                "verdict": verdict_text(v, check, cell.steps),
                "calibration": check.calibration, **whole,
            })
    return pd.DataFrame(rows)


def _yaml_value(v) -> str:
    return str(v).lower() if isinstance(v, bool) else str(v)


def range_text(lo: float, hi: float, metric: str = METRIC) -> str:
    """``0.14-0.69`` for a success rate, ``-2248 to 136`` for a return."""
    return f"{value_text(lo, metric)}{'-' if metric == METRIC else ' to '}{value_text(hi, metric)}"


def value_text(x: float, metric: str = METRIC) -> str:
    """A window mean as the tables show it: a success rate with 2 decimals, a return rounded to a whole number."""
    if np.isnan(x):
        return "-"
    return f"{x:.2f}" if metric == METRIC else f"{x:.0f}"


def table_markdown(t: pd.DataFrame) -> str:
    """The ladder as a Markdown table (ours per seed, published mean and per-seed range, verdict); a ``config``
    column when some cell is a variant; the whole-curve verdicts, once per cell, when ``t`` has them."""
    variants = bool(t["config"].str.len().any()) if len(t) else False
    whole = "curve" in t
    head = "| method | " + ("config | " if variants else "") + "env | budget | window | published mean (per-seed range) " \
           "| ours: mean (per seed) | verdict |" + (" whole curve | first success |" if whole else "")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    seen = set()
    for r in t.itertuples():
        metric = getattr(r, "metric", METRIC)
        f = lambda x: value_text(x, metric)  # noqa: E731
        seeds = ", ".join(f(x) for x in r.ours_per_seed)
        ours = f(r.ours)
        config = f"{r.config or '-'} | " if variants else ""
        first = (r.method, r.env, r.config) not in seen
        seen.add((r.method, r.env, r.config))
        extra = (f" {r.curve} | {r.first_success} |" if first else " | |") if whole else ""
        span = range_text(r.published_min, r.published_max, metric)
        lines.append(f"| {r.method} | {config}{r.env} | {r.budget / 1e6:g}M | {r.window} | {f(r.published)} "
                     f"({span}) | {ours} ({seeds}) | {r.verdict} |{extra}")
    return "\n".join(lines) + "\n"


def replace_doc_table(text: str, suite: str, table: str) -> str:
    """``text`` with the block between ``<!-- table:SUITE -->`` and ``<!-- /table:SUITE -->`` replaced by ``table``."""
    start, end = f"<!-- table:{suite} -->", f"<!-- /table:{suite} -->"
    if start not in text or end not in text:
        raise ConfigError(f"the document has no '{start}' ... '{end}' block for the table of suite {suite!r}")
    a, b = text.index(start) + len(start), text.index(end)
    return text[:a] + "\n" + table + text[b:]


def seed_mean(curves: pd.DataFrame) -> pd.Series:
    """Mean over seeds per step, up to the last step every seed reached, so the mean never changes which seeds it
    averages part-way (seeds that have gone further show as their own lines)."""
    if curves.empty:
        return pd.Series(dtype=float)
    common = curves.groupby("seed")["step"].max().min()
    return curves[curves["step"] <= common].groupby("step")["value"].mean()


def pass_probability(per_seed: np.ndarray, lower: float, upper: float, n: int, draws: int = 100_000,
                     seed: int = 0, bounded: bool = True) -> float:
    """P(a check passes) for n seeds of a FAITHFUL method: seed window means drawn from a Beta distribution (a Normal
    for a return: ``bounded`` False) fitted by moments to the published per-seed window means ``per_seed``, so seeds
    may fall outside the published range."""
    m = np.asarray(per_seed, dtype=np.float64)
    x = C.window_model(m, np.random.default_rng(seed), (draws, n), bounded).mean(axis=1)
    return float(((lower <= x) & (x <= upper)).mean())


def operating_characteristics(ladder: Ladder, published: pd.DataFrame, seeds=(2, 3, 5)) -> pd.DataFrame:
    """Per check: the accepted band and P(pass) of a faithful method with each number of seeds (docs/reproduction.md)."""
    rows = []
    for cell in ladder.cells:
        for check in cell.checks:
            per_seed = window_means(published_curves(published, check, cell.env), check.lo, check.hi).to_numpy()
            lower, upper = check.min - ladder.widen_of(cell), check.max + ladder.widen_of(cell)
            rows.append({"method": cell.name, "env": cell.env, "window": f"{check.lo // 1000}k-{check.hi // 1000}k",
                         "lower": lower, "upper": upper,
                         **{f"p_pass_{n}_seeds": pass_probability(per_seed, lower, upper, n, bounded=cell.bounded)
                            for n in seeds}})
    return pd.DataFrame(rows)
