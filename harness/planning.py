"""From a :class:`~harness.request.RunRequest` to a :class:`~harness.plan.Plan`: suite expansion (products of
algorithms and envs, or cells), the checks that an algorithm fits an env, the packing, config hashes, and the checks of
existing results directories (a different config is refused, a resumed run keeps its update mode). Nothing is
written; everything is checked before :mod:`harness.runner` starts a group."""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from algorithms.update_modes import UPDATES
from harness.envs import EnvUnavailableError, UnknownEnvError, check_env, env_info, env_name, load_env_demos
from harness.packing import Machine, Work, pack, seed_groups
from harness.plan import Plan, RunSpec
from harness.provenance import git_sha
from harness.request import (
    BACKENDS,
    DEFAULT_STEPS,
    LOGGERS,
    RUN_KEYS,
    RunRequest,
    parse_seeds,
)
from harness.runnable import CannotRunThere, check_runs_on, unseen_by_workers
from harness.suites import (
    ConfigError,
    as_plain,
    check_all_keys,
    check_name,
    config_hash,
    load_suite,
    resolve_algo_config,
)
from harness.words import did_you_mean, names


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



def _check_envs_algos(envs: list[str], algos: list[str]) -> None:
    from harness.catalogue import algorithm_names  # the names only: a bad word is answered before torch loads

    ALGORITHMS = algorithm_names()
    for e in envs:
        try:
            check_env(e)  # unknown, never released, or its optional simulator not installed: one line
        except UnknownEnvError as err:
            raise ConfigError(str(err)) from None
    unknown = [a for a in algos if a not in ALGORITHMS]
    if unknown:
        raise ConfigError(f"unknown algorithm(s) {unknown}{did_you_mean(unknown[0], ALGORITHMS)}; known: "
                          f"{', '.join(ALGORITHMS)}")


def _product_units(suite: dict[str, Any], req: RunRequest, left_out: list[str]) -> list[Unit]:
    """Every algorithm x every env of a suite (or of the ad-hoc ``algo=``/``env=`` words), one budget per env. A
    ``runnable_only`` suite leaves out an env that cannot be built here (minitaur without pybullet), noted in
    ``left_out``."""
    algos = list(req.algos) or names("algo", suite.get("algos") or [])
    envs = list(req.envs) or names("env", [env_name(e) for e in names("env", suite.get("envs") or [])])
    if suite.get("runnable_only"):
        for e in list(envs):
            try:
                check_env(e)
            except EnvUnavailableError as err:
                envs.remove(e)
                left_out.append(f"every algorithm on {e}: {err}")
            except UnknownEnvError:
                pass  # named by _check_envs_algos below
    _check_envs_algos(envs, algos)
    seeds = list(req.seeds) if req.seeds is not None else parse_seeds(suite.get("seeds", 1))
    members = RUN_KEYS["members"].parse("members", suite["members"]) if "members" in suite else None
    steps_cfg = req.steps if req.steps is not None else suite.get("steps", DEFAULT_STEPS)
    if isinstance(steps_cfg, dict):  # per env, its names as the envs' (any case, a gymnasium id, ...)
        steps_cfg = {env_name(str(e)): v for e, v in steps_cfg.items()}
    units = []
    for env in envs:
        if isinstance(steps_cfg, dict):
            if env not in steps_cfg:
                raise ConfigError(f"suite gives no step budget for env {env!r}")
            steps = RUN_KEYS["steps"].parse(f"steps[{env}]", steps_cfg[env])
        else:
            steps = RUN_KEYS["steps"].parse("steps", steps_cfg)
        units += [Unit(env, a, a, steps, seeds, members, {}) for a in algos]
    return units


CELL_KEYS = {"algo", "env", "steps", "seeds", "members", "name", "config", "checks", "widen"}


def _cell_units(suite: dict[str, Any], req: RunRequest, left_out: list[str]) -> list[Unit]:
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
        algo, env, name = str(c["algo"]), env_name(str(c["env"])), str(c.get("name") or c["algo"])
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
        steps = req.steps if req.steps is not None else RUN_KEYS["steps"].parse(f"steps of {where}", c["steps"])
        given = c.get("members", suite.get("members"))
        members = None if given is None else RUN_KEYS["members"].parse(f"members of {where}", given)
        units.append(Unit(env, name, algo, steps, seeds, members, dict(config), cpu_members=len(seeds)))
    if not units:
        raise ConfigError(f"no cell of the suite matches algo={','.join(sorted(req.algos)) or '*'} "
                          f"env={','.join(sorted(pick_envs)) or '*'}")
    return units


