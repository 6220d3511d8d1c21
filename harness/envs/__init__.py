"""The env registry: short name -> (spec, class). An explicit dict, no import side effects.

``register_gym()`` registers the gymnasium ids (``earl/TabletopManipulation-v0``,
``earl/SawyerDoor-v0``, ``earl/SawyerPeg-v0``; ``max_episode_steps`` = EARL's eval horizon H_E).
``make_train_env`` / ``make_eval_env`` build the two envs of the EARL protocol directly (no
gymnasium checker wrappers on the hot path).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

import gymnasium as gym

from harness.envs.base import EarlEnv, EnvSpec, PersistentState
from harness.envs.tabletop import TABLETOP_SPEC


@dataclass(frozen=True)
class EnvEntry:
    spec_module: str  # module holding the spec and class (imported lazily: metaworld is heavy)
    spec_name: str
    class_name: str

    def load(self) -> tuple[EnvSpec, type[EarlEnv]]:
        mod = importlib.import_module(self.spec_module)
        return getattr(mod, self.spec_name), getattr(mod, self.class_name)


ENVS: dict[str, EnvEntry] = {
    "tabletop_manipulation": EnvEntry("harness.envs.tabletop", "TABLETOP_SPEC", "TabletopManipulationEnv"),
    "sawyer_door": EnvEntry("harness.envs.sawyer", "DOOR_SPEC", "SawyerDoorEnv"),
    "sawyer_peg": EnvEntry("harness.envs.sawyer", "PEG_SPEC", "SawyerPegEnv"),
}

GYM_IDS = {
    "tabletop_manipulation": "earl/TabletopManipulation-v0",
    "sawyer_door": "earl/SawyerDoor-v0",
    "sawyer_peg": "earl/SawyerPeg-v0",
}
EVAL_HORIZONS = {"tabletop_manipulation": 200, "sawyer_door": 300, "sawyer_peg": 200}


class UnknownEnvError(KeyError):
    def __str__(self) -> str:
        return str(self.args[0])


def _entry(name: str) -> EnvEntry:
    if name not in ENVS:
        raise UnknownEnvError(f"unknown env {name!r}; known envs: {', '.join(ENVS)}")
    return ENVS[name]


def get_spec(name: str) -> EnvSpec:
    if name == "tabletop_manipulation":
        return TABLETOP_SPEC
    return _entry(name).load()[0]


def make_env(name: str, **kwargs) -> EarlEnv:
    """The bare EARL env (never truncates on its own)."""
    return _entry(name).load()[1](**kwargs)


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
    for name, gym_id in GYM_IDS.items():
        if gym_id not in gym.registry:
            gym.register(id=gym_id, entry_point=_entry_point(name), max_episode_steps=EVAL_HORIZONS[name])


register_gym()


__all__ = [
    "ENVS",
    "EarlEnv",
    "EnvSpec",
    "PersistentState",
    "UnknownEnvError",
    "get_spec",
    "make_env",
    "make_eval_env",
    "make_train_env",
    "register_gym",
]
