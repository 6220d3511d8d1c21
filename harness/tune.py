"""``harness tune``: an Optuna study over an algorithm's hyperparameters (MEDAL's discriminator).

    harness tune algo=medal env=ENV trials=N [study=NAME] [storage=PATH|URL] [steps=N] [seeds=N]
                 [workers=N] [pruner=median|hyperband|none] [sampler=tpe|random] [seed=N]
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

import math
import os
import re
import shlex
import socket
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from harness.suites import SUITES_DIR, ConfigError
from harness.words import integer as parse_int
from harness.words import parse_words

if TYPE_CHECKING:
    from harness.runner import RunRequest

#: every key=value word of ``harness tune``: (default, meaning); ``harness tune --help`` prints this table
TUNE_KEY_HELP: dict[str, tuple[str, str]] = {
    "algo": ("-", "the algorithm to tune (its search space: suites/algorithms/<algo>_search.yaml)"),
    "env": ("-", "the env"),
    "trials": ("-", "finished trials (complete or pruned) the study should reach"),
    "study": ("<algo>_<env>", "study name"),
    "storage": ("<results>/tuning/<study>.journal", "journal file path or RDB URL (postgresql://..., sqlite:///...)"),
    "steps": ("the env's default", "training steps per trial"),
    "seeds": ("1", "seeds per trial (trained as members of one process)"),
    "workers": ("1", "worker processes (or Ray tasks) on the same study"),
    "pruner": ("median", "median, hyperband or none"),
    "sampler": ("tpe", "tpe or random"),
    "seed": ("none", "sampler seed"),
    "results": ("results", "results directory"),
    "backend": ("local", "local or ray"),
    "ray_address": ("start one", "Ray cluster to join, with backend=ray"),
    "search": ("suites/algorithms/<algo>_search.yaml", "search space file"),
    "heartbeat_interval": ("60", "RDB storage: seconds between trial heartbeats"),
    "grace_period": ("optuna's", "RDB storage: seconds before a silent trial counts as dead"),
    "eval_every": ("10000", "steps between evaluations"),
    "eval_episodes": ("10", "episodes per evaluation"),
    "checkpoint_every": ("50000", "steps between checkpoints"),
    "device": ("cpu", "torch device"),
}
TUNE_KEYS = set(TUNE_KEY_HELP)
PRUNERS = ("median", "hyperband", "none")
SAMPLERS = ("tpe", "random")
MAX_RETRY = 3
DEFAULT_HEARTBEAT = 60


class TrialRunError(RuntimeError):
    """The trial's training run failed (recorded as a FAILED trial; the study goes on)."""


# ---------------------------------------------------------------------------------------- setup


def _optuna():
    try:
        import optuna
    except ImportError:
        raise ConfigError("harness tune needs Optuna: pip install 'optuna>=4'") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings("ignore", category=FutureWarning, module="optuna")
    return optuna


def load_search_space(algo: str, path: str | None = None) -> dict[str, dict[str, Any]]:
    """The search space of ``algo`` (``suites/algorithms/<algo>_search.yaml`` or ``path``), validated."""
    p = Path(path) if path else SUITES_DIR / "algorithms" / f"{algo}_search.yaml"
    if not p.exists():
        raise ConfigError(f"no search space for algorithm {algo!r}: {p} not found")
    try:
        d = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as e:
        raise ConfigError(f"malformed YAML in {p}: {getattr(e, 'problem', None) or type(e).__name__}") from None
    if not isinstance(d, dict) or set(d) - {"params"} or not isinstance(d.get("params"), dict):
        raise ConfigError(f"{p} must be a mapping with the one key 'params'")
    space: dict[str, dict[str, Any]] = {}
    for name, spec in d["params"].items():
        if not isinstance(spec, dict):
            raise ConfigError(f"{p}: parameter {name!r} must be a mapping (type, low, high, log or choices)")
        kind = spec.get("type")
        if kind == "categorical":
            if set(spec) - {"type", "choices"} or not isinstance(spec.get("choices"), list) or not spec["choices"]:
                raise ConfigError(f"{p}: categorical parameter {name!r} needs a non-empty list 'choices' (only)")
        elif kind in ("float", "int"):
            if set(spec) - {"type", "low", "high", "log"} or "low" not in spec or "high" not in spec:
                raise ConfigError(f"{p}: {kind} parameter {name!r} needs 'low' and 'high' (and optionally 'log')")
            try:
                lo, hi = float(spec["low"]), float(spec["high"])
            except (TypeError, ValueError):
                raise ConfigError(f"{p}: bounds of {name!r} must be numbers") from None
            if not lo < hi or (spec.get("log") and lo <= 0):
                raise ConfigError(f"{p}: bounds of {name!r} must satisfy 0 < low < high (log) or low < high")
            if kind == "int" and not (lo.is_integer() and hi.is_integer()):
                raise ConfigError(f"{p}: bounds of int parameter {name!r} must be integers")
        else:
            raise ConfigError(f"{p}: parameter {name!r} has type {kind!r}; use float, int or categorical")
        space[name] = spec
    return space


