"""The one results writer, and the loader.

Each run (suite, env, algo, seed) owns a deterministic directory
``<results>/<suite>/<env>/<algo>/seed=<k>/`` holding

- ``evals.parquet``: the long table of this run (columns ``COLUMNS``), rewritten atomically at
  every evaluation, so a reader never sees a half file and a resumed run truncates to its
  checkpoint's step before appending (no row lost or duplicated);
- ``run.yaml``: resolved config, command, git SHA, package versions, demo source, device, members;
- ``status.json``: running / done / failed / resumed, step, steps/s, ETA, last success, error.

``load(path)`` returns one DataFrame of every ``evals.parquet`` under ``path`` (corrupt files are
named on stderr and skipped). The published curves (``reference/published_curves.csv.gz``) share
the long format: ``load_published()`` renames ``method`` to ``algo`` and maps their metric names
onto ours so the two concatenate.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from harness.data import atomic_write_bytes, find_data_dir
from harness.envs import ENVS
from harness.suites import ConfigError

COLUMNS = ["suite", "env", "algo", "seed", "step", "metric", "value"]
META_COLUMNS = ["source", "config_hash", "git_sha", "demo_source", "device", "members", "study", "trial"]
METRICS = ("deployed_success", "deployed_return", "continuing_reward", "interventions", "steps_per_s", "wall_s")
PUBLISHED_METRICS = {"deployed": "deployed_success", "continuing_cumulative_reward": "continuing_reward"}
EVALS_FILE, RUN_FILE, STATUS_FILE = "evals.parquet", "run.yaml", "status.json"
CHECKPOINT_FILE = "checkpoint.pt"  # one per group: <results>/<suite>/<env>/<algo>/checkpoints/seeds=<a-b-..>/
TRAIN_FILE = "train.parquet"  # training diagnostics (Algorithm.metrics every log_every steps), same columns


def run_dir(results: Path, suite: str, env: str, algo: str, seed: int) -> Path:
    return Path(results) / suite / env / algo / f"seed={seed}"


def parse_run_dir(path: Path, results: Path) -> dict[str, Any] | None:
    """The inverse of :func:`run_dir`: the ``suite, env, algo, seed`` of the run directory ``path`` under
    ``results`` (``run_dir(results, **parse_run_dir(path, results)) == path``), or None when ``path`` is no run
    directory (its last part is not ``seed=<k>``). A suite nested in folders (``tuning/<study>/...``) is named by
    all of them. Lenient for display: below the results root (``results`` a suite's folder, say) the parts above
    it are None, and so is the seed of a ``seed=`` that is no integer."""
    parts = Path(path).relative_to(results).parts
    if not parts or not parts[-1].startswith("seed="):
        return None
    try:
        seed: int | None = int(parts[-1].split("=", 1)[1])
    except ValueError:
        seed = None
    rest = parts[:-1]
    return {"suite": "/".join(rest[:-2]) if len(rest) >= 3 else None, "env": rest[-2] if len(rest) >= 2 else None,
            "algo": rest[-1] if rest else None, "seed": seed}


def kept_checkpoint_path(ckpt: Path, step: int) -> Path:
    """Where a checkpoint kept at ``step`` (``keep_every``) lies: ``checkpoint-<step>.pt`` beside ``ckpt``."""
    return ckpt.with_name(f"{ckpt.stem}-{step}{ckpt.suffix}")


def checkpoint_path(results: Path, suite: str, env: str, algo: str, seeds: list[int]) -> Path:
    """Where the group of ``seeds`` (trained together, E = len(seeds)) keeps its one checkpoint."""
    tag = "-".join(str(s) for s in seeds)
    return Path(results) / suite / env / algo / "checkpoints" / f"seeds={tag}" / CHECKPOINT_FILE


def _parquet_bytes(df: pd.DataFrame) -> bytes:
    import io

    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


class RunResults:
    """Rows of one run, kept in memory and written atomically after every append."""

    def __init__(self, directory: Path, ident: dict[str, Any], meta: dict[str, Any], filename: str = EVALS_FILE):
        self.dir, self.filename = Path(directory), filename
        self.ident = ident  # suite, env, algo, seed
        self.meta = {k: meta.get(k) for k in META_COLUMNS}
        self.meta["source"] = self.meta.get("source") or "harness"
        self.rows: list[dict[str, Any]] = []
        self._mirror: Callable[[list[dict[str, Any]]], None] | None = None
        self._mirrored = 0

    @property
    def path(self) -> Path:
        return self.dir / self.filename

    def resume(self, step: int) -> None:
        """Keep the rows written up to ``step`` (the checkpoint's), drop any later ones."""
        if self.path.exists():
            df = pd.read_parquet(self.path)
            self.rows = df[df["step"] <= step].to_dict("records")
        else:
            self.rows = []

    def append(self, step: int, values: dict[str, float], flush: bool = True) -> None:
        for metric, value in values.items():
            self.rows.append({**self.ident, "step": int(step), "metric": metric, "value": float(value), **self.meta})
        if flush:
            self.flush()

    def frame(self) -> pd.DataFrame:
        df = pd.DataFrame(self.rows, columns=COLUMNS + META_COLUMNS)
        return df.astype({"seed": "int64", "step": "int64", "value": "float64", "members": "Int64", "trial": "Int64"})

    def flush(self) -> None:
        atomic_write_bytes(self.path, _parquet_bytes(self.frame()))
        if self._mirror is not None:
            self._mirror(self.rows[self._mirrored :])
            self._mirrored = len(self.rows)

    def mirror_to(self, fn: Callable[[list[dict[str, Any]]], None]) -> None:
        """After each flush, also hand the rows added since the last one to ``fn`` (e.g. a TensorBoard writer);
        rows kept by :meth:`resume` were handed over before the run stopped."""
        self._mirror, self._mirrored = fn, len(self.rows)


def _strict(v: Any) -> Any:
    """JSON-safe: non-finite floats (an unknown ETA, a success not measured yet) become null."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_strict(x) for x in v]
    return v


def write_status(directory: Path, **fields: Any) -> None:
    """``status.json``, strict JSON (no NaN / Infinity: they are written as null)."""
    fields.setdefault("updated", time.time())
    fields = {k: _strict(v) for k, v in fields.items()}
    atomic_write_bytes(Path(directory) / STATUS_FILE,
                       json.dumps(fields, indent=1, default=str, allow_nan=False).encode())


def update_status(directory: Path, **fields: Any) -> None:
    """``write_status`` keeping the fields not given (e.g. the step and total of a run that failed)."""
    old = read_status(directory) or {}
    old.pop("updated", None)
    write_status(directory, **{**old, **fields})


def read_status(directory: Path, strict: bool = False) -> dict[str, Any] | None:
    """The run's ``status.json``; None without one, and None for an unreadable one too unless ``strict``, which
    raises its OSError / ValueError instead (for a caller that says why)."""
    p = Path(directory) / STATUS_FILE
    if strict:
        return json.loads(p.read_text()) if p.exists() else None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return None


def load(path: str | Path, warn=None, filename: str = EVALS_FILE) -> pd.DataFrame:
    """All results under ``path`` as one long DataFrame (empty with the right columns if none); ``filename``
    :data:`TRAIN_FILE` reads the training diagnostics instead of the evaluations."""
    warn = warn or (lambda msg: print(msg, file=sys.stderr))
    tables = []
    root = Path(path).expanduser()
    if not root.exists():  # a mistyped path is not "no results yet"
        warn(f"no results directory {root} (from {Path.cwd()}): nothing loaded")
    files = [root] if root.is_file() else sorted(root.rglob(filename))
    for f in files:
        try:
            tables.append(pq.read_table(f))
        except Exception as e:  # a corrupt or foreign file: name it, skip it
            warn(f"skipping unreadable results file {f}: {type(e).__name__}: {e}")
    if not tables:
        return pd.DataFrame(columns=COLUMNS + META_COLUMNS)
    # one Arrow concat and one conversion (3x faster than a pandas concat of 100 frames)
    return pa.concat_tables(tables, promote_options="permissive").to_pandas()


def runs_holding(path: str | Path, filename: str = TRAIN_FILE) -> set[tuple[str, str, str, int]]:
    """``(suite, env, algo, seed)`` of every run under ``path`` whose directory holds ``filename`` (by default the
    training diagnostics: which shipped evaluations have the tables a diagnosis can check beside them)."""
    root = Path(path)
    runs = (parse_run_dir(f.parent, root) for f in root.rglob(filename))
    return {(r["suite"], r["env"], r["algo"], r["seed"]) for r in runs if r and None not in r.values()}


#: envs whose published "deployed" curves are the deployed policy's return, not a success rate
#: (shared/earl/README.md: EARL's kitchen and dhand_lightbulb, RISC's minitaur): each env's ``EnvInfo.published_metric``,
#: and dhand_lightbulb, which EARL published curves for but never released
RETURN_ENVS = frozenset({n for n, e in ENVS.items() if e.published_metric == "deployed_return"} | {"dhand_lightbulb"})


def load_published(data_dir: str | Path | None = None) -> pd.DataFrame:
    """The published learning curves in our long format (``source`` says whose)."""
    root = Path(data_dir) if data_dir else find_data_dir("reference/published_curves.csv.gz")
    df = pd.read_csv(root / "reference" / "published_curves.csv.gz")
    df = df.rename(columns={"method": "algo"})
    df["metric"] = df["metric"].replace(PUBLISHED_METRICS)
    returns = df["env"].isin(RETURN_ENVS) & (df["metric"] == "deployed_success")
    df.loc[returns, "metric"] = "deployed_return"  # the published "deployed" values are returns on these envs
    return df


def load_train(path: str | Path, warn=None) -> pd.DataFrame:
    """The training diagnostics (``train.parquet``) under ``path``, in the evaluations' long format."""
    return load(path, warn, TRAIN_FILE)


def _last_step(evals: Path) -> int:
    """The furthest evaluated step of an ``evals.parquet`` (-1 when it has no rows)."""
    steps = pq.read_table(evals, columns=["step"]).column("step")
    return -1 if len(steps) == 0 else int(pc.max(steps).as_py())


def _shipped_status(run: Path) -> bytes:
    """The status a shipped copy carries: a finished or failed run's as it is; an unfinished one's as ``shipped``
    (a copy taken at its step; the run goes on elsewhere, so no speed, no ETA and never "stale")."""
    st = read_status(run) or {}
    if st.get("state") in ("done", "failed"):
        return (run / STATUS_FILE).read_bytes()
    st = {**st, "state": "shipped", "shipped_from": st.get("state"), "steps_per_s": None, "eta_s": None}
    return (json.dumps(st, indent=1, allow_nan=False) + "\n").encode()


def ship(source: str | Path, suite: str, dest: str | Path, force: bool = False) -> tuple[list[Path], list[str]]:
    """Copy the tables of every run of ``suite`` under ``source`` (``evals.parquet``, ``train.parquet``, ``run.yaml``,
    ``status.json``; never checkpoints) to the same place under ``dest``, each file written atomically: the small
    tables a repository can ship so that a fresh clone shows them (docs/reproduction.md). An unfinished run's status
    is shipped as ``shipped`` at its step (see :func:`_shipped_status`).

    A run that restarted from 0 (its checkpoint lost with a machine) would replace a shipped table that got further;
    such a run is kept as shipped, and named in the second return value, unless ``force``. Returns (files written,
    runs kept)."""
    src, dst = Path(source).expanduser() / suite, Path(dest).expanduser() / suite
    if not src.is_dir():
        raise ConfigError(f"no results of suite {suite!r} under {source}")
    if src.resolve() == dst.resolve():
        raise ConfigError(f"source and destination are the same directory: {src}")
    written, kept = [], []
    for evals in sorted(src.rglob(EVALS_FILE)):
        run = evals.parent
        rel = run.relative_to(src)
        if "checkpoints" in rel.parts:
            continue
        shipped = dst / rel / EVALS_FILE
        if not force and shipped.is_file() and (there := _last_step(shipped)) > (here := _last_step(evals)):
            kept.append(f"{rel.as_posix()} (shipped to step {there:,}, the run is at {here:,})")
            continue
        for name in (EVALS_FILE, TRAIN_FILE, RUN_FILE, STATUS_FILE):  # the training diagnostics too: a diagnosis cites them
            if (run / name).is_file():
                target = dst / rel / name
                data = (run / name).read_bytes() if name != STATUS_FILE else _shipped_status(run)
                atomic_write_bytes(target, data)
                written.append(target)
    return written, kept
