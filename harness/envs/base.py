"""The EARL environment contract shared by the three tasks.

Every EARL observation is ``[state, goal]`` with ``goal_dim == state_dim`` (minitaur alone: a goal of some state
coordinates, ``EnvSpec.goal_idx``). The reward and the success predicate read the goal *from the observation*,
so any algorithm can ask "would this state count as reaching that goal?" by writing a goal into the second half of
an observation (FBRL's initial-state goals, VaPRL's demo-state subgoals and hindsight relabelling all rely on it).

:class:`EnvSpec` is the typed, picklable description of a task that algorithms receive. It carries
the constants of ``docs/algorithms.md`` section 1.1 and vectorised ``is_success`` /
``compute_reward`` that work on any batch of observations (numpy or torch).

:class:`EnvInfo` is the env's entry in the harness's catalogue (``harness.envs.ENVS``): its spec plus what the
harness knows about it (display label, default budget, the class that simulates it, scripted experts).

:class:`EarlEnv` is the gymnasium base class. Subclasses implement the simulator; horizons are
never terminations: the eval horizon is a ``TimeLimit`` truncation (registered ``max_episode_steps``)
and the train horizon is the :class:`PersistentState` wrapper's truncation.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class EnvSpec:
    """Constants of one EARL task (docs/algorithms.md section 1.1)."""

    name: str  # short name used everywhere: tabletop_manipulation, sawyer_door, sawyer_peg
    gym_id: str
    state_dim: int
    act_dim: int
    success_idx: tuple[int, ...]  # coordinates of the state compared with the goal
    success_threshold: float
    train_horizon: int  # H_T: steps between hard resets of the reset-free train env
    eval_horizon: int  # H_E: length of an evaluation episode
    initial_states: np.ndarray = field(repr=False)  # (n, state_dim): EARL's get_initial_states()
    goal_states: np.ndarray = field(repr=False)  # (n, goal_dim): EARL's task goals
    goal_idx: tuple[int, ...] | None = None  # the state coordinates the goal holds; None: the whole state
    #: dense reward of observations, or its "module:name" (imported on first use, so the catalogue stays cheap and
    #: free of the simulator); None: 1[success]
    reward_fn: Callable | str | None = field(default=None, repr=False)

    @property
    def obs_dim(self) -> int:
        return self.state_dim + self.goal_dim

    @property
    def goal_dim(self) -> int:
        return self.state_dim if self.goal_idx is None else len(self.goal_idx)

    def goal_of(self, states):
        """The goals that ``states`` (..., state_dim) would be: their goal coordinates (``goal_idx``, minitaur's base
        xy), else the whole states (numpy or torch)."""
        return states if self.goal_idx is None else states[..., list(self.goal_idx)]

    def split(self, obs):
        """``obs[..., :state_dim], obs[..., state_dim:]`` (works for numpy and torch)."""
        return obs[..., : self.state_dim], obs[..., self.state_dim :]

    def with_goal(self, obs, goal):
        """A copy of ``obs`` with its goal half replaced by ``goal`` (numpy, broadcasting)."""
        out = np.array(obs, dtype=np.float32, copy=True)
        out[..., self.state_dim :] = goal
        return out

    def goal_distance(self, obs):
        """Distance between state and goal on the success coordinates, for a batch (numpy/torch)."""
        idx = list(self.success_idx)
        at = idx if self.goal_idx is None else [self.goal_idx.index(i) for i in idx]
        s = obs[..., idx]
        g = obs[..., [self.state_dim + i for i in at]]
        d = s - g
        return (d * d).sum(-1) ** 0.5

    def is_success(self, obs):
        """EARL's ``is_successful`` on any observation(s): distance <= threshold."""
        return self.goal_distance(obs) <= self.success_threshold

    def compute_reward(self, obs):
        """EARL's sparse reward ``1[success(obs)]`` as float (numpy float64 / torch dtype of obs), or the env's dense
        ``reward_fn(obs)`` where it declares one."""
        if self.reward_fn is not None:
            return resolve(self.reward_fn)(obs)
        ok = self.is_success(obs)
        if isinstance(ok, np.ndarray) or np.isscalar(ok):
            return np.asarray(ok, dtype=np.float64) * 1.0
        return ok.to(obs.dtype)


