"""The trials of ``harness tune``: sampling, pruning, the objective (one run group per trial) and a worker's loop."""

from __future__ import annotations

import math
import os
import socket
import sys
from pathlib import Path
from typing import Any

from harness.suites import ConfigError
from harness.tune.setup import trial_request
from harness.tune.studies import (
    fail_dead_local_trials,
    finished,
    frozen_trial,
    load_optuna,
    make_storage,
    open_study,
    retry_callback_class,
    retry_interrupted_trials,
)


class TrialRunError(RuntimeError):
    """The trial's training run failed (recorded as a FAILED trial; the study goes on)."""


def suggest(trial, name: str, spec: dict[str, Any]) -> Any:
    if spec["type"] == "categorical":
        return trial.suggest_categorical(name, spec["choices"])
    if spec["type"] == "int":
        return trial.suggest_int(name, int(spec["low"]), int(spec["high"]), log=bool(spec.get("log")))
    return trial.suggest_float(name, float(spec["low"]), float(spec["high"]), log=bool(spec.get("log")))


def make_sampler(setup: dict[str, Any], index: int, n_existing: int):
    optuna = load_optuna()
    seed = None if setup["sampler_seed"] is None else setup["sampler_seed"] + 1009 * index + n_existing
    if setup["sampler"] == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    return optuna.samplers.TPESampler(seed=seed)


def make_pruner(setup: dict[str, Any]):
    optuna = load_optuna()
    if setup["pruner"] == "median":
        return optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=setup["steps"] // 4)
    if setup["pruner"] == "hyperband":
        return optuna.pruners.HyperbandPruner(min_resource=setup["eval_every"], max_resource=setup["steps"], reduction_factor=3)
    return optuna.pruners.NopPruner()


def trial_progress(dirs: list[Path]) -> tuple[int, float]:
    """(last evaluated step, mean deployed success so far averaged over seeds) from the parquet files."""
    import pandas as pd

    from harness.results import EVALS_FILE

    means, step = [], 0
    for d in dirs:
        p = Path(d) / EVALS_FILE
        if not p.exists():
            continue
        df = pd.read_parquet(p, columns=["step", "metric", "value"])
        s = df[df.metric == "deployed_success"]
        if len(s):
            means.append(float(s.value.mean()))
            step = max(step, int(s.step.max()))
    return step, (float(sum(means) / len(means)) if means else float("nan"))


def objective(setup: dict[str, Any], threads: int | None):
    optuna = load_optuna()
    from harness.planning import build_plan
    from harness.results import write_status
    from harness.runner import run_group

    retry_cls = retry_callback_class()

    def objective(trial) -> float:
        origin = retry_cls.retried_trial_number(frozen_trial(trial.study, trial.number))
        number = trial.number if origin is None else origin  # a retry resumes in the dead trial's directory
        trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
        params = {k: suggest(trial, k, spec) for k, spec in setup["space"].items()}
        trial_dir = Path(setup["results"]) / "tuning" / setup["study"] / f"trial={number}"
        trial.set_user_attr("results", str(trial_dir))
        try:
            plan = build_plan(trial_request(setup["request"], setup["algo"], params, str(trial_dir), number))
        except ConfigError as e:
            raise TrialRunError(str(e)) from None
        (group,) = plan.groups
        dirs = group.member_dirs()
        pruned: dict[str, Any] = {}

        def should_stop() -> bool:
            step, value = trial_progress(dirs)
            if math.isfinite(value):
                trial.report(value, step)
                if trial.should_prune():
                    pruned.update(step=step, value=value)
                    return True
            return False

        retried = f" (retry of trial {origin})" if origin is not None else ""
        print(f"[{setup['study']}] trial {trial.number}{retried}: {params}", flush=True)
        from harness.interrupts import RunInterrupted

        try:
            err = run_group(group, setup["command"], None, threads, should_stop)
        except RunInterrupted:
            trial.set_user_attr("interrupted", True)  # retried with its parameters when tuning resumes
            raise
        if err:
            print(f"[{setup['study']}] trial {trial.number} failed: {err}", file=sys.stderr, flush=True)
            raise TrialRunError(err)
        if pruned:
            for d in dirs:
                write_status(d, state="pruned", step=pruned["step"], total=group.steps, last_success=pruned["value"])
            print(f"[{setup['study']}] trial {trial.number} pruned at step {pruned['step']:,} "
                  f"(mean success so far {pruned['value']:.4f})", flush=True)
            raise optuna.TrialPruned(f"pruned at step {pruned['step']}")
        step, value = trial_progress(dirs)
        print(f"[{setup['study']}] trial {trial.number} finished: mean success {value:.4f}", flush=True)
        return value

    return objective


def tune_worker(setup: dict[str, Any], index: int, threads: int | None, env: dict[str, str] | None = None) -> int:
    """One worker: optimise the shared study until it holds ``trials`` finished trials. Returns the
    number of trials this worker ran."""
    if env:
        os.environ.update(env)
    optuna = load_optuna()
    import torch
    from optuna.study import MaxTrialsCallback
    from optuna.trial import TrialState

    if threads:
        torch.set_num_threads(threads)
    storage = make_storage(setup)
    study = open_study(setup, create=False, storage=storage)
    fail_dead_local_trials(study, storage)
    optuna.storages.fail_stale_trials(study)
    if index == 0:  # one worker re-queues the interrupted trials
        retry_interrupted_trials(study)
    study = optuna.load_study(study_name=setup["study"], storage=storage,
                              sampler=make_sampler(setup, index, len(study.trials)), pruner=make_pruner(setup))
    remaining = setup["trials"] - finished(study)
    if remaining <= 0:
        return 0
    before = len(study.trials)
    study.optimize(objective(setup, threads), n_trials=remaining, catch=(TrialRunError,),
                   callbacks=[MaxTrialsCallback(setup["trials"], states=(TrialState.COMPLETE, TrialState.PRUNED))])
    return len(study.trials) - before

