"""Optuna studies of ``harness tune``: the storage (journal file or RDB), opening a study, and repairing trials whose
worker died or was interrupted (failed and retried with the same parameters, in the same directory)."""

from __future__ import annotations

import os
import socket
import sys
import warnings
from pathlib import Path
from typing import Any

from harness.suites import ConfigError

MAX_RETRY = 3


DEFAULT_HEARTBEAT = 60


def load_optuna():
    try:
        import optuna
    except ImportError:
        raise ConfigError("harness tune needs Optuna: pip install 'optuna>=4'") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings("ignore", category=FutureWarning, module="optuna")
    return optuna


def make_storage(setup: dict[str, Any]):
    """Optuna storage: a journal file (path) or an RDB URL with heartbeats and retried failed trials."""
    optuna = load_optuna()
    spec = setup["storage"]
    if is_rdb(spec):
        kw: dict[str, Any] = {"heartbeat_interval": setup["heartbeat_interval"] or DEFAULT_HEARTBEAT}
        if setup["grace_period"]:
            kw["grace_period"] = setup["grace_period"]
        try:
            from optuna.storages import RetryHeartbeatStaleTrialCallback  # optuna >= 4.9

            kw["heartbeat_stale_trial_callback"] = RetryHeartbeatStaleTrialCallback(MAX_RETRY, inherit_intermediate_values=True)
        except ImportError:
            kw["failed_trial_callback"] = optuna.storages.RetryFailedTrialCallback(MAX_RETRY, inherit_intermediate_values=True)
        spec = pg_driver(spec)
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


def is_rdb(spec: str) -> bool:
    """A storage spec names a database (a URL), not a journal file."""
    return "://" in spec


def pg_driver(url: str) -> str:
    """``postgresql://`` with whichever driver is installed (SQLAlchemy 2.1 defaults to psycopg 3,
    earlier versions to psycopg2)."""
    if not url.startswith(("postgresql://", "postgres://")):
        return url
    import importlib.util

    rest = url.split("://", 1)[1]
    if importlib.util.find_spec("psycopg") is None and importlib.util.find_spec("psycopg2") is not None:
        return f"postgresql+psycopg2://{rest}"
    return f"postgresql://{rest}"


def retry_callback_class():
    try:
        from optuna.storages import RetryHeartbeatStaleTrialCallback as cb
    except ImportError:
        from optuna.storages import RetryFailedTrialCallback as cb
    return cb


def open_study(setup: dict[str, Any], create: bool, storage=None):
    """The study of ``setup`` (created when ``create`` and absent) on ``storage`` (default: a new one from setup)."""
    optuna = load_optuna()
    if storage is None and not create and not is_rdb(setup["storage"]) and not Path(setup["storage"]).is_file():
        raise ConfigError(f"no study {setup['study']!r}: no journal file {setup['storage']}")  # and write none
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
    if create and "protocol" in setup:
        if "protocol" in ident:
            check_protocol(setup["study"], ident["protocol"], setup["protocol"])
        else:  # a new study, or one made before studies kept their settings: it keeps these from now on
            if study.trials:
                print(f"harness: note: study {setup['study']!r} has {len(study.trials)} trial(s) from before studies "
                      "kept their settings; this command's settings are kept as the study's from now on",
                      file=sys.stderr)
            study.set_user_attr("protocol", setup["protocol"])
    return study


def check_protocol(study: str, kept: dict[str, Any], given: dict[str, Any]) -> None:
    """Refuse to go on with a study under another budget, evaluation, seeds, config or search space than its trials
    were scored with (their scores would not be comparable), naming what changed. A config that only gained keys (at
    the defaults that keep the old behaviour, the project's rule) is the same; so is a key one side does not keep."""
    from harness.planning import only_gained_keys

    def differs(k: str) -> bool:
        return not only_gained_keys(kept[k], given[k]) if k == "config" else kept[k] != given[k]

    def change(k: str) -> str:
        if k == "config":
            keys = sorted(k2 for k2 in kept[k] if kept[k][k2] != given[k].get(k2))
            return ", ".join(f"{k2} {kept[k][k2]!r} -> {given[k].get(k2)!r}" for k2 in keys)
        return f"{k} {kept[k]!r} -> {given[k]!r}" if k == "space" else f"{k} {kept[k]} -> {given[k]}"

    changed = [change(k) for k in given if k in kept and differs(k)]
    if changed:
        raise ConfigError(f"study {study!r} was run with other settings ({'; '.join(changed)}): its trials would not "
                          "be comparable; give the study's settings again, or choose another study=")


def finished(study) -> int:
    from optuna.trial import TrialState

    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


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
    if isinstance(storage, load_optuna().storages.RDBStorage):
        return out  # an RDB with heartbeats: Optuna fails stale trials itself (fail_stale_trials)
    from optuna.exceptions import UpdateFinishedTrialError

    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        h, _, pid = str(t.user_attrs.get("worker", "")).rpartition(":")
        if h != host or not pid.isdigit() or _alive(int(pid)):
            continue
        try:  # only the process whose write fails the trial retries it
            study.tell(t.number, state=TrialState.FAIL)
        except (ValueError, RuntimeError, UpdateFinishedTrialError):
            continue  # finished, or failed by another worker, meanwhile
        _retry(study, frozen_trial(study, t.number))
        out.append(t.number)
    return out


def _retry(study, trial) -> None:
    """Queue a retry of ``trial`` with its parameters and intermediate values (it resumes in the same directory),
    without the marks of the process that ran it (``worker``, ``interrupted``)."""
    import copy

    clean = copy.deepcopy(trial)
    clean.user_attrs = {k: v for k, v in trial.user_attrs.items() if k not in ("worker", "interrupted")}
    retry_callback_class()(MAX_RETRY, inherit_intermediate_values=True)(study, clean)


def retried_numbers(trials) -> set[int]:
    """Every trial that has a retry (anywhere down a chain of retries of retries)."""
    cls = retry_callback_class()
    return {n for t in trials for n in cls.retry_history(t)}


def retry_interrupted_trials(study) -> list[int]:
    """Trials stopped by Ctrl-C / SIGTERM (FAILED with the ``interrupted`` mark) that have no retry yet: enqueue one
    with the same parameters, which resumes in the interrupted trial's directory. Returns their numbers."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    retried = retried_numbers(trials)
    out = []
    for t in trials:
        if t.state == TrialState.FAIL and t.user_attrs.get("interrupted") and t.number not in retried:
            _retry(study, t)
            out.append(t.number)
    return out


def summary(study) -> str:
    from optuna.trial import TrialState

    counts = {s.name.lower(): len(study.get_trials(deepcopy=False, states=(s,)))
              for s in (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL, TrialState.RUNNING, TrialState.WAITING)}
    line = ", ".join(f"{n} {k}" for k, n in counts.items() if n)
    return f"study {study.study_name}: {len(study.trials)} trial(s) ({line or 'none'})"

