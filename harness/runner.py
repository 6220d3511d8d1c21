"""``harness run``: resolve a suite (or an ad-hoc set) into run groups and execute them.

Overrides (``key=value``): ``suite``, ``algo``/``algos``, ``env``/``envs``, ``seeds`` (a count or a
comma list), ``steps``, ``eval_every``, ``eval_episodes``, ``checkpoint_every``, ``members`` (E, seeds
trained in lockstep by one process), ``workers`` (parallel processes, default: cores), ``device``,
``results`` (directory), ``backend`` (``local``: a process pool, the default; ``ray``: one Ray task per
group, see ``harness/backends.py``), ``ray_address`` (``auto`` or ``HOST:PORT``; default: start a local
Ray instance), and algorithm config as ``<algo>.<key>=value`` or ``all.<key>=value``.

Everything is validated before anything is written; re-running the same command resumes every
unfinished run from its checkpoint and skips finished ones.
"""

from __future__ import annotations

import importlib.metadata
import math
import os
import shlex
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from algorithms.core.sac import UPDATES
from harness.backends import keep_freed_memory
from harness.envs import ENVS, UnknownEnvError, check_env, demos_record, env_info, load_env_demos
from harness.packing import Machine, Work, pack
from harness.plan import Plan, RunSpec
from harness.suites import (
    ConfigError,
    as_plain,
    check_all_keys,
    check_name,
    config_hash,
    load_suite,
    resolve_algo_config,
)
from harness.words import boolean, names, parse_words
from harness.words import integer as _int

#: every key=value word of ``harness run``: (default, meaning); ``harness run --help`` prints this table
RUN_KEYS: dict[str, tuple[str, str]] = {
    "suite": ("-", "a suite in suites/ or a path to a suite YAML (its name names the results directory)"),
    "algo": ("-", "algorithm(s), comma-separated (ad hoc; with a suite of cells: selects cells)"),
    "algos": ("-", "same as algo"),
    "env": ("-", f"env(s), comma-separated: {', '.join(ENVS)}"),
    "envs": ("-", "same as env"),
    "seeds": ("1", "a count (seeds 0..n-1) or a comma list of distinct seeds (one seed: 7, or [7])"),
    "steps": ("/".join(f"{e.default_steps / 1e6:g}M" for e in ENVS.values()) + " per env", "training steps per run"),
    "eval_every": ("10000", "steps between deployed-policy evaluations"),
    "eval_episodes": ("10", "episodes per evaluation"),
    "checkpoint_every": ("50000", "steps between checkpoints (a multiple of eval_every; by default the first one from "
                                  "50000 on)"),
    "keep_every": ("0", "also keep the checkpoints at multiples of it (checkpoint-<step>.pt; each a full checkpoint)"),
    "log_every": ("1000", "steps between training-diagnostics rows in train.parquet (divides eval_every; default: the "
                          "largest divisor of eval_every up to 1000)"),
    "members": ("1 (cells: the cell's seeds; cuda: a cell's seeds, <= 128)", "seeds trained in lockstep by one process"),
    "workers": ("cores (cuda: what the GPUs' memory and the cores hold)", "processes running groups in parallel"),
    "device": ("cpu", "torch device, e.g. cpu or cuda:0"),
    "results": ("results", "results directory"),
    "backend": ("local", "local (a process pool) or ray (one Ray task per group)"),
    "ray_address": ("start one", "Ray cluster to join (auto or HOST:PORT), with backend=ray"),
    "env_workers": ("0 (cuda: spare cores)", "worker processes stepping the member envs of each group (0: in the group's process; "
                         "for many seeds per process, e.g. on a GPU)"),
    "update": ("default; a run resuming from its checkpoint: the mode it last ran with",
               "SAC updates: default (per-member kernels; E seeds per process bitwise equal E single-seed runs), "
               "static (one fixed kernel sequence, equal within rounding), compiled (static + torch.compile; CUDA "
               "graphs on a GPU); a run resumes bit for bit only in the mode it ran with"),
    "logger": ("parquet", "parquet, or tensorboard: the same rows also as TensorBoard events in each run's "
                          "tensorboard/ directory (pip install tensorboard)"),
    "calibrate": ("true", "with --dry-run: measure the speed of each kind of group not measured yet on this machine "
                          "(seconds each, cached) for the time estimate"),
}
#: what a run can hold: one replay row per step (capacity <= 1e9), seeds as 31-bit integers
MAX_STEPS, MAX_SEEDS, MAX_SEED, MAX_MEMBERS, MAX_EPISODES, MAX_WORKERS = 10**9, 1000, 2**31 - 1, 1024, 10_000, 1024
BACKENDS = ("local", "ray")
LOGGERS = ("parquet", "tensorboard")
DEFAULT_STEPS = {name: e.default_steps for name, e in ENVS.items()}  # each env's EnvInfo.default_steps
PACKAGES = ("torch", "numpy", "gymnasium", "mujoco", "metaworld", "pandas", "pyarrow", "earl-harness")


