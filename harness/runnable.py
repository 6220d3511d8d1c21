"""Which algorithm runs on which env: the refusals a plan makes before anything is written (one line each), and the
pairs a ``runnable_only`` suite leaves out (:class:`CannotRunThere`); and which worker processes can run an algorithm
or env registered at run time (:func:`unseen_by_workers`)."""

from __future__ import annotations

import sys

from harness.envs import env_info
from harness.words import ConfigError


class CannotRunThere(ConfigError):
    """An algorithm that cannot run on an env by its nature (demonstrations, reward, goal shape): the pairs a
    ``runnable_only`` suite leaves out. ``reason`` is the sentence without the algorithm's name."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def why_not_on(cls, cfg, env: str) -> str | None:
    """Why algorithm ``cls`` configured by ``cfg`` cannot run on ``env``, or None: it needs demonstrations the env does
    not have (``requires_demos``, ``EnvInfo.demos``), it learns from 1[success] where EARL trained on a dense reward
    (``task_reward``, ``EnvSpec.reward_fn``), or it writes whole states into goals of a few state coordinates
    (``state_goals``, ``EnvSpec.goal_idx``: minitaur's base xy)."""
    info = env_info(env)
    spec = info.spec
    if not info.demos and cls.requires_demos(cfg):
        return f"needs demonstrations and env={env} has none (EARL ships none for it)"
    if spec.reward_fn is not None and not cls.task_reward:
        return f"learns from 1[success] and env={env}'s reward is dense (EARL trained on it)"
    if spec.goal_dim != spec.state_dim and cls.state_goals:
        return (f"sets whole states as goals and env={env}'s goal is {spec.goal_dim} of its {spec.state_dim} state "
                "coordinates")
    return None


def runs_on(env: str) -> list[str]:
    """The registered algorithms that run on ``env`` with their default settings."""
    from harness.registry import ALGORITHMS

    return [a for a, c in ALGORITHMS.items() if why_not_on(c, c.Config(), env) is None]


def check_runs_on(name: str, cls, cfg, env: str) -> None:
    """:class:`CannotRunThere` (one line, naming what runs there instead) when algorithm ``cls`` configured by ``cfg``
    cannot run on ``env``; :class:`ConfigError` when its settings do not fit the env (``check_task``)."""
    why = why_not_on(cls, cfg, env)
    if why is not None:
        raise CannotRunThere(f"algo={name} {why}; algorithms that run on env={env}: {', '.join(runs_on(env))}", why)
    try:
        cls.check_task(cfg, env_info(env).spec)
    except ValueError as e:
        raise ConfigError(f"{name} on {env}: {e}") from None


def runtime_entries(groups: list) -> list[str]:
    """The algorithms and envs of ``groups`` that were added to (or replaced in) the registries at run time, outside
    their source: ``algorithm 'x'``, ``env 'y'``."""
    from harness.envs import BUILT_IN_ENVS, ENVS
    from harness.registry import ALGORITHMS, BUILT_IN

    algos = sorted({g.algo_class for g in groups if BUILT_IN.get(g.algo_class) is not ALGORITHMS.get(g.algo_class)})
    envs = sorted({g.env for g in groups if BUILT_IN_ENVS.get(g.env) is not ENVS.get(g.env)})
    return [f"algorithm {a!r}" for a in algos] + [f"env {e!r}" for e in envs]


def unseen_by_workers(groups: list, backend: str = "local") -> str:
    """Why worker processes would not hold the run-time registrations of ``groups`` ("" when they would, or there are
    none). A spawned local worker runs the top level of the script that started it again, registrations included; a
    notebook, ``python -c`` or a REPL has no script to run again, and a Ray worker imports the registries from their
    source. (A registration under a script's ``if __name__ == "__main__":`` is not run again either: the worker then
    fails with one line saying so, :func:`harness.runner.run_group`.)"""
    entries = runtime_entries(groups)
    script = getattr(sys.modules.get("__main__"), "__file__", None)
    if not entries or (backend != "ray" and script):
        return ""
    where = "this Ray driver" if backend == "ray" else "this process (a notebook, `python -c` or a REPL)"
    return f"{', '.join(entries)} registered at run time in {where}, which worker processes would not hold"