def suggest(trial, name: str, spec: dict[str, Any]) -> Any:
    if spec["type"] == "categorical":
        return trial.suggest_categorical(name, spec["choices"])
    if spec["type"] == "int":
        return trial.suggest_int(name, int(spec["low"]), int(spec["high"]), log=bool(spec.get("log")))
    return trial.suggest_float(name, float(spec["low"]), float(spec["high"]), log=bool(spec.get("log")))


def _fmt(v: Any) -> str:
    return str(v).lower() if isinstance(v, bool) else repr(v) if isinstance(v, float) else str(v)


def trial_request(base: RunRequest, algo: str, params: dict[str, Any], results: str, trial: int | None = None) -> RunRequest:
    """The run request of one trial: the study's request with the sampled parameters on top of the fixed ones."""
    config = {**base.config, algo: {**base.config.get(algo, {}), **params}}
    return replace(base, config=config, results=results, trial=trial)


def parse_setup(words: list[str], best: bool = False) -> dict[str, Any]:
    """Validate the tune command's words into a plain (picklable) setup dict; nothing is written."""
    from harness.registry import ALGORITHMS
    from harness.runner import MAX_EPISODES, MAX_STEPS, RunRequest, build_plan, check_device, parse_seeds

    ov, fixed_config = parse_words(words, TUNE_KEYS, scope=lambda s: True)

    def optional(key: str, maximum: int) -> int | None:
        return parse_int(key, ov[key], 1, maximum) if key in ov else None

    algo = ov.get("algo", "medal")
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}; known: {', '.join(ALGORITHMS)}")
    env = ov.get("env")
    if not env or "," in env:
        raise ConfigError("give one env=NAME to tune on")
    study = ov.get("study", f"{algo}_{env}")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", study):
        raise ConfigError(f"study names may hold letters, digits, '_', '.' and '-', got {study!r}")
    results = ov.get("results", "results")
    storage = ov.get("storage") or str(Path(results) / "tuning" / f"{study}.journal")
    setup: dict[str, Any] = {"algo": algo, "env": env, "study": study, "results": results, "storage": storage}
    hb = parse_int("heartbeat_interval", ov["heartbeat_interval"], 1) if "heartbeat_interval" in ov else None
    grace = parse_int("grace_period", ov["grace_period"], 1) if "grace_period" in ov else None
    setup.update(heartbeat_interval=hb, grace_period=grace)
    if best:
        return setup

    if "trials" not in ov:
        raise ConfigError("give trials=N, the number of finished trials the study should reach")
    setup["trials"] = parse_int("trials", ov["trials"], 1)
    setup["workers"] = parse_int("workers", ov.get("workers", 1), 1)
    seeds = ov.get("seeds", "1")
    setup["pruner"] = ov.get("pruner", "median")
    if setup["pruner"] not in PRUNERS:
        raise ConfigError(f"unknown pruner {setup['pruner']!r}; known: {', '.join(PRUNERS)}")
    setup["sampler"] = ov.get("sampler", "tpe")
    if setup["sampler"] not in SAMPLERS:
        raise ConfigError(f"unknown sampler {setup['sampler']!r}; known: {', '.join(SAMPLERS)}")
    setup["seed"] = parse_int("seed", ov["seed"], 0) if "seed" in ov else None
    setup["backend"] = ov.get("backend", "local")
    setup["ray_address"] = ov.get("ray_address")

    if setup["backend"] not in ("local", "ray"):
        raise ConfigError(f"unknown backend {setup['backend']!r}; known backends: local, ray")
    if setup["ray_address"] and setup["backend"] != "ray":
        raise ConfigError("ray_address is only used with backend=ray")
    space = load_search_space(algo, ov.get("search"))
    fixed = set(fixed_config.get(algo, {})) | set(fixed_config.get("all", {}))
    space = {k: v for k, v in space.items() if k not in fixed}
    unknown = sorted(set(space) - ALGORITHMS[algo].Config.keys())
    if unknown:
        raise ConfigError(f"search space names unknown config key(s) {unknown} for algorithm {algo!r}")
    if not space:
        raise ConfigError("nothing to tune: every parameter of the search space is fixed on the command line")
    setup["space"] = space

    seed_list = parse_seeds(seeds)
    ray_cluster = setup["backend"] == "ray" and setup["ray_address"]
    base = RunRequest(
        algos=(algo,), envs=(env,), seeds=tuple(seed_list), members=len(seed_list), workers=1,
        steps=optional("steps", MAX_STEPS), eval_every=optional("eval_every", MAX_STEPS),
        eval_episodes=optional("eval_episodes", MAX_EPISODES), checkpoint_every=optional("checkpoint_every", MAX_STEPS),
        device=check_device(ov.get("device", "cpu"), local=not ray_cluster),
        backend="ray" if ray_cluster else "local", ray_address=setup["ray_address"] if ray_cluster else None,
        config=fixed_config, study=study,
    )
    # validate everything (keys, values, data) with one plan of each extreme choice; nothing is written
    probe = str(Path(results) / "tuning" / study / ".validate")
    for pick in (0, -1):
        params = {k: (s["choices"][pick] if s["type"] == "categorical" else s["low"] if pick == 0 else s["high"])
                  for k, s in space.items()}
        plan = build_plan(trial_request(base, algo, params, probe))
    g = plan.groups[0]
    setup.update(request=base, fixed_config=fixed_config, steps=g.steps, eval_every=g.eval_every)
    setup["command"] = " ".join(["harness", "tune", *map(shlex.quote, words)])
    return setup


