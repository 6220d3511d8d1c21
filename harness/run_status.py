"""The state of every run under a results directory, read from the files the runs write (``harness.results``: the
run directory layout of :func:`~harness.results.run_dir` and its ``status.json``), for the dashboard's Runs tab."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pandas as pd

from harness.results import EVALS_FILE, RUN_FILE, STATUS_FILE, parse_run_dir, read_status

STATUS_COLUMNS = ["suite", "env", "algo", "seed", "tuning", "state", "step", "total", "progress", "steps_per_s", "eta_s",
                  "last_success", "error", "updated", "age_s", "dir"]


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def run_status(results: str | Path, now: float | None = None, stale_after: float = 900.0) -> pd.DataFrame:
    """One row per run directory under ``results`` (any folder with a ``status.json`` or an
    ``evals.parquet``). ``state`` is the status file's (running / done / failed / resumed; ``shipped``: a copy of an
    unfinished run, ``harness ship``), or
    ``unknown`` without one; a running or resumed run whose status was last updated more than
    ``max(stale_after, 3 x (eval interval from run.yaml) / steps_per_s)`` seconds ago is marked
    ``stale``. ``error`` is the first line of the recorded error; ``tuning`` marks the trial runs of
    ``harness tune`` (under ``<results>/tuning/``)."""
    root = Path(results)
    now = time.time() if now is None else now
    dirs = sorted({p.parent for name in (STATUS_FILE, EVALS_FILE) for p in root.rglob(name)})
    rows = []
    for d in dirs:
        r = parse_run_dir(d, root) or {"suite": None, "env": None, "algo": None, "seed": None}
        p = d / STATUS_FILE
        try:
            st: Any = read_status(d, strict=True) if p.exists() else {}
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
        rows.append({**r, "tuning": d.relative_to(root).parts[:1] == ("tuning",), "state": state, "step": step,
                     "total": total,
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
    order = ["running", "resumed", "stale", "shipped", "done", "failed", "unknown"]
    c = status["state"].value_counts()
    return {s: int(c[s]) for s in order + sorted(set(c.index) - set(order)) if s in c.index}


def format_duration(s: float) -> str:
    """``1h02m``, ``3m05s``, ``?`` for unknown/infinite."""
    if s is None or not math.isfinite(s):
        return "?"
    s = int(max(s, 0))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def status_text(df: pd.DataFrame) -> str:
    """The runs of :func:`run_status` as a fixed-width table (step of total, steps/s, ETA, last deployed success, the
    age of the status) and a count per state; failed runs add their error line."""
    if df.empty:
        return "no runs"
    def num(x: float, fmt: str) -> str:
        return "-" if math.isnan(x) else format(x, fmt)

    rows = [("suite", "env", "algo", "seed", "state", "step", "of", "%", "steps/s", "ETA", "success", "updated")]
    for r in df.itertuples():
        rows.append((str(r.suite or "-"), str(r.env or "-"), str(r.algo or "-"), "-" if pd.isna(r.seed) else str(r.seed),
                     r.state, num(r.step, ",.0f"), num(r.total, ",.0f"), num(100 * r.progress, ".0f"),
                     num(r.steps_per_s, ",.0f") if r.state in ("running", "resumed") and r.steps_per_s > 0 else "-",
                     format_duration(r.eta_s) if r.state in ("running", "resumed") else "-", num(r.last_success, ".2f"),
                     "-" if math.isnan(r.age_s) else f"{format_duration(r.age_s)} ago"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    right = {3, 5, 6, 7, 8, 10}
    lines = ["  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))).rstrip()
             for row in rows]
    lines += [f"  {r.suite}/{r.env}/{r.algo} seed {r.seed}: {r.error}" for r in df.itertuples() if r.error]
    return "\n".join(lines) + f"\n{len(df)} run(s): " + ", ".join(f"{n} {s}" for s, n in status_counts(df).items())
