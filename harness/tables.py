"""Table 1 of the MEDAL paper beside ours: the published numbers (:data:`PUBLISHED_TABLE1`), the long numeric
table (:func:`table1`) and its renderings (display table, Markdown, LaTeX, CSV)."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import pandas as pd

from harness.analysis import OURS, base_algo, final_performance, select, with_runs
from harness.envs import ENVS
from harness.labels import algo_label, env_label, order_algos, order_envs

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
    have = {base_algo(a) for a in ours["algo"]}
    algos = order_algos(list(ours["algo"]) + [a for a, e in published if e in envs and a not in have])
    rows = []
    for env in envs:
        for algo in algos:
            o = ours[(ours["env"] == env) & (ours["algo"] == algo)]
            p = published.get((base_algo(algo), env))  # a method split by suite is compared with the paper's too
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


#: the Table-1 budgets of suites/earl_sparse.yaml (docs/algorithms.md 1.2; the MEDAL paper does not state its own)
TABLE1_BUDGET = {name: e.default_steps for name, e in ENVS.items() if e.in_table1}  # the paper's 3M / 5M / 8M
EARLY = "†"  # marks a number taken at less than half of TABLE1_BUDGET


def short_steps(n: float) -> str:
    """1.5M, 540k, 400: a step count as tables write it."""
    return f"{n / 1e6:g}M" if n >= 1e6 else f"{n / 1e3:g}k" if n >= 1e3 else f"{n:g}"


def _fmt_ms(m: float, se: float, digits: int, n: int = 2) -> str:
    if m is None or (isinstance(m, float) and math.isnan(m)):
        return "–"
    return f"{m:.{digits}f} ({se:.{digits}f})" if n > 1 else f"{m:.{digits}f} (1 seed)"


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
        mixed = e["step"].dropna().nunique() > 1  # rows at different steps: each says its own
        lab = env_label(env)
        ours, paper, diff = [], [], []
        for a in algos:
            if a not in e.index:
                ours.append("–"), paper.append("–"), diff.append("–")
                continue
            r = e.loc[a]
            s = _fmt_ms(r["ours_mean"], r["ours_se"], digits, int(r["n"]))
            if s != "–":
                s = bold(s) if r["ours_best"] else s
                early = r["step"] < 0.5 * TABLE1_BUDGET.get(env, 0)
                s += f" @{short_steps(r['step'])}" if mixed or early else ""  # an early number always says its step
                s += EARLY if early else ""
            ours.append(s)
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
    return "\n".join(lines) + "\n" + (f"\n{EARLY_NOTE}\n" if any(EARLY in str(v) for v in w.to_numpy().ravel()) else "")


EARLY_NOTE = (f"{EARLY} taken before half of the Table-1 budget ("
              + ", ".join(f"{short_steps(n)} {env_label(e).lower()}" for e, n in TABLE1_BUDGET.items())
              + " steps), at the step after @: not a final number.")


def _tex(s: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"),
                 ("Δ", r"$\Delta$"), ("±", r"$\pm$"), ("–", "--"), (EARLY, r"$^\dagger$")):
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
