"""Which cells of Table 1 the results verify: each (method, env) of the MEDAL paper's Table 1 beside the reproduction
cell that checks it (suites/reproduction.yaml, suites/table1.yaml), with the cell's budget, seeds and its three
verdicts (final window, whole curve, first success; docs/reproduction.md). Shown under Table 1 by the dashboard and
written by ``harness report`` (``table1_evidence.md``)."""

from __future__ import annotations

import pandas as pd

from harness.labels import algo_label, env_label, order_algos, order_envs
from harness.reproduction import ladder_table, load_ladder
from harness.tables import PUBLISHED_TABLE1

#: the suites whose cells check Table 1, in the order their cells are taken (first cell of a (method, env) wins)
TABLE1_SUITES = ("reproduction", "table1")


def _summary(rows: pd.DataFrame) -> str:
    """``verified``, ``fails``, ``running`` or ``no results`` from a cell's rows (calibration windows left out)."""
    checks = rows[~rows["calibration"]]
    if (rows["furthest"] == 0).all():
        return "no results"
    statuses = list(checks["status"]) + [rows["curve_status"].iloc[0], rows["first_success_status"].iloc[0]] \
        if "curve_status" in rows else list(checks["status"])
    if "fail" in statuses:
        return "fails"
    if "running" in statuses:
        return "running"
    curves = "curve_status" in rows and rows["curve_status"].iloc[0] != "none"
    return "verified" if curves else "verified (final window only: no published curves)"


def table1_cells() -> dict[tuple[str, str], str]:
    """(method, env) of each Table-1 cell -> the suite whose cell checks it (:data:`TABLE1_SUITES`, first wins)."""
    cells: dict[tuple[str, str], str] = {}
    for suite in TABLE1_SUITES:
        for cell in load_ladder(suite).cells:
            if (cell.name, cell.env) in PUBLISHED_TABLE1:
                cells.setdefault((cell.name, cell.env), suite)
    return cells


def table1_cell_rows(df: pd.DataFrame, cells: dict[tuple[str, str], str] | None = None) -> pd.DataFrame:
    """The rows of ``df`` (ours) that belong to a Table-1 cell: method ``m`` on env ``e`` from the suite of cell
    ``(m, e)`` only, so no cell pools runs of two suites."""
    cells = table1_cells() if cells is None else cells
    if df.empty:
        return df
    want = pd.MultiIndex.from_tuples([(s, e, a) for (a, e), s in cells.items()], names=["suite", "env", "algo"])
    have = pd.MultiIndex.from_frame(df[["suite", "env", "algo"]].astype(str))
    return df[have.isin(want)]


def table1_evidence(df: pd.DataFrame, published: pd.DataFrame | None,
                    train: set[tuple[str, str, str, int]] | None = None) -> pd.DataFrame:
    """One row per Table-1 cell: algo, env, suite, budget, seeds, reached (slowest seed), ``evidence`` (verified /
    fails / running / no results / no cell), the final-window verdicts (``windows``), ``curve`` and
    ``first_success`` (texts; absent without the published curves), and with ``train`` (the runs that hold training
    diagnostics, :func:`harness.results.runs_holding`) ``train_tables``: how many of the cell's seeds have them."""
    cells: dict[tuple[str, str], dict] = {}
    for suite in TABLE1_SUITES:
        ladder = load_ladder(suite)
        t = ladder_table(ladder, df, published=published)
        for cell in ladder.cells:
            key = (cell.name, cell.env)
            if key not in PUBLISHED_TABLE1 or key in cells:
                continue
            rows = t[(t["method"] == cell.name) & (t["env"] == cell.env) & (t["config"] == "")]
            cells[key] = {
                "suite": suite, "budget": cell.steps, "seeds": len(cell.seeds), "reached": int(rows["reached"].min()),
                "evidence": _summary(rows),
                "checks": list(zip(rows["window"], rows["verdict"])),  # (window, verdict) of each final window
                "windows": "; ".join(f"{w}: {v}" for w, v in zip(rows["window"], rows["verdict"])),
                "curve": rows["curve"].iloc[0] if "curve" in rows else "",
                "first_success": rows["first_success"].iloc[0] if "first_success" in rows else "",
                "train_tables": None if train is None else sum((suite, cell.env, cell.name, s) in train
                                                               for s in cell.seeds),
            }
    out = []
    for (algo, env) in PUBLISHED_TABLE1:
        c = cells.get((algo, env), {"suite": "", "budget": 0, "seeds": 0, "reached": 0, "evidence": "no cell",
                                    "checks": [], "windows": "", "curve": "", "first_success": "",
                                    "train_tables": None})
        out.append({"algo": algo, "env": env, **c})
    return pd.DataFrame(out)


def _short(text: str) -> str:
    """A verdict's first words: ``pass``, ``fail (too weak)``, ``running (at 90,000)``."""
    return text.replace(" (calibration: not independent evidence)", " (calibration)").split(":")[0]


def evidence_markdown(e: pd.DataFrame) -> str:
    """A Method x env Markdown grid (per cell the evidence, the budget, seeds and the three verdicts in short), then
    the verdicts in full, one line per cell with results."""
    envs, algos = order_envs(e["env"]), order_algos(e["algo"])
    lines = ["| Method | " + " | ".join(env_label(x) for x in envs) + " |", "|---|" + ":-:|" * len(envs)]
    details = []
    for a in algos:
        cells = []
        for env in envs:
            r = e[(e["algo"] == a) & (e["env"] == env)].iloc[0]
            if r["evidence"] in ("no cell", "no results"):
                cells.append(r["evidence"] + (f" ({r['suite']}, {r['budget'] / 1e6:g}M)" if r["suite"] else ""))
                continue
            at = "" if r["reached"] >= r["budget"] else f", at {r['reached'] / 1e6:g}M"
            finals = "; ".join(f"{w} {_short(v)}" for w, v in r["checks"])
            curve = f"<br>curve {_short(r['curve'])}<br>first success {_short(r['first_success'])}" if r["curve"] else ""
            train = "" if pd.isna(r.get("train_tables")) else f"{int(r['train_tables'])} of {r['seeds']} seeds"
            cells.append(f"**{r['evidence']}** ({r['seeds']} seeds, {r['budget'] / 1e6:g}M{at})<br>{finals}{curve}"
                         + (f"<br>training tables: {train}" if train else ""))
            details.append(f"- {algo_label(a)}, {env_label(env)} (suite {r['suite']}): final window {r['windows']}"
                           + (f"; whole curve {r['curve']}; first success {r['first_success']}" if r["curve"] else "")
                           + (f"; training diagnostics (train.parquet) shipped for {train}" if train else ""))
        lines.append(f"| {algo_label(a)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n" + ("\n" + "\n".join(details) + "\n" if details else "")
