"""A synthetic results directory with known values, written through the harness's own writer
(``harness.results.RunResults`` and ``write_status``, via ``harness.synthetic``), for the
dashboard/report/analysis tests. ``write_big`` (the large set) lives in ``harness.synthetic``.

Deployed success of run (env, algo, seed) at step s (evaluations every ``EVAL_EVERY`` steps up to
``STEPS``)::

    success = FINAL[env][algo] * s / STEPS + OFFSET[seed]

so at the last evaluation the mean over seeds is ``FINAL + mean(OFFSET)`` and the standard error
``std(OFFSET, ddof=1) / sqrt(3)`` for every method (see :func:`expected_final`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from harness.results import RunResults, run_dir, write_status
from harness.synthetic import metric_rows, write_big, write_run  # noqa: F401  (write_big: re-exported)

SUITE = "fixture"
ENVS = ("tabletop_manipulation", "sawyer_door")
ALGOS = ("naive", "medal", "medal_logc")
SEEDS = (0, 1, 2)
OFFSET = {0: 0.0, 1: 0.1, 2: 0.2}
STEPS, EVAL_EVERY = 100_000, 10_000
FINAL = {
    "tabletop_manipulation": {"naive": 0.3, "medal": 0.6, "medal_logc": 0.45},
    "sawyer_door": {"naive": 0.1, "medal": 0.7, "medal_logc": 0.5},
}
#: run (env, algo, seed) -> status written for it; everything else is "done"
STATUS = {
    ("sawyer_door", "medal_logc", 0): "running",
    ("sawyer_door", "medal_logc", 1): "resumed",
    ("sawyer_door", "medal_logc", 2): "stale",  # "running", last updated 2 hours ago
}
FAILED = ("sawyer_door", "fbrl", 0)  # a run that failed before its first evaluation (status only)
FAILED_ERROR = "RuntimeError: CUDA out of memory (synthetic)"


def success(env: str, algo: str, seed: int, step: int) -> float:
    return FINAL[env][algo] * step / STEPS + OFFSET[seed]


def expected_final(env: str, algo: str) -> tuple[float, float]:
    """(mean, standard error ddof=1) over seeds of the last evaluation's deployed success."""
    v = np.array([success(env, algo, s, STEPS) for s in SEEDS])
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(len(v)))


