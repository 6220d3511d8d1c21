"""What a ``harness tune`` command asks for: its words, the search space, and each trial's run request."""

from __future__ import annotations

import json
import re
import shlex
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from harness.request import RUN_KEYS, RunRequest
from harness.suites import SUITES_DIR, ConfigError
from harness.words import did_you_mean, parse_words
from harness.words import integer as parse_int

#: every key=value word of ``harness tune``: a :class:`~harness.request.Key` (those it shares with ``harness run`` are
#: the run's own) or (default, meaning); ``harness tune --help`` prints this table
TUNE_KEY_HELP: dict[str, Any] = {
    "algo": ("-", "the algorithm to tune (its search space: suites/algorithms/<algo>_search.yaml)"),
    "env": ("-", "the env"),
    "trials": ("-", "finished trials (complete or pruned) the study should reach"),
    "study": ("<algo>_<env>", "study name"),
    "storage": ("<results>/tuning/<study>.journal", "journal file path or RDB URL (postgresql://..., sqlite:///...)"),
    "steps": RUN_KEYS["steps"],
    "seeds": ("1", "seeds per trial, a count or a list as in harness run (trained as members of one process)"),
    "seed": RUN_KEYS["seed"],
    "workers": ("1", "worker processes (or Ray tasks) on the same study"),
    "pruner": ("median", "median, hyperband or none"),
    "sampler": ("tpe", "tpe or random"),
    "sampler_seed": ("none", "the sampler's seed (same seed, same sequence of suggested parameters)"),
    "results": RUN_KEYS["results"],
    "backend": RUN_KEYS["backend"],
    "ray_address": RUN_KEYS["ray_address"],
    "search": ("suites/algorithms/<algo>_search.yaml", "search space file"),
    "heartbeat_interval": ("60", "RDB storage: seconds between trial heartbeats"),
    "grace_period": ("optuna's", "RDB storage: seconds before a silent trial counts as dead"),
    "eval_every": RUN_KEYS["eval_every"],
    "eval_episodes": RUN_KEYS["eval_episodes"],
    "checkpoint_every": RUN_KEYS["checkpoint_every"],
    "device": RUN_KEYS["device"],
}


TUNE_KEYS = set(TUNE_KEY_HELP)


PRUNERS = ("median", "hyperband", "none")


SAMPLERS = ("tpe", "random")


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


def trial_request(base: RunRequest, algo: str, params: dict[str, Any], results: str, trial: int | None = None) -> RunRequest:
    """The run request of one trial: the study's request with the sampled parameters on top of the fixed ones."""
    config = {**base.config, algo: {**base.config.get(algo, {}), **params}}
    return replace(base, config=config, results=results, trial=trial)


def parse_setup(words: list[str], best: bool = False) -> dict[str, Any]:
    """Validate the tune command's words into a plain (picklable) setup dict; nothing is written."""
    from harness.catalogue import algorithm_name, check_unscoped_settings
    from harness.envs import env_name
    from harness.planning import build_plan
    from harness.registry import ALGORITHMS
    from harness.request import check_device, parse_seeds
    from harness.runnable import unseen_by_workers

    check_unscoped_settings([w for w in words if "=" in w], TUNE_KEYS)
    ov, fixed_config = parse_words(words, TUNE_KEYS, scope=lambda s: True)

    def optional(key: str) -> int | None:
        return RUN_KEYS[key].parse(key, ov[key]) if key in ov else None

    algo = algorithm_name(ov.get("algo", "medal"))
    if algo not in ALGORITHMS:
        raise ConfigError(f"unknown algorithm {algo!r}{did_you_mean(algo, ALGORITHMS)}; known: {', '.join(ALGORITHMS)}")
    env = env_name(ov["env"]) if ov.get("env") else None
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
    if "seed" in ov and "seeds" in ov:
        raise ConfigError("give seed= or seeds=, not both")
    seeds = ov["seeds"] if "seeds" in ov else [str(ov["seed"]).strip("[] ")] if "seed" in ov else "1"
    setup["pruner"] = ov.get("pruner", "median")
    if setup["pruner"] not in PRUNERS:
        raise ConfigError(f"unknown pruner {setup['pruner']!r}; known: {', '.join(PRUNERS)}")
    setup["sampler"] = ov.get("sampler", "tpe")
    if setup["sampler"] not in SAMPLERS:
        raise ConfigError(f"unknown sampler {setup['sampler']!r}; known: {', '.join(SAMPLERS)}")
    setup["sampler_seed"] = parse_int("sampler_seed", ov["sampler_seed"], 0) if "sampler_seed" in ov else None
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
        steps=optional("steps"), eval_every=optional("eval_every"), eval_episodes=optional("eval_episodes"),
        checkpoint_every=optional("checkpoint_every"),
        device=check_device(ov.get("device", RUN_KEYS["device"].default), local=not ray_cluster),
        backend="ray" if ray_cluster else "local", ray_address=setup["ray_address"] if ray_cluster else None,
        config=fixed_config, study=study,
    )
    # validate everything (keys, values, data) with one plan of each extreme choice; nothing is written
    probe = str(Path(results) / "tuning" / study / ".validate")
    for pick in (0, -1):
        params = {k: (s["choices"][pick] if s["type"] == "categorical" else s["low"] if pick == 0 else s["high"])
                  for k, s in space.items()}
        plan = build_plan(trial_request(base, algo, params, probe))
    unseen = unseen_by_workers(plan.groups, setup["backend"])
    if unseen and (setup["workers"] > 1 or setup["backend"] == "ray"):
        raise ConfigError(f"{unseen}; tune with workers=1 (backend=local), or register it in the project's registry")
    g = plan.groups[0]
    setup.update(request=base, fixed_config=fixed_config, steps=g.steps, eval_every=g.eval_every,
                 seed_note=g.seed_phase_note())
    # what makes one trial's score comparable with another's: a study keeps it and refuses to go on under another
    # (the resolved config, the search space's keys left out: `all.lr=` and `medal.lr=`, `1e-3` and `0.001` are one)
    setup["protocol"] = json.loads(json.dumps(  # as a study keeps it (JSON): lists, not tuples
        {"steps": g.steps, "eval_every": g.eval_every, "eval_episodes": g.eval_episodes, "seeds": list(g.seeds),
         "config": {k: v for k, v in g.config.items() if k not in space}, "space": space}))
    setup["command"] = " ".join(["harness", "tune", *map(shlex.quote, words)])
    return setup

