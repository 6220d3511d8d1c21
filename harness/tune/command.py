"""``harness tune``: an Optuna study over an algorithm's hyperparameters (MEDAL's discriminator).

    harness tune algo=medal env=ENV trials=N [study=NAME] [storage=PATH|URL] [steps=N] [seeds=N]
                 [seed=K] [workers=N] [pruner=median|hyperband|none] [sampler=tpe|random] [sampler_seed=N]
                 [results=DIR] [backend=local|ray] [ray_address=...] [search=FILE]
                 [heartbeat_interval=S] [grace_period=S] [eval_every=...] [eval_episodes=...]
                 [checkpoint_every=...] [device=...] [<algo>.<key>=value | all.<key>=value ...]
    harness tune algo=medal env=ENV [study=NAME] [storage=...] --best

Search space: ``suites/algorithms/<algo>_search.yaml`` (``params: {name: {type, low, high, log} |
{type: categorical, choices}}``); parameters fixed on the command line are left out of it.

A trial trains its seeds in lockstep (one group, ``members`` = seeds) with the sampled config into
``<results>/tuning/<study>/trial=<n>/`` under the suite name ``tune_<study>``, with the ``study``
and ``trial`` metadata columns filled. After every evaluation the trial reports the mean deployed
success so far (the area under the success curve, averaged over seeds) and stops if the pruner
says so (``optuna.TrialPruned``; its partial results stay). The objective is that value at the end.

Storage: by default the journal file ``<results>/tuning/<study>.journal``; ``storage=`` takes another
path or an RDB URL (``postgresql://user@host/db``, ``sqlite:///file.db``). The study is loaded if it
exists, so re-running the command continues it until ``trials`` trials have finished (complete or
pruned). ``workers=N`` runs N worker processes (or Ray tasks with ``backend=ray``) on the same study.
A trial whose worker died is marked FAILED and retried with the same parameters, resuming from the
dead trial's checkpoint (it writes into the dead trial's directory): on an RDB through Optuna's
heartbeat (``heartbeat_interval``, ``grace_period``), on a journal file when a later worker on the
same host finds the dead trial's process gone.
"""

from __future__ import annotations

import os
import shlex
import sys
from typing import Any

import yaml

from harness.suites import ConfigError
from harness.tune.setup import parse_setup
from harness.tune.studies import fail_dead_local_trials, finished, make_storage, open_study, summary
from harness.tune.trials import tune_worker


def _fmt(v: Any) -> str:
    return str(v).lower() if isinstance(v, bool) else repr(v) if isinstance(v, float) else str(v)


def best_yaml(study, setup: dict[str, Any]) -> str:
    """The best trial's parameters as a YAML ``config:`` block (for a suite file) with the equivalent
    ``harness run`` command in a comment. The whole text is valid YAML."""
    try:
        best = study.best_trial
    except ValueError:
        raise ConfigError(f"study {study.study_name!r} has no complete trial yet") from None
    algo, env = study.user_attrs.get("algo", setup["algo"]), study.user_attrs.get("env", setup["env"])
    fixed: dict[str, dict[str, Any]] = {s: {k: yaml.safe_load(str(v)) for k, v in kv.items()}
                                        for s, kv in study.user_attrs.get("fixed_config", {}).items()}
    for w in study.user_attrs.get("algo_words", []):  # studies created before fixed_config
        k, v = w.split("=", 1)
        scope, key = k.split(".", 1)
        fixed.setdefault(scope, {})[key] = yaml.safe_load(v)
    config = {**fixed, algo: {**fixed.get(algo, {}), **best.params}}
    words = [f"algo={algo}", f"env={env}"] + [f"{s}.{k}={_fmt(v)}" for s, kv in config.items() for k, v in kv.items()]
    head = [
        f"# best of study {study.study_name} ({finished(study)} finished trials): trial {best.number}, "
        f"mean deployed success {best.value:.4f}",
        f"# results: {best.user_attrs.get('results', '?')}",
        "# as a command (add seeds=, steps=, ...):",
        f"#   harness run {' '.join(shlex.quote(w) for w in words)}",
        "# or as a suite's config block:",
    ]
    return "\n".join(head) + "\n" + yaml.safe_dump({"config": config}, sort_keys=False)


def tune_cli(words: list[str], best: bool = False) -> int:
    setup = parse_setup(words, best=best)
    if best:
        print(best_yaml(open_study(setup, create=False), setup), end="")
        return 0
    if setup["seed_note"]:
        print(f"harness: note: {setup['seed_note']}", file=sys.stderr)
    storage = make_storage(setup)
    study = open_study(setup, create=True, storage=storage)
    fail_dead_local_trials(study, storage)
    print(f"tuning {setup['algo']} on {setup['env']}: study {setup['study']} in {setup['storage']}, "
          f"{setup['trials']} trial(s) of {setup['steps']:,} steps, {len(setup['space'])} parameter(s), "
          f"{setup['workers']} worker(s), {setup['backend']} backend; {summary(study)}", flush=True)
    n = setup["workers"]
    if finished(study) < setup["trials"]:
        if setup["backend"] == "ray":
            from harness.backends import ray_env, ray_options, ray_session, run_ray_tasks

            threads = 1  # each worker task reserves one CPU
            errors: list[str] = []
            with ray_session(setup["ray_address"], n) as ray:
                run_ray_tasks(ray, tune_worker, [(setup, i, threads, ray_env()) for i in range(n)],
                              [f"worker {i}" for i in range(n)], ray_options(setup["request"].device, 1),
                              lambda label, line: errors.append(f"{label}: {line}"))
            for e in errors:
                print(f"harness: tune worker failed: {e}", file=sys.stderr)
        else:
            from harness.backends import run_local_tasks

            threads = max(1, (os.cpu_count() or 1) // n) if n > 1 else None  # one worker: torch's default
            run_local_tasks(tune_worker, [(setup, i, threads) for i in range(n)], n)
    study = open_study(setup, create=False)
    print(summary(study))
    done = finished(study)
    if any(t.value is not None for t in study.get_trials(deepcopy=False)):
        b = study.best_trial
        print(f"best: trial {b.number}, mean deployed success {b.value:.4f}, {b.params}")
    print(f"best parameters as YAML: harness tune algo={setup['algo']} env={setup['env']} study={setup['study']} "
          f"storage={shlex.quote(setup['storage'])} --best")
    return 0 if done >= setup["trials"] else 1