def metrics_at(env: str, algo: str, seed: int):
    def fn(step: int) -> dict[str, float]:
        s = success(env, algo, seed, step)
        return {"deployed_success": s, "deployed_return": 300 * s, "continuing_reward": step * s / 1000,
                "interventions": step // 50_000, "steps_per_s": 100.0, "wall_s": step / 100}
    return fn


def write_fixture(root: str | Path, corrupt: bool = False, tuning: bool = True, failed: bool = True) -> Path:
    """Write the fixture under ``root``; ``corrupt`` adds an unreadable ``evals.parquet``;
    ``tuning`` adds an Optuna journal under ``<root>/tuning/`` when optuna is installed;
    ``failed`` adds the failed run :data:`FAILED` (status only)."""
    root = Path(root)
    now = time.time()
    steps = range(0, STEPS + 1, EVAL_EVERY)
    for env in ENVS:
        for algo in ALGOS:
            for seed in SEEDS:
                state = STATUS.get((env, algo, seed), "done")
                last = success(env, algo, seed, STEPS)
                st = {"state": "running" if state == "stale" else state, "step": STEPS, "total": STEPS,
                      "steps_per_s": 100.0, "eta_s": 0.0 if state == "done" else 50.0, "last_success": last,
                      "updated": now - 7200 if state == "stale" else now}
                write_run(root, SUITE, env, algo, seed, steps, metrics_at(env, algo, seed), st, EVAL_EVERY)
    if failed:
        env, algo, seed = FAILED
        write_status(run_dir(root, SUITE, env, algo, seed), state="failed", error=FAILED_ERROR + "\nsecond line",
                     traceback="Traceback (most recent call last): ...")
    if corrupt:
        d = run_dir(root, SUITE, "sawyer_door", "broken", 0)
        d.mkdir(parents=True, exist_ok=True)
        (d / "evals.parquet").write_bytes(b"this is not a parquet file")
    if tuning:
        write_tuning(root)
    return root


TUNE_STUDY = "medal_sawyer_door"


def write_tuning(root: Path) -> Path | None:
    """One ``harness tune`` trial run (as harness/tune/ lays it out: suite ``tune_<study>``,
    ``study``/``trial`` metadata) and, when optuna is installed, the study's journal."""
    d = run_dir(Path(root) / "tuning" / TUNE_STUDY / "trial=0", f"tune_{TUNE_STUDY}", "sawyer_door", "medal", 0)
    r = RunResults(d, {"suite": f"tune_{TUNE_STUDY}", "env": "sawyer_door", "algo": "medal", "seed": 0},
                   {"study": TUNE_STUDY, "trial": 0, "members": 1})
    r.rows = metric_rows(r.ident, r.meta, range(0, STEPS + 1, EVAL_EVERY), lambda s: {"deployed_success": 0.99})
    r.flush()
    write_status(d, state="done", step=STEPS, total=STEPS, steps_per_s=100.0, eta_s=0.0, last_success=0.99)
    try:
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend
    except ImportError:
        return None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    path = Path(root) / "tuning" / f"{TUNE_STUDY}.journal"
    path.parent.mkdir(parents=True, exist_ok=True)
    storage = JournalStorage(JournalFileBackend(str(path)))
    study = optuna.create_study(study_name=TUNE_STUDY, storage=storage, direction="maximize",
                                sampler=optuna.samplers.RandomSampler(seed=0), load_if_exists=True)
    study.optimize(lambda t: 1 - abs(math.log10(t.suggest_float("lr", 1e-4, 1e-2, log=True)) + 2.5)
                   + 0 * t.suggest_int("batch_size", 32, 256), n_trials=12)
    return path


#: :func:`write_mixed_suites`: (suite, env, algo) -> (seeds, last step, eval every, final success, hours since updated)
MIXED = {
    **{("smoke", "tabletop_manipulation", a): ((0,), 400, 200, 0.0, 0.0)
       for a in ("naive", "medal", "medal_logc", "fbrl_vice", "bc", "gail_naive", "gail_oracle")},
    ("reproduction", "tabletop_manipulation", "medal"): ((0, 1, 2), 1_500_000, 100_000, 1.0, 2.0),
    ("reproduction", "tabletop_manipulation", "risc"): ((0, 1), 500_000, 100_000, 0.8, 2.0),  # not a Table-1 cell
    ("table1", "sawyer_peg", "medal"): ((0, 1), 400_000, 100_000, 0.0, 1.0),  # running: 400k of 8M
    ("imitation", "sawyer_door", "medal"): ((0, 1), 200_000, 100_000, 0.9, 3.0),
    ("imitation", "sawyer_door", "bc"): ((0, 1), 200_000, 100_000, 0.3, 3.0),
}


def write_mixed_suites(root: str | Path) -> Path:
    """Runs of one method in several suites at very different budgets, as after ``harness run suite=smoke`` in a
    results directory with the shipped tables (:data:`MIXED`): success rises linearly to its final value; smoke is the
    most recently updated suite."""
    root = Path(root)
    now = time.time()
    for (suite, env, algo), (seeds, last, every, final, hours) in MIXED.items():
        for seed in seeds:
            done = suite != "table1"
            st = {"state": "done" if done else "running", "step": last, "total": last if done else 8_000_000,
                  "steps_per_s": 40.0, "eta_s": 0.0, "last_success": final, "updated": now - 3600 * hours}
            write_run(root, suite, env, algo, seed, range(0, last + 1, every),
                      lambda s, f=final, last=last: {"deployed_success": f * s / last}, st, every)
    return root