class EarlEnv(gym.Env):
    """Base class of the three EARL tasks (gymnasium API, never terminates).

    ``reset(seed=..., options=...)`` draws only from ``self.np_random``. Options:

    - ``{"goal": g}``: use goal ``g`` (goal_dim vector) instead of drawing one of the task goals;
    - ``{"state": obs}``: put the simulator in the state of a full observation (its goal half
      becomes the goal unless ``"goal"`` is also given).

    ``info`` of ``step`` carries ``success`` (bool) computed on the returned observation.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    spec_: EnvSpec  # set by subclasses (``spec`` is taken by gymnasium for the registration spec)

    def __init__(self, render_mode: str | None = None):
        s = self.spec_
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (s.obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (s.act_dim,), np.float32)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode

    # -- what algorithms use -------------------------------------------------------------------
    def compute_reward(self, obs):
        return self.spec_.compute_reward(obs)

    def is_success(self, obs):
        return self.spec_.is_success(obs)

    def get_initial_states(self) -> np.ndarray:
        return self.spec_.initial_states.copy()

    def get_goal_states(self) -> np.ndarray:
        return self.spec_.goal_states.copy()

    def sample_goal(self) -> np.ndarray:
        goals = self.spec_.goal_states
        return goals[self.np_random.integers(len(goals))].copy()

    # -- checkpointing ---------------------------------------------------------------------------
    def get_sim_state(self) -> dict[str, Any]:
        """Everything needed to continue this env bit-for-bit (simulator + goal + RNG)."""
        raise NotImplementedError

    def set_sim_state(self, state: dict[str, Any]) -> None:
        raise NotImplementedError

    def _rng_state(self) -> dict:
        return self.np_random.bit_generator.state

    def _set_rng_state(self, st: dict) -> None:
        self.np_random.bit_generator.state = st


class PersistentState(gym.Wrapper):
    """EARL's persistent-state train wrapper: truncates only after ``horizon`` steps since reset.

    Counts ``steps_since_reset``, ``total_steps`` and ``interventions`` (resets after the first);
    ``info`` carries them. The learner must call ``reset`` after a truncation (a hard reset).
    """

    def __init__(self, env: gym.Env, horizon: int):
        super().__init__(env)
        self.horizon = int(horizon)
        self.steps_since_reset = 0
        self.total_steps = 0
        self.resets = 0
        self._env_step = env.step  # bound once: this wrapper is on the hot path

    @property
    def interventions(self) -> int:
        return max(self.resets - 1, 0)

    def reset(self, **kwargs):
        self.resets += 1
        self.steps_since_reset = 0
        obs, info = self.env.reset(**kwargs)
        info["interventions"] = self.interventions
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env_step(action)
        n = self.steps_since_reset = self.steps_since_reset + 1
        self.total_steps += 1
        info["steps_since_reset"] = n
        return obs, reward, terminated, truncated or n >= self.horizon, info

    def get_wrapper_state(self) -> dict:
        return {"steps_since_reset": self.steps_since_reset, "total_steps": self.total_steps, "resets": self.resets}

    def set_wrapper_state(self, st: dict) -> None:
        self.steps_since_reset = st["steps_since_reset"]
        self.total_steps = st["total_steps"]
        self.resets = st["resets"]


def resolve(ref: Any) -> Any:
    """``ref`` itself, or the object that a ``"package.module:name"`` string names (imported on first use)."""
    if not isinstance(ref, str):
        return ref
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


def unpickle_env(cls: type, kwargs: dict, state: dict) -> EarlEnv:
    """An env rebuilt from its constructor arguments and ``get_sim_state()``: what the simulator envs' ``__reduce__``
    pickle instead of their simulator objects."""
    env = cls(**kwargs)
    env.set_sim_state(state)
    return env


@dataclass(frozen=True)
class EnvInfo:
    """One env in the harness's catalogue: its :class:`EnvSpec` and the harness's facts about it.

    Declared in the env's own module (next to its spec), registered with one line in ``harness.envs.ENVS``;
    every per-env table of the harness (gym ids, horizons, default step budgets, labels, scripted demos,
    benchmarks) is derived from these records (docs/extending.md). ``env_class`` and ``experts`` may be
    ``"module:name"`` strings, imported on first use, so that the catalogue stays cheap to import when a
    simulator is not (Meta-World takes over a second)."""

    spec: EnvSpec
    label: str  # display name in reports and the dashboard
    env_class: type[EarlEnv] | str  # the EarlEnv subclass that simulates it, or its "module:Class"
    default_steps: int  # training steps of a run when neither the suite nor the command gives a budget
    experts: tuple[Callable | str, Callable | str] | None = None  # scripted (forward, reverse) experts obs -> action
    scripted_demos: tuple[int, int] = (0, 0)  # trajectories (forward, reverse) that `harness data scripted` writes
    bench_steps: int = 2_000  # env steps per timing in `harness bench env`
    metaworld_class: str | None = None  # "module:Class" of the raw Meta-World 3 env it builds on (timed by bench env)
    offline_assets: Callable | str | None = None  # writes its model files into a data dir without network (data scripted)
    demos: bool = True  # False: the env has no demonstrations (EARL ships none): no demo files are looked for, the
    #                     algorithms get empty demo sets, and those that need demos are refused at plan time
    # what its simulator needs beyond the base install: (module, pip extra, newest Python the module has wheels for)
    requires: tuple[str, str, str] | None = None
    in_table1: bool = False  # one of the MEDAL paper's Table 1 envs: its budget there is ``default_steps``
    published_metric: str = "deployed_success"  # what the published "deployed" curves measure ("deployed_return")

    def unavailable(self) -> str | None:
        """Why this env cannot be built here (one line), or None: its ``requires`` module is not importable."""
        if self.requires is None or importlib.util.find_spec(self.requires[0]) is not None:
            return None
        module, extra, newest = self.requires
        install = f"pip install 'earl-harness[{extra}]' on Python <= {newest}"
        if sys.version_info[:2] > tuple(int(x) for x in newest.split(".")):
            return f"env {self.name} needs {module}, which is not available for Python {sys.version_info[0]}." \
                   f"{sys.version_info[1]}: {install}"
        return f"env {self.name} needs {module}, which is not installed: {install}"

    @property
    def name(self) -> str:
        return self.spec.name

    def load_class(self) -> type[EarlEnv]:
        return resolve(self.env_class)

    def expert(self, direction: str) -> Callable[[np.ndarray], np.ndarray]:
        """The scripted expert for ``direction`` (``forward`` or ``reverse``); KeyError when there is none."""
        if self.experts is None or direction not in ("forward", "reverse"):
            raise KeyError(f"no scripted expert for env={self.name!r} direction={direction!r}")
        return resolve(self.experts[direction == "reverse"])
