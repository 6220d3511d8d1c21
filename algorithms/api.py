"""The one interface between the EARL protocol loop (``harness/``) and an algorithm.

An algorithm trains E independent *members* (seeds) in lockstep; every array it receives or
returns has a leading member dimension E. The protocol loop owns the environments, hard resets,
evaluation, results and checkpoints; the algorithm owns its controllers, goals, buffers and
updates. Per training step the loop (``harness.protocol.Interaction.step``) calls::

    actions = algo.act(obs)                       # (E, obs_dim) -> (E, act_dim) in [-1, 1]
    if algo.update_at == AFTER_ACT: algo.update()      # MEDAL's order: learn before the env moves
    next_obs = envs.step(actions)
    algo.store(next_obs, hard_reset)              # record the transitions just taken
    if algo.update_at == AFTER_STORE: algo.update()    # RISC's order: learn from them, then pick the next goal
    wants_reset = algo.observe(next_obs, hard_reset)   # controllers: switch phases, pick goals; (E,) bool
    for members that hit H_T or want a reset: obs = env.reset(); algo.on_reset(obs, mask)

and for evaluation ``algo.eval_act(obs)`` (deterministic forward policy on the eval env's own
observation). Algorithms see the task only through :class:`Task` and :class:`DemoSet`, which
``harness`` fills in (structural types: this package never imports ``harness``).
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields
from decimal import Decimal
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

if TYPE_CHECKING:
    import torch


class Task(Protocol):
    """What an algorithm may know about the env (``harness.envs.EnvSpec`` satisfies it)."""

    name: str
    state_dim: int
    act_dim: int
    success_idx: tuple[int, ...]
    success_threshold: float
    train_horizon: int
    eval_horizon: int
    initial_states: np.ndarray  # (n, state_dim)
    goal_states: np.ndarray  # (n, goal_dim)

    @property
    def obs_dim(self) -> int: ...  # state_dim + goal_dim

    @property
    def goal_dim(self) -> int: ...  # state_dim, or fewer where the goal holds some state coordinates (minitaur: xy)

    def goal_of(self, states): ...  # the goals states would be: their goal coordinates, or the whole states

    def goal_distance(self, obs): ...

    def is_success(self, obs): ...

    def compute_reward(self, obs): ...


class Demos(Protocol):
    """Demonstrations as flat transition arrays (``harness.data.Demos`` satisfies it)."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminals: np.ndarray
    next_observations: np.ndarray
    source: str


#: the transition arrays of a demo set, in EARL's file layout (``harness.data`` reads and checks exactly these)
DEMO_FIELDS = ("observations", "actions", "rewards", "terminals", "next_observations")

#: where the loop calls :meth:`Algorithm.update` in a training step (``Algorithm.update_at``)
AFTER_ACT, AFTER_STORE = "after act", "after store"

#: a member's phase (forward/backward controllers) or direction (goal-conditioned methods): the task, or the reset
FORWARD, BACKWARD = 0, 1


def demo_arrays(demos: Demos) -> dict[str, np.ndarray]:
    """A demo set as the keyword arguments of ``SegmentReplayBuffer.add_demo``."""
    return {k: getattr(demos, k) for k in DEMO_FIELDS}


def demo_segments(terminals) -> tuple[np.ndarray, np.ndarray]:
    """Split flat demo transitions into trajectories: (index of each trajectory's first transition,
    trajectory id of every transition). A trajectory ends after each ``terminals`` row."""
    t = np.asarray(terminals, dtype=bool).reshape(-1)
    ended = np.concatenate([[False], t[:-1]])  # the previous transition closed a trajectory
    return np.flatnonzero(np.concatenate([[True], t[:-1]])), np.cumsum(ended)


@dataclass(frozen=True)
class DemoSet:
    forward: Demos
    reverse: Demos


def setting(default: Any, help: str, *, ge: float | None = None, gt: float | None = None, le: float | None = None,
            lt: float | None = None, choices: tuple[str, ...] | None = None) -> Any:
    """A config field that declares its meaning and what it accepts: bounds (``ge``/``gt``/``le``/``lt``) for numbers,
    ``choices`` for strings. :meth:`AlgoConfig.validate` checks every field against its declaration, in one place;
    a subclass that only changes a default inherits the declaration (``field: float = 10.0``)."""
    return field(default=default, metadata={"help": help, "ge": ge, "gt": gt, "le": le, "lt": lt, "choices": choices})


def declaration(cls: type, name: str) -> dict[str, Any]:
    """The :func:`setting` metadata of field ``name``: the nearest class in ``cls``'s MRO that declares it."""
    for klass in cls.__mro__:
        f = getattr(klass, "__dataclass_fields__", {}).get(name)
        if f is not None and f.metadata:
            return dict(f.metadata)
    return {}