def parse_seeds(v: Any) -> list[int]:
    """``seeds=``: a count n (seeds 0..n-1) or a list of distinct seeds: a YAML list, or on the command line
    ``0,3,7``, ``[0,3,7]``, and for one seed ``7,`` or ``[7]``."""
    raw = v
    if isinstance(v, str) and ("," in v or v.startswith("[")):
        v = v.removeprefix("[").removesuffix("]").split(",")
        if not v[-1].strip():  # "7," is the list [7], "[]" the empty list
            v = v[:-1]
    if isinstance(v, (list, tuple)):
        if not v:
            raise ConfigError("seeds is an empty list")
        seeds = [_int("seeds", x, 0, MAX_SEED) for x in v]
        if len(set(seeds)) != len(seeds):
            raise ConfigError(f"seeds must be distinct, got {raw!r}")
        if len(seeds) > MAX_SEEDS:
            raise ConfigError(f"at most {MAX_SEEDS} seeds per run command, got {len(seeds)}")
        return seeds
    return list(range(_int("seeds", v, 1, MAX_SEEDS)))


def check_device(v: str, local: bool = True) -> str:
    """A torch device name; with ``local``, CUDA must be available here (a Ray cluster's GPUs need not be visible
    from the driver)."""
    try:
        dev = torch.device(v)
    except RuntimeError:
        raise ConfigError(f"device must be a torch device such as cpu or cuda:0, got {v!r}") from None
    if local and dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {v!r} requested but CUDA is not available on this machine")
    return v


def git_sha(root: Path | None = None) -> str:
    """HEAD's SHA, with ``-dirty`` when tracked files differ from it (the results then come from code that
    no commit holds); ``unknown`` outside a git checkout, e.g. an installed wheel."""
    root = root or Path(__file__).resolve().parent.parent
    try:
        git = ["git", "-C", str(root)]
        sha = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5).stdout.strip()
        if not sha:
            return "unknown"
        dirty = subprocess.run([*git, "diff", "--quiet", "HEAD", "--"], capture_output=True, timeout=5).returncode == 1
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def package_versions() -> dict[str, str]:
    out = {}
    for p in PACKAGES:
        try:
            out[p] = importlib.metadata.version(p)
        except importlib.metadata.PackageNotFoundError:
            out[p] = "absent"
    return out


@dataclass(frozen=True)
class Unit:
    """What one (env, method) of a suite asks for; ``name`` is the method's name in results (a cell's variant name,
    else the algorithm), ``algo_class`` its registry key, ``config`` a cell's own config overrides."""

    env: str
    name: str
    algo_class: str
    steps: int
    seeds: list[int]
    members: int | None  # the suite's or cell's own value (None: harness.packing chooses)
    config: dict[str, Any]
    cpu_members: int = 1  # a CPU run's members when nothing is given (cells: the cell's seeds)