def make_storage(setup: dict[str, Any]):
    """Optuna storage: a journal file (path) or an RDB URL with heartbeats and retried failed trials."""
    optuna = _optuna()
    spec = setup["storage"]
    if "://" in spec:
        kw: dict[str, Any] = {"heartbeat_interval": setup["heartbeat_interval"] or DEFAULT_HEARTBEAT}
        if setup["grace_period"]:
            kw["grace_period"] = setup["grace_period"]
        try:
            from optuna.storages import RetryHeartbeatStaleTrialCallback  # optuna >= 4.9

            kw["heartbeat_stale_trial_callback"] = RetryHeartbeatStaleTrialCallback(MAX_RETRY, inherit_intermediate_values=True)
        except ImportError:
            kw["failed_trial_callback"] = optuna.storages.RetryFailedTrialCallback(MAX_RETRY, inherit_intermediate_values=True)
        spec = _pg_driver(spec)
        try:
            return optuna.storages.RDBStorage(spec, **kw)
        except Exception as e:  # noqa: BLE001 - bad URL, unreachable server, missing driver
            raise ConfigError(f"cannot open storage {spec}: {type(e).__name__}: {' '.join(str(e).split())[:300]}") from None
    path = Path(spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        from optuna.storages.journal import JournalFileBackend  # optuna >= 4.0

        backend = JournalFileBackend(str(path))
    except ImportError:
        backend = optuna.storages.JournalFileStorage(str(path))
    return optuna.storages.JournalStorage(backend)


def _pg_driver(url: str) -> str:
    """``postgresql://`` with whichever driver is installed (SQLAlchemy 2.1 defaults to psycopg 3,
    earlier versions to psycopg2)."""
    if not url.startswith(("postgresql://", "postgres://")):
        return url
    import importlib.util

    rest = url.split("://", 1)[1]
    if importlib.util.find_spec("psycopg") is None and importlib.util.find_spec("psycopg2") is not None:
        return f"postgresql+psycopg2://{rest}"
    return f"postgresql://{rest}"


def _retry_callback():
    try:
        from optuna.storages import RetryHeartbeatStaleTrialCallback as cb
    except ImportError:
        from optuna.storages import RetryFailedTrialCallback as cb
    return cb


def make_sampler(setup: dict[str, Any], index: int, n_existing: int):
    optuna = _optuna()
    seed = None if setup["seed"] is None else setup["seed"] + 1009 * index + n_existing
    if setup["sampler"] == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    return optuna.samplers.TPESampler(seed=seed)


def make_pruner(setup: dict[str, Any]):
    optuna = _optuna()
    if setup["pruner"] == "median":
        return optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=setup["steps"] // 4)
    if setup["pruner"] == "hyperband":
        return optuna.pruners.HyperbandPruner(min_resource=setup["eval_every"], max_resource=setup["steps"], reduction_factor=3)
    return optuna.pruners.NopPruner()


def open_study(setup: dict[str, Any], create: bool, storage=None):
    """The study of ``setup`` (created when ``create`` and absent) on ``storage`` (default: a new one from setup)."""
    optuna = _optuna()
    storage = storage if storage is not None else make_storage(setup)
    try:
        if create:
            study = optuna.create_study(study_name=setup["study"], storage=storage, direction="maximize",
                                        load_if_exists=True)
        else:
            study = optuna.load_study(study_name=setup["study"], storage=storage)
    except KeyError:
        raise ConfigError(f"no study {setup['study']!r} in {setup['storage']}") from None
    ident = study.user_attrs
    if ident.get("algo", setup["algo"]) != setup["algo"] or ident.get("env", setup["env"]) != setup["env"]:
        raise ConfigError(f"study {setup['study']!r} tunes {ident.get('algo')} on {ident.get('env')}, not "
                          f"{setup['algo']} on {setup['env']}; choose another study=")
    if create and "algo" not in ident:
        study.set_user_attr("algo", setup["algo"])
        study.set_user_attr("env", setup["env"])
        study.set_user_attr("fixed_config", setup["fixed_config"])
    return study


def finished(study) -> int:
    from optuna.trial import TrialState

    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


# --------------------------------------------------------------------------------------- trials


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a killed child its parent has not reaped yet
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def frozen_trial(study, number: int):
    """The stored (frozen) trial ``number`` of ``study``."""
    return next(t for t in study.get_trials(deepcopy=False) if t.number == number)


def fail_dead_local_trials(study, storage) -> list[int]:
    """RUNNING trials started on this host by a process that no longer exists: mark them FAILED and
    enqueue a retry (the journal file's stand-in for an RDB's heartbeat). Returns their numbers."""
    from optuna.trial import TrialState

    host, out = socket.gethostname(), []
    if isinstance(storage, _optuna().storages.RDBStorage):
        return out  # an RDB with heartbeats: Optuna fails stale trials itself (fail_stale_trials)
    cls = _retry_callback()
    retry = cls(MAX_RETRY, inherit_intermediate_values=True)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        h, _, pid = str(t.user_attrs.get("worker", "")).rpartition(":")
        if h != host or not pid.isdigit() or _alive(int(pid)):
            continue
        study.tell(t.number, state=TrialState.FAIL, skip_if_finished=True)
        retried = {cls.retried_trial_number(x) for x in study.get_trials(deepcopy=False)}
        failed = frozen_trial(study, t.number)
        if failed.state == TrialState.FAIL and t.number not in retried:  # not finished or retried meanwhile
            retry(study, failed)
            out.append(t.number)
    return out


def retry_interrupted_trials(study) -> list[int]:
    """Trials stopped by Ctrl-C / SIGTERM (FAILED with the ``interrupted`` mark) that have no retry yet: enqueue one
    with the same parameters, which resumes in the interrupted trial's directory. Returns their numbers."""
    from optuna.trial import TrialState

    cls = _retry_callback()
    retry = cls(MAX_RETRY, inherit_intermediate_values=True)
    trials = study.get_trials(deepcopy=False)
    retried = {cls.retried_trial_number(t) for t in trials} - {None}
    out = []
    for t in trials:
        if t.state == TrialState.FAIL and t.user_attrs.get("interrupted") and t.number not in retried:
            retry(study, t)
            out.append(t.number)
    return out


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


def _objective(setup: dict[str, Any], threads: int | None):
    optuna = _optuna()
    from harness.results import write_status
    from harness.runner import build_plan, run_group

    retry_cls = _retry_callback()

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
    optuna = _optuna()
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
    study.optimize(_objective(setup, threads), n_trials=remaining, catch=(TrialRunError,),
                   callbacks=[MaxTrialsCallback(setup["trials"], states=(TrialState.COMPLETE, TrialState.PRUNED))])
    return len(study.trials) - before


# ------------------------------------------------------------------------------------------ CLI


def summary(study) -> str:
    from optuna.trial import TrialState

    counts = {s.name.lower(): len(study.get_trials(deepcopy=False, states=(s,)))
              for s in (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL, TrialState.RUNNING, TrialState.WAITING)}
    line = ", ".join(f"{n} {k}" for k, n in counts.items() if n)
    return f"study {study.study_name}: {len(study.trials)} trial(s) ({line or 'none'})"


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

