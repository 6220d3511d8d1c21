"""The env registry: short name -> :class:`EnvInfo` (spec, label, class, ...). An explicit dict, no import side
effects but the gymnasium registration.

Each env declares its :class:`EnvInfo` in its own module and is registered here with one line; every per-env
table of the harness is derived from ``ENVS`` (``GYM_IDS``, ``EVAL_HORIZONS`` below, ``harness.request.DEFAULT_STEPS``,
``harness.labels.ENV_ORDER`` / ``ENV_LABELS``, ...). See docs/extending.md.

``register_gym()`` registers the gymnasium ids (``earl/TabletopManipulation-v0``,
``earl/SawyerDoor-v0``, ``earl/SawyerPeg-v0``, ...; ``max_episode_steps`` = EARL's eval horizon H_E). An env whose
simulator is an optional extra (minitaur: pybullet) stays registered without it; building it (``make_env``,
``gym.make``) raises :class:`EnvUnavailableError` with one line saying why. ``UNAVAILABLE_ENVS``: EARL envs that
cannot be run at all (dhand_lightbulb), listed with their reason.
``make_train_env`` / ``make_eval_env`` build the two envs of the EARL protocol directly (no
gymnasium checker wrappers on the hot path).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import gymnasium as gym

from harness.envs.base import EarlEnv, EnvInfo, EnvSpec, PersistentState
from harness.envs.kitchen_task import KITCHEN
from harness.envs.minitaur_task import MINITAUR
from harness.envs.sawyer_tasks import SAWYER_DOOR, SAWYER_PEG
from harness.envs.tabletop import TABLETOP

if TYPE_CHECKING:
    from harness.data import Demos

ENVS: dict[str, EnvInfo] = {
    "tabletop_manipulation": TABLETOP,
    "sawyer_door": SAWYER_DOOR,
    "sawyer_peg": SAWYER_PEG,
    "kitchen": KITCHEN,
    "minitaur": MINITAUR,
}

#: EARL envs that cannot be run at all: name -> why (``harness list`` shows them; ``env=`` gets the reason)
UNAVAILABLE_ENVS: dict[str, str] = {
    "dhand_lightbulb": "not available: EARL never released it",
}

#: the env registry as its source builds it: what a spawned worker process imports (see ``harness.registry.BUILT_IN``)
BUILT_IN_ENVS: dict[str, EnvInfo] = dict(ENVS)

#: derived views of ``ENVS`` as imported (code that must follow a registry changed at run time reads ``ENVS``)
GYM_IDS = {name: info.spec.gym_id for name, info in ENVS.items()}
EVAL_HORIZONS = {name: info.spec.eval_horizon for name, info in ENVS.items()}


class UnknownEnvError(KeyError):
    def __str__(self) -> str:
        return str(self.args[0])


class EnvUnavailableError(UnknownEnvError):
    """The env is known but cannot be built here (never released, or an optional dependency is missing)."""


def env_name(word: str) -> str:
    """The registry name of the env ``word`` names (:func:`harness.words.name_of`): its name in any case or with
    dashes (``Sawyer-Door``), its gymnasium id with or without namespace and version (``earl/SawyerDoor-v0``,
    ``SawyerDoor``), or a part of one name alone (``door``, ``peg``, ``tabletop``); any other word unchanged (the
    check that follows names it as unknown)."""
    from harness.words import name_of

    ids = {info.spec.gym_id: n for n, info in ENVS.items()}  # earl/SawyerDoor-v0, SawyerDoor-v0, SawyerDoor
    aliases = {form: n for gid, n in ids.items()
               for form in (gid, gid.split("/")[-1], gid.split("/")[-1].rsplit("-v", 1)[0])}
    return name_of(word, (*ENVS, *UNAVAILABLE_ENVS), aliases)


def env_info(name: str) -> EnvInfo:
    """The registered :class:`EnvInfo` of the env ``name`` names (:func:`env_name`); :class:`UnknownEnvError` (one
    line) when there is none."""
    name = env_name(name)
    if name in UNAVAILABLE_ENVS:
        raise EnvUnavailableError(f"env {name}: {UNAVAILABLE_ENVS[name]}")
    if name not in ENVS:
        from harness.words import did_you_mean

        raise UnknownEnvError(f"unknown env {name!r}{did_you_mean(name, ENVS)}; known envs: {', '.join(ENVS)}")
    return ENVS[name]


def check_env(name: str) -> EnvInfo:
    """:func:`env_info`, and :class:`EnvUnavailableError` (one line saying why) when the env cannot be built here."""
    info = env_info(name)
    why = info.unavailable()
    if why:
        raise EnvUnavailableError(why)
    return info


def load_env_demos(name: str, direction: str = "forward") -> Demos:
    """The demonstrations of env ``name`` (:func:`harness.data.load_demos`), or empty sets in its shapes for an env
    that has none (``EnvInfo.demos`` False: EARL ships no kitchen or minitaur demos), without looking for files."""
    from harness.data import empty_demos, load_demos  # the data module imports torch: not for the registry alone

    name = env_name(name)
    info = env_info(name)
    if info.demos:
        return load_demos(name, direction)
    return empty_demos(name, direction, info.spec.obs_dim, info.spec.act_dim)


def demos_record(name: str) -> dict[str, str | None]:
    """What ``run.yaml`` records of the demos of env ``name``: their directory and SHA-256, None for an env without."""
    from harness.data import demos_fingerprint

    name = env_name(name)
    return demos_fingerprint(name) if env_info(name).demos else {"data_dir": None, "demos_sha256": None}


def get_spec(name: str) -> EnvSpec:
    return env_info(name).spec


def make_env(name: str, **kwargs) -> EarlEnv:
    """The bare EARL env (never truncates on its own)."""
    return check_env(name).load_class()(**kwargs)


def make_train_env(name: str, horizon: int | None = None, **kwargs) -> PersistentState:
    """EARL's reset-free train env: truncates every H_T steps (a hard reset is then due)."""
    env = make_env(name, **kwargs)
    return PersistentState(env, horizon or env.spec_.train_horizon)


def make_eval_env(name: str, **kwargs) -> gym.Env:
    """EARL's eval env: episodes of H_E steps (truncation), each reset drawing s0 ~ rho0."""
    env = make_env(name, **kwargs)
    return gym.wrappers.TimeLimit(env, env.spec_.eval_horizon)


def _entry_point(name: str):
    def make(**kwargs):
        return make_env(name, **kwargs)

    return make


def register_gym() -> None:
    """Register the gymnasium ids; idempotent. Importing this module already does (as gymnasium packages do), so
    ``gym.make("earl/SawyerDoor-v0")`` works after ``import harness.envs``, and so does
    ``gym.make("harness.envs:earl/SawyerDoor-v0")`` without it."""
    for name, info in ENVS.items():
        if info.spec.gym_id not in gym.registry:
            gym.register(id=info.spec.gym_id, entry_point=_entry_point(name), max_episode_steps=info.spec.eval_horizon)


register_gym()


__all__ = [
    "ENVS",
    "EVAL_HORIZONS",
    "GYM_IDS",
    "UNAVAILABLE_ENVS",
    "EarlEnv",
    "EnvInfo",
    "EnvSpec",
    "EnvUnavailableError",
    "PersistentState",
    "UnknownEnvError",
    "check_env",
    "demos_record",
    "load_env_demos",
    "env_info",
    "get_spec",
    "make_env",
    "make_eval_env",
    "make_train_env",
    "register_gym",
]