def check_setting(cls: type, name: str, value: Any, default: Any) -> None:
    """Raise ValueError naming ``name``, ``value`` and what is allowed when ``value`` breaks the declaration."""
    d = declaration(cls, name)
    what = f" ({d['help']})" if d.get("help") else ""
    kind = type(default)
    if kind is bool and not isinstance(value, bool) or kind is str and not isinstance(value, str):
        raise ValueError(f"{name}={value!r} is not allowed: must be a {kind.__name__}{what}")
    if kind in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or kind is int and not isinstance(value, int):
            raise ValueError(f"{name}={value!r} is not allowed: must be {'an integer' if kind is int else 'a number'}{what}")
        if math.isnan(value) or math.isinf(value) and not math.isinf(default):
            raise ValueError(f"{name}={value!r} is not allowed: must be a finite number{what}")
        for key, ok, text in (("ge", lambda b: value >= b, ">="), ("gt", lambda b: value > b, ">"),
                              ("le", lambda b: value <= b, "<="), ("lt", lambda b: value < b, "<")):
            if d.get(key) is not None and not ok(d[key]):
                raise ValueError(f"{name}={value!r} is not allowed: must be {text} {d[key]:g}{what}")
    if d.get("choices") and value not in d["choices"]:
        raise ValueError(f"{name}={value!r} is not allowed: must be one of {', '.join(d['choices'])}{what}")