@dataclass(frozen=True)
class RunRequest:
    """What a ``harness run`` command asks for, parsed once from its words (:meth:`from_words`), or built directly
    (``harness tune`` makes one per trial from the sampled parameters). ``None``: the suite's value (or the default).
    ``config`` holds algorithm settings by scope (``{"all" | algo: {key: value}}``); ``study``/``trial`` mark a tuning
    trial (its runs go under the suite ``tune_<study>`` and carry both in their metadata)."""

    suite: str | None = None
    algos: tuple[str, ...] = ()
    envs: tuple[str, ...] = ()
    seeds: tuple[int, ...] | None = None
    steps: int | None = None
    eval_every: int | None = None
    eval_episodes: int | None = None
    checkpoint_every: int | None = None
    keep_every: int | None = None
    log_every: int | None = None
    members: int | None = None
    workers: int | None = None
    device: str = "cpu"
    results: str = "results"
    backend: str = "local"
    ray_address: str | None = None
    calibrate: bool = True
    logger: str = "parquet"
    env_workers: int | None = None
    update: str | None = None  # None: the mode the runs last ran with (resumed_update), else default
    config: dict[str, dict[str, Any]] = field(default_factory=dict)
    study: str | None = None
    trial: int | None = None

    @classmethod
    def from_words(cls, words: list[str]) -> "RunRequest":
        """Parse and check the words of ``harness run`` (one line naming the first problem)."""
        from harness.registry import ALGORITHMS

        for w in words:  # name the unknown algorithm of an override, not just its scope
            if "=" not in w:
                continue  # parse_words names it
            scope = w.split("=", 1)[0].split(".", 1)[0] if "." in w.split("=", 1)[0] else None
            if scope is not None and scope != "all" and scope not in ALGORITHMS:
                raise ConfigError(f"unknown algorithm {scope!r} in override {w!r}; known: {', '.join(ALGORITHMS)}")
        ov, config = parse_words(words, RUN_KEYS, scope=lambda s: s == "all" or s in ALGORITHMS)
        for a, b in (("algo", "algos"), ("env", "envs")):
            if a in ov and b in ov:
                raise ConfigError(f"give {a}= or {b}=, not both")
        backend = ov.get("backend", "local")
        if backend not in BACKENDS:
            raise ConfigError(f"unknown backend {backend!r}; known backends: {', '.join(BACKENDS)}")
        if "ray_address" in ov and backend != "ray":
            raise ConfigError("ray_address is only used with backend=ray")
        device = check_device(ov.get("device", "cpu"), local=not (backend == "ray" and ov.get("ray_address")))

        update = ov.get("update")
        if update is not None and update not in UPDATES:
            raise ConfigError(f"unknown update {update!r}; known: {', '.join(UPDATES)}")
        logger = ov.get("logger", "parquet")
        if logger not in LOGGERS:
            raise ConfigError(f"unknown logger {logger!r}; known: {', '.join(LOGGERS)}")
        if logger == "tensorboard":
            from harness.tensorboard import check_available

            check_available()

        def opt(key: str, lo: int, hi: int) -> int | None:
            return _int(key, ov[key], lo, hi) if key in ov else None

        for key in ("results", "suite", "device", "backend"):
            if key in ov and not str(ov[key]).strip():
                raise ConfigError(f"{key}= is empty: give a value (or leave {key} out for its default)")
        return cls(
            suite=ov.get("suite"), algos=tuple(names("algo", ov.get("algos") or ov.get("algo") or [])),
            envs=tuple(names("env", ov.get("envs") or ov.get("env") or [])),
            seeds=tuple(parse_seeds(ov["seeds"])) if "seeds" in ov else None, steps=opt("steps", 1, MAX_STEPS),
            eval_every=opt("eval_every", 1, MAX_STEPS), eval_episodes=opt("eval_episodes", 1, MAX_EPISODES),
            checkpoint_every=opt("checkpoint_every", 1, MAX_STEPS),
            keep_every=opt("keep_every", 0, MAX_STEPS), log_every=opt("log_every", 1, MAX_STEPS),
            members=opt("members", 1, MAX_MEMBERS), workers=opt("workers", 1, MAX_WORKERS), device=device,
            results=ov.get("results", "results"), backend=backend, ray_address=ov.get("ray_address"),
            calibrate=boolean("calibrate", ov.get("calibrate", "true")), logger=logger, config=config,
            env_workers=opt("env_workers", 0, MAX_WORKERS), update=update,
        )


def _check_envs_algos(envs: list[str], algos: list[str]) -> None:
    from harness.registry import ALGORITHMS

    for e in envs:
        try:
            check_env(e)  # unknown, never released, or its optional simulator not installed: one line
        except UnknownEnvError as err:
            raise ConfigError(str(err)) from None
    unknown = [a for a in algos if a not in ALGORITHMS]
    if unknown:
        raise ConfigError(f"unknown algorithm(s) {unknown}; known: {', '.join(ALGORITHMS)}")


def _product_units(suite: dict[str, Any], req: RunRequest) -> list[Unit]:
    """Every algorithm x every env of a suite (or of the ad-hoc ``algo=``/``env=`` words), one budget per env."""
    algos = list(req.algos) or names("algo", suite.get("algos") or [])
    envs = list(req.envs) or names("env", suite.get("envs") or [])
    _check_envs_algos(envs, algos)
    seeds = list(req.seeds) if req.seeds is not None else parse_seeds(suite.get("seeds", 1))
    members = _int("members", suite["members"], 1, MAX_MEMBERS) if "members" in suite else None
    steps_cfg = req.steps if req.steps is not None else suite.get("steps", DEFAULT_STEPS)
    units = []
    for env in envs:
        if isinstance(steps_cfg, dict):
            if env not in steps_cfg:
                raise ConfigError(f"suite gives no step budget for env {env!r}")
            steps = _int(f"steps[{env}]", steps_cfg[env], 1, MAX_STEPS)
        else:
            steps = _int("steps", steps_cfg, 1, MAX_STEPS)
        units += [Unit(env, a, a, steps, seeds, members, {}) for a in algos]
    return units


CELL_KEYS = {"algo", "env", "steps", "seeds", "members", "name", "config", "checks"}