def build_plan(req: RunRequest) -> Plan:
    """Resolve a request into run groups, checking everything (suite, algorithms, envs, configs, data, results
    directories); nothing is written. :func:`plan_words` does it for the words of a command."""
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

    def value(key: str, default: int | None = None) -> int:
        """The command's value of an integer key, else the suite's, else ``default`` (the key's own by default)."""
        given = getattr(req, key)
        fallback = RUN_KEYS[key].default if default is None else default
        return RUN_KEYS[key].parse(key, given if given is not None else suite.get(key, fallback))

    eval_every, eval_episodes = value("eval_every"), value("eval_episodes")
    # defaults follow the user's eval_every, so that no key the user never set can reject what they did set: a
    # checkpoint at the first evaluation from 50k on, a diagnostics row at the largest divisor of eval_every <= 1000
    ckpt = value("checkpoint_every", -(-RUN_KEYS["checkpoint_every"].default // eval_every) * eval_every)
    if ckpt % eval_every:
        raise ConfigError(f"checkpoint_every ({ckpt}) must be a multiple of eval_every ({eval_every})")
    keep = value("keep_every")
    if keep % ckpt:
        raise ConfigError(f"keep_every ({keep}) must be a multiple of checkpoint_every ({ckpt})")
    most = RUN_KEYS["log_every"].default
    divisor = next(d for d in range(min(most, eval_every), 0, -1) if eval_every % d == 0)
    # a row every eval_every steps where eval_every has no divisor from 100 to 1000 (a prime above 1000, say)
    log_every = value("log_every", divisor if divisor >= min(100, eval_every) else eval_every)
    if eval_every % log_every:
        raise ConfigError(f"log_every ({log_every}) must divide eval_every ({eval_every})")
    suite_cfg = suite.get("config") or {}
    if not isinstance(suite_cfg, dict):
        raise ConfigError("suite key 'config' must map algorithm names (or 'all') to settings")

    left_out: list[str] = []
    units = (_cell_units if "cells" in suite else _product_units)(suite, req, left_out)
    from harness.registry import ALGORITHMS  # after the names are checked: a bad word is answered before torch loads
    from harness.results import checkpoint_path, run_dir

    selected = {u.algo_class for u in units}
    stray = sorted(set(req.config) - selected - {"all"})
    if stray:
        raise ConfigError(f"override(s) for {', '.join(stray)} match no selected algorithm "
                          f"(selected: {', '.join(sorted(selected)) or 'none'})")
    check_all_keys([ALGORITHMS[u.algo_class].Config for u in units], suite_cfg, req.config)
    configs = []
    for u in units:
        cls = ALGORITHMS[u.algo_class]
        cell_layer = {u.algo_class: u.config} if u.config else {}
        cfg = resolve_algo_config(cls.Config, u.algo_class, u.env, suite_cfg, cell_layer, req.config)
        try:
            check_runs_on(u.name, cls, cfg, u.env)
        except CannotRunThere as e:  # a setting that does not fit the env is an error even so
            if not suite.get("runnable_only"):
                raise
            left_out.append(f"{u.name} on {u.env}: {e.reason}")
            continue
        configs.append((u, cfg))
    if not configs:
        raise ConfigError(f"nothing to run: every selected algorithm is left out ({'; '.join(left_out)})")
    units = [u for u, _ in configs]
    protocol = {"eval_every": eval_every, "eval_episodes": eval_episodes}
    sha = git_sha()
    machine = Machine.detect()
    split = {u.name for u in units if ALGORITHMS[u.algo_class].phase_split_updates and u.cpu_members > 1}
    packing = pack([Work(len(u.seeds), u.steps, env_info(u.env).spec.obs_dim, env_info(u.env).spec.act_dim, u.members,
                         1 if u.name in split else u.cpu_members) for u in units],
                   req.device, machine, req.members, req.workers, req.env_workers)
    if split and not str(req.device).startswith("cuda") and req.members is None:
        packing = replace(packing, reasons=(*packing.reasons, f"one seed per process for {', '.join(sorted(split))}: a "
                                            "step updates only each seed's acting controller (a checkpointed group stays)"))
    groups: list[RunSpec] = []
    for (u, cfg), members in zip(configs, packing.members):
        fwd = load_env_demos(u.env, "forward")  # fails early, with one line, if the data is missing
        cfg_plain = as_plain(cfg)
        ident = {"env": u.env, "algo": u.name, "config": cfg_plain, "protocol": protocol, "demos": fwd.source}
        if u.name != u.algo_class:
            ident["algo_class"] = u.algo_class
        h = config_hash(ident)
        groups += [RunSpec(suite=suite_name, env=u.env, algo=u.name, algo_class=u.algo_class,
                           seeds=seeds, steps=u.steps, eval_every=eval_every,
                           eval_episodes=eval_episodes, checkpoint_every=ckpt, keep_every=keep, log_every=log_every,
                           device=packing.device_of(len(groups) + n), results=req.results, config=cfg_plain,
                           config_hash=h, demo_source=fwd.source, git_sha=sha, study=req.study, trial=req.trial,
                           tensorboard=req.logger == "tensorboard", env_workers=packing.env_workers,
                           update=req.update or "default")
                   for n, seeds in enumerate(seed_groups(u.seeds, members, checkpoint_path(
                       req.results, suite_name, u.env, u.name, [0]).parent.parent, {s for s in u.seeds if finished(
                           run_dir(req.results, suite_name, u.env, u.name, s), u.steps)}))]
    if req.update is None:
        groups = [replace(g, update=resumed_update(g)) for g in groups]
    workers, reasons = packing.workers, packing.reasons
    unseen = unseen_by_workers(groups, req.backend)
    if unseen and (workers > 1 or packing.env_workers or req.backend == "ray"):
        if req.backend == "ray" or req.workers not in (None, 1) or req.env_workers:
            raise ConfigError(f"{unseen}; run with workers=1 env_workers=0 (backend=local), or register it in "
                              "harness/registry.py / harness/envs/__init__.py")
        workers, groups = 1, [replace(g, env_workers=0) for g in groups]
        reasons = (*reasons, f"workers=1, env_workers=0: {unseen}")
    plan = Plan(suite_name, run_order(groups), workers=workers, backend=req.backend,
                ray_address=req.ray_address, calibrate=req.calibrate, machine=machine.describe(),
                packing=reasons, per_device=packing.per_device, left_out=tuple(left_out))
    check_results_dirs(plan)
    return plan


def plan_words(words: list[str]) -> Plan:
    """The plan of a ``harness run`` command's words."""
    return build_plan(RunRequest.from_words(words))


def only_gained_keys(old: dict[str, Any], new: dict[str, Any]) -> bool:
    """True when ``new`` keeps every key of ``old`` with the same value and only adds keys.

    Project rule (docs/running.md, Results): a config key added to an algorithm defaults to the behaviour the code had
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


def finished(d: Path, steps: int, status: dict[str, Any] | None = None) -> bool:
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
                done = finished(d, g.steps)  # a finished run does not train again: nothing to note
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
                other = "another results= directory" + (" or suite" if g.suite != "adhoc" else "")
                raise ConfigError(f"{p.parent} holds a run with another config ({config_changes(old, g)}); choose "
                                  f"{other}, or give the run's own values to resume it")


def config_changes(old: dict[str, Any], g: RunSpec, most: int = 4) -> str:
    """What differs between a run's record (``run.yaml``) and the group ``g``: ``eval_every 1000 -> 2000, medal.lr
    0.0003 -> 0.001``, the first ``most`` of them; the config hashes where the record has no config to compare."""
    was = {k: old.get(k) for k in ("eval_every", "eval_episodes", "demo_source")}
    now = {k: getattr(g, k) for k in was}
    if isinstance(old.get("config"), dict):
        was |= {f"{g.algo}.{k}": v for k, v in old["config"].items()}
        now |= {f"{g.algo}.{k}": v for k, v in g.config.items()}
    changed = [f"{k} {was.get(k, '(none)')} -> {now.get(k, '(none)')}" for k in sorted(set(was) | set(now))
               if was.get(k) != now.get(k)]
    if not changed:
        return f"hash {old.get('config_hash')} != {g.config_hash}"
    return ", ".join(changed[:most]) + (f" and {len(changed) - most} more" if len(changed) > most else "")


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
        step, ended = int(st.get("step", 0)), st.get("state") == "done"
        if finished(d, spec.steps, st):
            done += spec.steps
        elif has_checkpoint:  # a finished run's final checkpoint is at its last step, an unfinished one's on the grid
            resume_at = step if ended else step // spec.checkpoint_every * spec.checkpoint_every
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
