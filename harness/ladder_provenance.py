"""What a ladder's runs cost and which code produced them, from their evaluation rows (docs/reproduction.md):
process-hours and steps/s per cell, and the git commits per seed with the steps each evaluated."""

from __future__ import annotations

import numpy as np
import pandas as pd

from harness.reproduction import Ladder, cell_rows


def ladder_cost(ladder: Ladder, ours: pd.DataFrame) -> pd.DataFrame:
    """What each cell's runs cost, from their evaluation rows: seeds started, env steps done (summed over seeds),
    process-hours (each seed's last ``wall_s``, divided by the seeds its process trained as members: on a CPU with one
    torch thread per process, core-hours) and the median steps/s per seed. Only the rows that exist count: a run redone
    from 0 after its checkpoint was lost counts once."""
    rows = []
    for cell in ladder.cells:
        o = cell_rows(ours, ladder.suite, cell)
        started, steps, hours, rates = 0, 0, 0.0, []
        for s in cell.seeds:
            r = o[o["seed"] == s]
            if r.empty:
                continue
            started, steps = started + 1, steps + int(r["step"].max())
            wall = r[r["metric"] == "wall_s"]
            if len(wall):
                last = wall.loc[wall["step"].idxmax()]
                members = last.get("members", 1)
                hours += float(last["value"]) / (int(members) if pd.notna(members) and members > 0 else 1) / 3600
            rate = r.loc[(r["metric"] == "steps_per_s") & (r["step"] > 0), "value"]
            rates += [v for v in rate if np.isfinite(v) and v > 0]
        rows.append({"method": cell.name, "env": cell.env, "seeds": len(cell.seeds), "started": started,
                     "steps": steps, "process_hours": hours,
                     "steps_per_s": float(np.median(rates)) if rates else float("nan")})
    return pd.DataFrame(rows)


def cost_markdown(c: pd.DataFrame) -> str:
    """:func:`ladder_cost` as a Markdown table with a total row."""
    lines = ["| method | env | seeds started | env steps | process-hours | steps/s per seed (median) |",
             "|---|---|---|---|---|---|"]
    for r in c.itertuples():
        rate = "-" if np.isnan(r.steps_per_s) else f"{r.steps_per_s:.0f}"
        lines.append(f"| {r.method} | {r.env} | {r.started} of {r.seeds} | {r.steps:,} | {r.process_hours:.1f} | {rate} |")
    lines.append(f"| total | | {int(c['started'].sum())} of {int(c['seeds'].sum())} | {int(c['steps'].sum()):,} | "
                 f"{c['process_hours'].sum():.1f} | |")
    return "\n".join(lines) + "\n"


def ladder_commits(ladder: Ladder, ours: pd.DataFrame) -> pd.DataFrame:
    """Which code produced each seed's rows: one row per started seed of each cell with ``commits``, a list of
    (git SHA, first step, last step), one per stretch of consecutive evaluations made by the same SHA, in step order.
    A run resumed across commits lists each commit with the evaluations it made (a commit it went back to, again);
    ``-dirty`` marks a tree with uncommitted changes."""
    rows = []
    for cell in ladder.cells:
        o = cell_rows(ours, ladder.suite, cell)
        for s in cell.seeds:
            r = o[o["seed"] == s]
            if r.empty:
                continue
            r = r.sort_values("step", kind="stable")
            shas = r["git_sha"].fillna("unknown")
            stretch = (shas != shas.shift()).cumsum()  # a new stretch wherever the SHA changes along the steps
            spans = r["step"].groupby(stretch).agg(["min", "max"]).assign(sha=shas.groupby(stretch).first())
            rows.append({"method": cell.name, "env": cell.env, "seed": s,
                         "commits": [(sha, int(lo), int(hi)) for lo, hi, sha in spans.itertuples(index=False)]})
    return pd.DataFrame(rows, columns=["method", "env", "seed", "commits"])


def _steps(n: int) -> str:
    return f"{n / 1000:g}k" if n else "0"


def commits_text(commits: list[tuple[str, int, int]], quote: str = "") -> str:
    """One seed's commits as ``abc1234 (0-220k), def5678 (230k-740k)``: short SHAs, each in ``quote``."""
    return ", ".join(f"{quote}{sha[:7]}{'-dirty' if sha.endswith('-dirty') else ''}{quote} "
                     f"({_steps(lo)}{'' if lo == hi else '-' + _steps(hi)})" for sha, lo, hi in commits)


def commits_markdown(c: pd.DataFrame) -> str:
    """:func:`ladder_commits` as a Markdown table, short SHAs with the steps each one evaluated."""
    lines = ["| method | env | seed | commits (steps evaluated) |", "|---|---|---|---|"]
    for r in c.itertuples():
        lines.append(f"| {r.method} | {r.env} | {r.seed} | {commits_text(r.commits, '`')} |")
    return "\n".join(lines) + "\n"