def _cell_units(suite: dict[str, Any], req: RunRequest) -> list[Unit]:
    """A suite of ``cells`` (each its own algorithm, env, budget and seeds); ``algo=``/``env=`` select cells: an
    ``algo=`` word that is a cell's name selects the cells of that name, any other word every cell of that algorithm
    (``algo=vaprl_risc`` in the VaPRL ablation is its one base cell, ``algo=vaprl`` every variant built on ``vaprl``);
    ``seeds=``/``steps=`` replace every cell's."""
    cells = suite["cells"]
    if not isinstance(cells, list) or not cells:
        raise ConfigError("suite key 'cells' must be a non-empty list of {algo, env, steps, ...} mappings")
    names = {str(c.get("name") or c.get("algo")) for c in cells if isinstance(c, dict)}
    pick_names = set(req.algos) & names
    pick_algos, pick_envs = set(req.algos) - pick_names, set(req.envs)
    units, seen = [], set()
    for n, c in enumerate(cells):
        where = f"cell {n + 1} of suite 'cells'"
        if not isinstance(c, dict) or not {"algo", "env", "steps"} <= set(c):
            raise ConfigError(f"{where} must be a mapping with at least algo, env and steps")
        if set(c) - CELL_KEYS:
            raise ConfigError(f"unknown key(s) {sorted(set(c) - CELL_KEYS)} in {where}; known: {sorted(CELL_KEYS)}")
        algo, env, name = str(c["algo"]), str(c["env"]), str(c.get("name") or c["algo"])
        _check_envs_algos([env], [algo])
        check_name(f"{where}:", name)
        if (env, name) in seen:
            raise ConfigError(f"{where}: two cells run {name!r} on {env!r}; give one a distinct name")
        seen.add((env, name))
        config = c.get("config") or {}
        if not isinstance(config, dict):
            raise ConfigError(f"{where}: config must map keys of {algo!r} to values")
        if (pick_names or pick_algos) and not (name in pick_names or algo in pick_algos) or (
                pick_envs and env not in pick_envs):
            continue
        seeds = list(req.seeds) if req.seeds is not None else parse_seeds(c.get("seeds", suite.get("seeds", 1)))
        steps = req.steps if req.steps is not None else _int(f"steps of {where}", c["steps"], 1, MAX_STEPS)
        given = c.get("members", suite.get("members"))
        members = None if given is None else _int(f"members of {where}", given, 1, MAX_MEMBERS)
        units.append(Unit(env, name, algo, steps, seeds, members, dict(config), cpu_members=len(seeds)))
    if not units:
        raise ConfigError(f"no cell of the suite matches algo={','.join(sorted(req.algos)) or '*'} "
                          f"env={','.join(sorted(pick_envs)) or '*'}")
    return units


def check_demos_needed(name: str, cls, cfg, env: str) -> None:
    """:class:`ConfigError` (one line) when algorithm ``cls`` with ``cfg`` needs demonstrations (``requires_demos``)
    and ``env`` declares it has none (``EnvInfo.demos``)."""
    from harness.registry import ALGORITHMS

    if env_info(env).demos or not cls.requires_demos(cfg):
        return
    able = [a for a, c in ALGORITHMS.items() if not c.requires_demos(c.Config())]
    raise ConfigError(f"algo={name} needs demonstrations and env={env} has none (EARL ships none for it); "
                      f"algorithms that run without demonstrations: {', '.join(able)}")


def check_task_reward(name: str, cls, env: str) -> None:
    """:class:`ConfigError` (one line) when ``env`` declares a dense reward (``EnvSpec.reward_fn``: EARL trained on it)
    and algorithm ``cls`` learns from 1[success] instead (``task_reward`` False)."""
    from harness.registry import ALGORITHMS

    info = env_info(env)
    if info.spec.reward_fn is None or cls.task_reward:
        return
    able = [a for a, c in ALGORITHMS.items() if c.task_reward and (info.demos or not c.requires_demos(c.Config()))]
    raise ConfigError(f"algo={name} learns from 1[success] and env={env}'s reward is dense (EARL trained on it); "
                      f"algorithms that learn from it: {', '.join(able)}")


def check_goal_shape(name: str, cls, env: str) -> None:
    """:class:`ConfigError` (one line) when algorithm ``cls`` writes states into the goal (``state_goals``) and
    ``env``'s goal is only some of its state coordinates (``EnvSpec.goal_idx``: minitaur's base xy)."""
    from harness.registry import ALGORITHMS

    info = env_info(env)
    spec = info.spec
    if spec.goal_dim == spec.state_dim or not cls.state_goals:
        return
    able = [a for a, c in ALGORITHMS.items() if not c.state_goals and (info.demos or not c.requires_demos(c.Config()))]
    raise ConfigError(f"algo={name} sets states as goals and env={env}'s goal is {spec.goal_dim} of its "
                      f"{spec.state_dim} state coordinates; algorithms that run on it: {', '.join(able)}")


