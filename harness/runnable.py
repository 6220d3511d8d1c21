"""Which algorithm runs on which env: the refusals a plan makes before anything is written (one line each), and the
pairs a ``runnable_only`` suite leaves out (:class:`CannotRunThere`)."""

from __future__ import annotations

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