@dataclass
class AlgoConfig:
    """Base of every algorithm's config dataclass; YAML defaults and ``key=value`` overrides fill it.

    ``config_file``: the name of the per-env YAML (``suites/algorithms/<name>.yaml``) when it is not
    the registered algorithm name (an ablation sharing its parent's per-env values)."""

    config_file: ClassVar[str | None] = None

    @classmethod
    def keys(cls) -> set[str]:
        return {f.name for f in fields(cls)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AlgoConfig":
        unknown = set(d) - cls.keys()
        if unknown:
            raise KeyError(f"unknown config key(s) {sorted(unknown)} for {cls.__name__}; known: {sorted(cls.keys())}")
        out = cls()
        for f in fields(cls):
            if f.name in d:
                setattr(out, f.name, _coerce(f.name, d[f.name], getattr(out, f.name)))
        out.validate()
        return out

    def validate(self) -> None:
        """Raise ValueError naming the key, the value and what is allowed when a field breaks its :func:`setting`
        declaration; subclasses add checks that span several fields."""
        defaults = type(self)()
        for f in fields(self):
            check_setting(type(self), f.name, getattr(self, f.name), getattr(defaults, f.name))

    @classmethod
    def describe(cls) -> list[tuple[str, Any, str]]:
        """(key, default, meaning) of every field, for ``--help``."""
        return [(f.name, getattr(cls(), f.name), declaration(cls, f.name).get("help", "")) for f in fields(cls)]


#: the step counts' shorthand the docs and the plans use: ``500k``, ``1.5M``, ``8M``
_SUFFIXES = {"k": 10**3, "m": 10**6, "b": 10**9, "g": 10**9}


def parse_int(name: str, value: Any) -> int:
    """An integer from a YAML/CLI value; accepts ``300000``, ``3e5``, ``300_000``, ``300,000`` and ``300k`` / ``1.5M`` (k = 10^3,
    M = 10^6, B or G = 10^9, either case; read in decimal, so 1.1M is 1,100,000 exactly). Digits are read exactly,
    however many; a value too long to show is cut in the message."""
    text = str(value).strip().replace("_", "")
    if re.fullmatch(r"[+-]?[0-9]{1,3}(,[0-9]{3})+", text):  # 300,000: as the plans and tables print it
        text = text.replace(",", "")
    shown = repr(value) if len(str(value)) <= 40 else f"{str(value)[:20]!r}... ({len(str(value))} characters)"
    if re.fullmatch(r"[+-]?[0-9]+", text):  # ASCII digits only (str.isdigit takes other scripts' digits too)
        if len(text) > 400:  # beyond any bound a setting declares (and Python's int() digit limit)
            raise ValueError(f"{name} is too large: {shown}")
        return int(text)
    short = re.fullmatch(r"([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))([kKmMbBgG])", text)
    if short and len(text) <= 40:
        n = Decimal(short[1]) * _SUFFIXES[short[2].lower()]
        if n != n.to_integral_value():
            raise ValueError(f"{name} must be an integer, got {shown}")
        return int(n)
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{name} must be an integer, got {shown}") from None
    if math.isinf(x):
        raise ValueError(f"{name} is too large: {shown}")
    if not x.is_integer():
        raise ValueError(f"{name} must be an integer, got {shown}")
    return int(x)


def _coerce(name: str, value: Any, default: Any) -> Any:
    """Coerce a YAML/CLI value to the type of the field's default (bool/int/float/str/tuple)."""
    if isinstance(default, bool):
        if isinstance(value, str):
            if value.lower() in ("true", "1", "yes", "on"):
                return True
            if value.lower() in ("false", "0", "no", "off"):
                return False
            raise ValueError(f"{name} must be a boolean, got {value!r}")
        return bool(value)
    if isinstance(default, int):
        return parse_int(name, value)
    if isinstance(default, float):
        try:
            return float(value)
        except ValueError:
            raise ValueError(f"{name} must be a number, got {value!r}") from None
    if isinstance(default, tuple):
        return tuple(value)
    return value


class Algorithm(ABC):
    """Base class of registered algorithms (see the module docstring for the call order).

    Subclasses set ``Config`` and ``label`` and implement the abstract methods. ``seeds`` has one entry per
    member; member ``i`` must behave exactly as an E = 1 run with seed ``seeds[i]``.
    """

    Config: ClassVar[type[AlgoConfig]]
    label: ClassVar[str] = ""  # display name in reports and the dashboard (every registered algorithm sets its own)
    #: True: cannot run without demonstrations (a discriminator's positives, a curriculum, the cloned data); the
    #: harness refuses it on an env that has none. False: demos, if any, only seed buffers (empty sets are fine).
    needs_demos: ClassVar[bool] = False
    #: True: writes whole states into the goal (demo-state subgoals, hindsight, relabelled demos), so it needs goals
    #: that are whole states (``goal_dim == state_dim``); the harness refuses it on an env whose goal is only some state
    #: coordinates (minitaur: the base xy). False: uses the env's own goals, or projects states onto the goal's
    #: coordinates (``Task.goal_of``: FBRL's and RISC's initial-state goals).
    state_goals: ClassVar[bool] = True
    #: True: learns from the task's reward (``Task.compute_reward``: EARL's dense reward where the env declares one,
    #: as on kitchen and minitaur). False: learns from 1[success] of the goals it sets, which on an env with a dense
    #: reward is not what EARL trained on; the harness refuses it there.
    task_reward: ClassVar[bool] = False
    #: where the loop calls :meth:`update`: :data:`AFTER_ACT` (once the actions are chosen, before the env moves, as
    #: MEDAL's code does) or :data:`AFTER_STORE` (once the new transitions are stored, before :meth:`observe` switches
    #: phases and picks goals with the updated critic, as RISC's code does)
    update_at: ClassVar[str] = AFTER_ACT
    #: True: a step updates each member's ACTING controller only (forward or backward phase), so a process whose members
    #: are in different phases runs every controller's member-batched update, twice the work of one. On a CPU the
    #: harness then trains one seed per process (``harness.packing``); measured on MEDAL, sawyer_peg: 84 steps/s per
    #: core as one seed, 51 as two members in different phases, 93 only while their phases coincide.
    phase_split_updates: ClassVar[bool] = False

    @classmethod
    def requires_demos(cls, cfg: AlgoConfig) -> bool:
        """Whether this algorithm, configured by ``cfg``, needs demonstrations (default: :attr:`needs_demos`)."""
        return cls.needs_demos

    @classmethod
    def check_task(cls, cfg: AlgoConfig, task: Task) -> None:
        """Raise ValueError (one line) when ``cfg`` cannot run on ``task`` (a setting naming state coordinates the task
        lacks, say). The harness calls it when it plans a run, so the error comes before anything is written."""

    def __init__(self, task: Task, demos: DemoSet, cfg: AlgoConfig, seeds: list[int], device: torch.device):
        self.task, self.demos, self.cfg, self.seeds, self.device = task, demos, cfg, list(seeds), device
        self.E = len(seeds)

    @abstractmethod
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Members in ``mask`` (E,) bool had their train env reset; ``obs`` (E, obs_dim)."""

    @abstractmethod
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Training actions for all members, (E, act_dim) float32 in [-1, 1]."""

    def update(self) -> None:
        """One learning step of every member (sample, losses, optimizers); called once per training step at
        :attr:`update_at`. An algorithm decides itself whether it learns yet (a seed phase, say)."""

    def store(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> None:
        """Record the transitions just taken (the last :meth:`act`'s actions, ``next_obs`` (E, obs_dim)).
        ``hard_reset`` (E,) bool: the env hit H_T and will be reset."""

    @abstractmethod
    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        """The controllers after the step (:meth:`store` has recorded it): end phases or episodes, pick goals.
        Returns (E,) bool: members whose env the algorithm wants reset (episodic)."""

    @abstractmethod
    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic forward-policy actions on eval observations (E, obs_dim)."""

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue bit-for-bit: networks, optimizers, buffers, RNGs, phase."""

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def metrics(self) -> dict[str, np.ndarray]:
        """Training diagnostics, each (E,): means since the previous call of what the updates returned (losses,
        temperature, Q, learned rewards, ...) and the algorithm's state (phase, curriculum, ...); NaN where a member
        has nothing to report. The protocol calls it every ``log_every`` steps and writes ``train.parquet``."""
        return {}