def build_plan(req: RunRequest) -> Plan:
    """Resolve a request into run groups, checking everything (suite, algorithms, envs, configs, data, results
    directories); nothing is written. :func:`plan_words` does it for the words of a command."""
    from harness.registry import ALGORITHMS

    if req.backend not in BACKENDS:
        raise ConfigError(f"unknown backend {req.backend!r}; known backends: {', '.join(BACKENDS)}")
    if req.logger not in LOGGERS:
        raise ConfigError(f"unknown logger {req.logger!r}; known: {', '.join(LOGGERS)}")
    if req.suite is not None:
        suite_name, suite = load_suite(req.suite)
    else:
        if not req.algos or not req.envs:
            raise ConfigError("give suite=NAME, or algo=... and env=... for an ad-hoc run")
        suite_name, suite = "adhoc", {}
    if req.study is not None:
        suite_name = f"tune_{req.study}"

    def value(key: str, default: int, hi: int) -> int:
        given = getattr(req, key)
        return _int(key, given if given is not None else suite.get(key, default), 1, hi)

    eval_every, eval_episodes = value("eval_every", 10_000, MAX_STEPS), value("eval_episodes", 10, MAX_EPISODES)
    # defaults follow the user's eval_every, so that no key the user never set can reject what they did set: a
    # checkpoint at the first evaluation from 50k on, a diagnostics row at the largest divisor of eval_every <= 1000
    ckpt = value("checkpoint_every", -(-50_000 // eval_every) * eval_every, MAX_STEPS)
    if ckpt % eval_every:
        raise ConfigError(f"checkpoint_every ({ckpt}) must be a multiple of eval_every ({eval_every})")
    keep = _int("keep_every", req.keep_every if req.keep_every is not None else suite.get("keep_every", 0), 0,
                MAX_STEPS)
    if keep % ckpt:
        raise ConfigError(f"keep_every ({keep}) must be a multiple of checkpoint_every ({ckpt})")
    divisor = next(d for d in range(min(1000, eval_every), 0, -1) if eval_every % d == 0)
    # a row every eval_every steps where eval_every has no divisor from 100 to 1000 (a prime above 1000, say)
    log_every = value("log_every", divisor if divisor >= min(100, eval_every) else eval_every, MAX_STEPS)
    if eval_every % log_every:
        raise ConfigError(f"log_every ({log_every}) must divide eval_every ({eval_every})")
    suite_cfg = suite.get("config") or {}
    if not isinstance(suite_cfg, dict):
        raise ConfigError("suite key 'config' must map algorithm names (or 'all') to settings")

    units = (_cell_units if "cells" in suite else _product_units)(suite, req)
    selected = {u.algo_class for u in units}
    stray = sorted(set(req.config) - selected - {"all"})
    if stray:
        raise ConfigError(f"override(s) for {', '.join(stray)} match no selected algorithm "
                          f"(selected: {', '.join(sorted(selected)) or 'none'})")
    check_all_keys([ALGORITHMS[u.algo_class].Config for u in units], suite_cfg, req.config)
    protocol = {"eval_every": eval_every, "eval_episodes": eval_episodes}
    sha = git_sha()
    machine = Machine.detect()
    packing = pack([Work(len(u.seeds), u.steps, env_info(u.env).spec.obs_dim, env_info(u.env).spec.act_dim, u.members,
                         u.cpu_members) for u in units], req.device, machine, req.members, req.workers, req.env_workers)
    groups: list[RunSpec] = []
    for u, members in zip(units, packing.members):
        cls = ALGORITHMS[u.algo_class]
        cell_layer = {u.algo_class: u.config} if u.config else {}
        cfg = resolve_algo_config(cls.Config, u.algo_class, u.env, suite_cfg, cell_layer, req.config)
        check_goal_shape(u.name, cls, u.env)  # first: its list of what runs also leaves out what needs demos
        check_demos_needed(u.name, cls, cfg, u.env)
        check_task_reward(u.name, cls, u.env)
        try:
            cls.check_task(cfg, env_info(u.env).spec)
        except ValueError as e:
            raise ConfigError(f"{u.name} on {u.env}: {e}") from None
        fwd = load_env_demos(u.env, "forward")  # fails early, with one line, if the data is missing
        cfg_plain = as_plain(cfg)
        ident = {"env": u.env, "algo": u.name, "config": cfg_plain, "protocol": protocol, "demos": fwd.source}
        if u.name != u.algo_class:
            ident["algo_class"] = u.algo_class
        h = config_hash(ident)
        groups += [RunSpec(suite=suite_name, env=u.env, algo=u.name, algo_class=u.algo_class,
                           seeds=tuple(u.seeds[i : i + members]), steps=u.steps, eval_every=eval_every,
                           eval_episodes=eval_episodes, checkpoint_every=ckpt, keep_every=keep, log_every=log_every,
                           device=packing.device_of(len(groups) + n), results=req.results, config=cfg_plain,
                           config_hash=h, demo_source=fwd.source, git_sha=sha, study=req.study, trial=req.trial,
                           tensorboard=req.logger == "tensorboard", env_workers=packing.env_workers,
                           update=req.update or "default")
                   for n, i in enumerate(range(0, len(u.seeds), members))]
    if req.update is None:
        groups = [replace(g, update=resumed_update(g)) for g in groups]
    plan = Plan(suite_name, run_order(groups), workers=packing.workers, backend=req.backend,
                ray_address=req.ray_address, calibrate=req.calibrate, machine=machine.describe(),
                packing=packing.reasons, per_device=packing.per_device)
    check_results_dirs(plan)
    return plan


def plan_words(words: list[str]) -> Plan:
    """The plan of a ``harness run`` command's words."""
    return build_plan(RunRequest.from_words(words))


def only_gained_keys(old: dict[str, Any], new: dict[str, Any]) -> bool:
    """True when ``new`` keeps every key of ``old`` with the same value and only adds keys.

    Project rule (README, Results): a config key added to an algorithm defaults to the behaviour the code had
    before it existed, so a run started before the key was added resumes under the new code unchanged."""
    return all(k in new and new[k] == v for k, v in old.items())


def resumed_update(g: RunSpec) -> str:
    """The update mode a group runs with when ``update=`` is not given: for a group that resumes from its checkpoint,
    the one mode its runs last ran with, else ``default``. So the command that started a run resumes it bit for bit,
    whatever mode it chose, and a run that starts from 0 starts in ``default``."""
    from harness.results import RUN_FILE

    if not g.checkpoint_path().exists():
        return "default"
    modes = {read_run_record(d / RUN_FILE).get("update", "default") for d in g.member_dirs() if (d / RUN_FILE).exists()}
    return modes.pop() if len(modes) == 1 and modes <= set(UPDATES) else "default"


def _done(d: Path, steps: int, status: dict[str, Any] | None = None) -> bool:
    """Whether the run in ``d`` (its ``status``, read if not given) finished ``steps`` or more: running it again
    trains nothing."""
    from harness.results import read_status

    st = (status if status is not None else read_status(d)) or {}
    return st.get("state") == "done" and int(st.get("step", 0)) >= steps


def check_results_dirs(plan: Plan) -> None:
    """Refuse to mix runs of a different config into an existing results directory (a config that only gained
    keys, at the defaults that keep the old behaviour, is the same config: see :func:`only_gained_keys`)."""
    from harness.results import RUN_FILE

    for g in plan.groups:
        for d in g.member_dirs():
            p = d / RUN_FILE
            _check_writable(d)
            if p.exists():
                old = read_run_record(p)
                done = _done(d, g.steps)  # a finished run does not train again: nothing to note
                if old.get("update", "default") != g.update and not done and g.checkpoint_path().exists():
                    print(f"harness: note: {p.parent}: this run last ran with update={old.get('update', 'default')}, "
                          f"now update={g.update}: the curve goes on equal within float rounding, not bit for bit "
                          "(give the same update= to resume exactly)", file=sys.stderr)
                if old.get("config_hash") == g.config_hash:
                    continue
                same_protocol = all(old.get(k) == getattr(g, k) for k in ("eval_every", "eval_episodes", "demo_source"))
                if same_protocol and isinstance(old.get("config"), dict) and only_gained_keys(old["config"], g.config):
                    if not done:
                        print(f"harness: note: {p.parent}: the config gained key(s) "
                              f"{', '.join(sorted(set(g.config) - set(old['config'])))} since this run started; "
                              "resuming it under the new code", file=sys.stderr)
                    continue
                raise ConfigError(
                    f"{p.parent} holds a run with another config (hash {old.get('config_hash')} != "
                    f"{g.config_hash}); choose another results= directory or suite name"
                )


def _check_writable(d: Path) -> None:
    """The nearest existing directory of ``d`` must be writable (and ``d`` itself, if it exists)."""
    probe = d
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError(f"results directory {probe} is not writable (needed for {d}); choose another results=")


def read_run_record(p: Path) -> dict[str, Any]:
    """A run's ``run.yaml`` as a mapping, or a one-line error naming the file and the fix."""
    from harness.suites import read_yaml_text

    fix = "delete it (it is rewritten when the run starts; the run resumes from its checkpoint)"
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {p} ({getattr(e, 'strerror', None) or 'not UTF-8 text'}): {fix}") from None
    try:
        rec = read_yaml_text(text, str(p))
    except ConfigError as e:
        raise ConfigError(f"{e}: {fix}") from None
    if not isinstance(rec, dict) or not rec:
        what = "empty" if rec is None or rec == {} else f"a YAML {type(rec).__name__}, not a run record"
        raise ConfigError(f"{p} is {what}: {fix}")
    return rec


def run_group(spec: RunSpec, command: str, queue=None, threads: int | None = None, should_stop=None) -> str | None:
    """Run one group to completion (resuming if a checkpoint exists). Returns an error line or None.

    Holds the run directories' locks while it trains: raises :class:`~harness.interrupts.RunLocked` if another
    process holds one, and :class:`~harness.interrupts.RunInterrupted` after SIGINT/SIGTERM stopped it (statuses
    ``interrupted``; the last checkpoint is the resume point). ``should_stop`` (no arguments, called after every
    evaluation) ends the run early (tuning's pruner)."""
    from harness import interrupts
    from harness.interrupts import RunInterrupted, RunLocked, in_group, remove_stale_temp, run_locks
    from harness.results import update_status

    if threads:
        torch.set_num_threads(threads)
    keep_freed_memory()  # same results, fewer page faults per update
    dirs = spec.member_dirs()
    queue = queue if queue is not None else interrupts.progress_queue

    def say(msg: str) -> None:
        if queue is not None:
            queue.put(msg)
        else:
            print(msg, flush=True)

    try:
        with run_locks(dirs, spec.label), in_group():
            remove_stale_temp([*dirs, spec.checkpoint_path().parent])
            _train_group(spec, command, say, should_stop)
        return None
    except KeyboardInterrupt:
        for d in dirs:
            _try_status(update_status, d, state="interrupted", steps_per_s=0.0, eta_s=math.inf)
        raise RunInterrupted(spec.label) from None
    except RunLocked:
        raise
    except Exception as e:  # noqa: BLE001 - recorded per run, the suite goes on
        err = f"{type(e).__name__}: {' '.join(str(e).split())}"
        for d in dirs:
            _try_status(update_status, d, state="failed", steps_per_s=0.0, eta_s=math.inf, error=err,
                        traceback=traceback.format_exc())
        return f"{spec.label}: {err}"


def _try_status(write, d: Path, **fields: Any) -> None:
    """A status write that must not hide the error being reported (e.g. a read-only results directory)."""
    try:
        write(d, **fields)
    except OSError:
        pass


def _train_group(spec: RunSpec, command: str, say, should_stop) -> None:
    from algorithms.api import DemoSet
    from algorithms.core.sac import set_update_mode
    from harness.data import atomic_write_bytes
    from harness.envs import get_spec
    from harness.protocol import train
    from harness.registry import ALGORITHMS
    from harness.results import RUN_FILE

    meta = {
        "suite": spec.suite, "env": spec.env, "algo": spec.algo, "algo_class": spec.algo_class, "steps": spec.steps,
        "eval_every": spec.eval_every, "eval_episodes": spec.eval_episodes, "device": spec.device,
        "group_seeds": list(spec.seeds),
        "config": spec.config, "config_hash": spec.config_hash, "demo_source": spec.demo_source,
        **demos_record(spec.env), "command": command, "git_sha": spec.git_sha, "versions": package_versions(),
        "python": sys.version.split()[0], "update": spec.update,
    }
    # a finished run keeps the record of its run (unless it has none: a deleted run.yaml is written anew)
    if not all(_done(d, spec.steps) and (d / RUN_FILE).exists() for d in spec.member_dirs()):
        for d, s in zip(spec.member_dirs(), spec.seeds):
            atomic_write_bytes(d / RUN_FILE, yaml.safe_dump({**meta, "seed": s}, sort_keys=False).encode())
    cls = ALGORITHMS[spec.algo_class]
    demos = DemoSet(load_env_demos(spec.env, "forward"), load_env_demos(spec.env, "reverse"))
    algo = cls(get_spec(spec.env), demos, cls.Config.from_dict(spec.config), list(spec.seeds), torch.device(spec.device))
    set_update_mode(algo, spec.update)
    train(spec, algo, lambda p: say(progress_line(spec.label, p)), should_stop)


def _fmt_time(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(s)
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def progress_line(label: str, p) -> str:
    if p.resumed:
        return f"[{label}] resuming from the checkpoint at step {p.step:,} of {p.total:,}"
    succ = ",".join("-" if not np.isfinite(x) else f"{x:.2f}" for x in p.success)
    pct = 100.0 * p.step / max(p.total, 1)
    return (f"[{label}] {p.step:,}/{p.total:,} ({pct:.0f}%)  {p.steps_per_s:,.0f} steps/s  "
            f"ETA {_fmt_time(p.eta_s)}  success {succ}")


def steps_done(spec: RunSpec) -> int:
    """Env steps of the group (summed over its seeds) that a run would not redo: finished runs count in full,
    unfinished ones up to their last checkpoint (the latest multiple of ``checkpoint_every`` they reported), and
    runs that finished a smaller budget (``steps=`` raised since) up to the step they finished at (their final
    checkpoint), from where they go on."""
    from harness.results import read_status

    has_checkpoint = spec.checkpoint_path().exists()
    done = 0
    for d in spec.member_dirs():
        st = read_status(d) or {}
        step, finished = int(st.get("step", 0)), st.get("state") == "done"
        if _done(d, spec.steps, st):
            done += spec.steps
        elif has_checkpoint:  # a finished run's final checkpoint is at its last step, an unfinished one's on the grid
            resume_at = step if finished else step // spec.checkpoint_every * spec.checkpoint_every
            done += min(resume_at, spec.steps)
    return done


def run_order(groups: list[RunSpec]) -> list[RunSpec]:
    """The order the groups run in: first those that resume from a checkpoint (work in flight finishes before new
    work starts, so a machine that loses its checkpoints loses less), then the other groups of cells (env, method)
    that have begun (so begun cells reach their verdict), then the rest; suite order within each."""
    done = {id(g): steps_done(g) for g in groups}
    begun = {(g.env, g.algo) for g in groups if done[id(g)] > 0}

    def rank(g: RunSpec) -> int:
        if 0 < done[id(g)] < g.steps * len(g.seeds):
            return 0
        return 1 if (g.env, g.algo) in begun else 2

    return sorted(groups, key=rank)


def print_plan(plan: Plan, calibrate: bool = False) -> None:
    """The plan, and its time on this machine from measured speeds (``calibrate``: measure what is not cached yet,
    a few seconds per kind of group; see :mod:`harness.calibration`)."""
    from harness import calibration

    total = [g.steps * len(g.seeds) for g in plan.groups]
    done = [steps_done(g) for g in plan.groups]
    steps, left = sum(total), sum(total) - sum(done)
    print(f"suite {plan.suite}: {len(plan.groups)} group(s), {sum(len(g.seeds) for g in plan.groups)} run(s), "
          f"{steps:,} env steps in all" + (f" ({left:,} left to run; the rest is done or checkpointed)" if left < steps else "")
          + f", {plan.workers} worker(s)")
    if plan.machine:
        devices = sorted({g.device for g in plan.groups})
        print(f"packed for {plan.machine}: {plan.workers} process(es) at once on {', '.join(devices)}"
              + "".join(f"; {r}" for r in plan.packing))
    cores = os.cpu_count() or 1
    busy = min(plan.workers, len(plan.groups))
    if busy > cores and all(str(g.device).startswith("cpu") for g in plan.groups):
        print(f"harness: note: workers={plan.workers} starts {busy} processes on {cores} cores: they will share cores "
              f"and each run slower than one process per core (workers={cores})", file=sys.stderr)
    threads = calibration.worker_threads(plan.workers, str(plan.groups[0].device) if plan.groups else "cpu")
    todo = [i for i, (t, d) in enumerate(zip(total, done)) if d < t]
    rates = dict(zip(todo, calibration.rates([plan.groups[i] for i in todo], threads, calibrate)))
    for i, g in enumerate(plan.groups):
        speed = f"  {rates[i]:,.1f} steps/s per seed" if rates.get(i) else ""
        state = "  done" if done[i] == total[i] else f"  {done[i]:,} of {total[i]:,} steps done" if done[i] else ""
        mode = f"  update={g.update}" if g.update != "default" else ""
        print(f"  {g.env:<22} {g.algo:<12} seeds={','.join(map(str, g.seeds)):<10} steps={g.steps:,} "
              f"eval every {g.eval_every:,} x {g.eval_episodes}  config {g.config_hash}{mode}{speed}{state}")
    if any(rates[i] is None for i in todo):
        print("estimated time: not measured yet on this machine; `harness run ... --dry-run calibrate=true` (the "
              "default) measures each kind of group for a few seconds (cached)")
        return
    work = [((total[i] - done[i]) // len(plan.groups[i].seeds), rates[i]) for i in todo]
    est = calibration.estimate(work, plan.workers)
    print(f"estimated time: {_fmt_time(est)} on {plan.workers} worker(s) x {threads} thread(s), from speeds measured "
          f"on this machine (evaluations add ~3%; other load on the machine slows it)")


def run_cli(words: list[str], dry_run: bool = False) -> int:
    plan = plan_words(words)
    print_plan(plan, calibrate=dry_run and plan.calibrate)
    if dry_run or not plan.groups:
        return 0
    command = " ".join(["harness", "run", *map(shlex.quote, words)])
    t0 = time.time()
    from harness.backends import run_plan

    errors = run_plan(plan, command, run_group)
    print(f"done: {len(plan.groups) - len(errors)}/{len(plan.groups)} group(s) in {_fmt_time(time.time() - t0)}; "
          f"results in {plan.groups[0].results}")
    return 1 if errors else 0
