"""VaPRL's parts (:mod:`algorithms.vaprl`), as plain functions and small classes: the value threshold's unit, the
subgoal candidates and rules (Lagrangian, nearest feasible), the dual variable of the Lagrangian rule, hindsight
relabelling (final state, demo prefixes) and the goal test of phases whose goal is a few state coordinates. ``cfg``
arguments are :class:`algorithms.vaprl.VaPRLConfig` (not imported: that module imports this one)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from algorithms.api import Task, demo_segments

ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8  # TF1 AdamOptimizer defaults (the multiplier's optimizer)


def value_ceiling(cfg: Any) -> float:
    """V_max, the unit of the value threshold: ``cfg.v_max``, or (0) the most one phase can earn in the critic's
    units: reward_scale when success ends the phase (one terminal reward), else reward_scale x (1 - gamma^H) /
    (1 - gamma), the sparse reward earned at every step of an H-step phase (no bootstrap at phase ends), or
    reward_scale / (1 - gamma) when the critic bootstraps through phase ends."""
    if cfg.v_max:
        return cfg.v_max
    if cfg.success_ends_phase:
        return cfg.reward_scale
    if cfg.bootstrap_on_truncation:  # the critic bootstraps through phase ends: an endless stream of rewards
        return cfg.reward_scale / (1.0 - cfg.gamma)
    return cfg.reward_scale * (1.0 - cfg.gamma**cfg.phase_step_limit) / (1.0 - cfg.gamma)


def demo_time_index(terminals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position inside its demo, that demo's length) for every transition; demos end at terminals."""
    starts, demo = demo_segments(terminals)
    return np.arange(len(demo)) - starts[demo], np.bincount(demo)[demo]


def subgoal_candidates(forward, reverse, state_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Candidate states (N, state_dim), forward demos first, and their time-index distance to rho0 (N,): steps since
    the forward demo's start, steps left to the backward demo's end (RISC's ``timestep`` distance)."""
    pos_f, _ = demo_time_index(forward.terminals)
    pos_b, len_b = demo_time_index(reverse.terminals)
    states = np.concatenate([forward.observations[:, :state_dim], reverse.observations[:, :state_dim]])
    return states.astype(np.float32), np.concatenate([pos_f, len_b - pos_b])


def choose_subgoal(values: np.ndarray, distance: np.ndarray, eps: float, allowed: np.ndarray | None = None) -> int:
    """``nearest_feasible``: the feasible (value >= eps) candidate with the smallest distance; if none, the largest
    value; only among ``allowed`` candidates (all if None)."""
    if allowed is not None:
        values = np.where(allowed, values, -np.inf)  # never feasible, never the largest
    feasible = values >= eps
    if not feasible.any():
        return int(np.argmax(values))
    return int(np.argmin(np.where(feasible, distance, np.inf)))


def lagrangian_subgoal(values: np.ndarray, distance: np.ndarray, lam: float, allowed: np.ndarray | None = None) -> int:
    """``lagrangian``: argmin over candidates (``allowed`` ones; all if None) of distance - lambda * value (ties: the
    first)."""
    objective = distance - lam * values
    return int(np.argmin(objective if allowed is None else np.where(allowed, objective, np.inf)))


def parse_coords(text: str) -> tuple[int, ...]:
    """``goal_coords``: "0,1,2" -> (0, 1, 2), "" -> (); anything but distinct non-negative integers -> ValueError."""
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    if not all(p.isdigit() for p in parts) or len(set(map(int, parts))) != len(parts):
        raise ValueError(f"goal_coords={text!r} is not allowed: must be distinct non-negative integers, comma-separated")
    return tuple(int(p) for p in parts)


def goal_test(task: Task, cfg: Any) -> Task:
    """The task as the agent judges reaching its goals (rewards, terminals, phase ends, relabelling, solved candidates,
    the demos). By default EARL's test: ``task`` itself. ``goal_coords`` / ``goal_threshold`` swap in another, e.g.
    VaPRL's own door env's ``is_successful`` (hand and handle positions, L2 <= 0.2: ``goal_coords=0,1,2,4,5,6
    goal_threshold=0.2`` on EARL's door state); ``task_goal_test=task`` keeps EARL's test for g* alone (EARL's door goal
    puts the hand at the handle's own coordinates, 0.075-0.086 from where every forward demo holds the shut door, so
    no hand-and-handle test both lets the demos reach g* and demands the shut door). The env, its success signal and
    the deployed evaluation keep EARL's."""
    coords = parse_coords(cfg.goal_coords)
    if not coords and not cfg.goal_threshold:
        return task
    if any(i >= task.state_dim for i in coords):
        raise ValueError(f"goal_coords={cfg.goal_coords!r} is not allowed: {task.name}'s state has {task.state_dim} "
                         f"coordinates (0-{task.state_dim - 1})")
    other = replace(task, success_idx=coords or tuple(task.success_idx),
                    success_threshold=cfg.goal_threshold or task.success_threshold)
    return TaskGoalKeepsItsTest(task, other) if cfg.task_goal_test == "task" else other


class TaskGoalKeepsItsTest:
    """The agent's goal test for subgoals and relabelled goals, the task's own for g*: a goal equal to one of the task's
    goal states is judged by ``task`` (EARL's test), any other by ``other``. Distances are in units of each test's
    threshold (success: distance <= 1), so one comparison serves both. Everything else is the task's."""

    success_threshold = 1.0

    def __init__(self, task: Task, other: Task):
        self.task, self.other = task, other
        self._goal_states = np.asarray(task.goal_states, dtype=np.float32)

    def __getattr__(self, name: str):  # name, dims, horizons, initial and goal states: the task's
        if name.startswith("__") or name in ("task", "other"):  # copy/pickle probe before __init__ ran
            raise AttributeError(name)
        return getattr(self.task, name)

    def is_task_goal(self, obs: np.ndarray) -> np.ndarray:
        """Whether each observation's goal part is one of the task's goal states (float32, as goals are stored)."""
        goal = np.asarray(obs, dtype=np.float32)[..., None, self.task.state_dim :]
        return (np.abs(goal - self._goal_states).max(axis=-1) <= 1e-6).any(axis=-1)

    def goal_distance(self, obs: np.ndarray) -> np.ndarray:
        return np.where(self.is_task_goal(obs), self.task.goal_distance(obs) / self.task.success_threshold,
                        self.other.goal_distance(obs) / self.other.success_threshold)

    def is_success(self, obs: np.ndarray) -> np.ndarray:
        return self.goal_distance(obs) <= 1.0

    def compute_reward(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self.is_success(obs), dtype=np.float64)


def cut_at_success(obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, is_success) -> dict[str, np.ndarray]:
    """``add_demo`` keyword arrays of one trajectory cut after its first transition that succeeds (terminal, reward 1
    there); without one, the whole trajectory, ending truncated."""
    success = np.asarray(is_success(next_obs), dtype=bool)
    end = int(np.argmax(success)) + 1 if success.any() else len(obs)
    return {"observations": obs[:end], "actions": actions[:end], "rewards": success[:end].astype(np.float32),
            "next_observations": next_obs[:end], "terminals": success[:end].copy()}


def final_state_relabel(phase: np.ndarray, state_dim: int, act_dim: int, is_success) -> dict[str, np.ndarray]:
    """One hindsight copy of a phase's rows [s, a, s'] (T, .) with goal = its final achieved state s'_T, cut at the
    first transition that succeeds for that goal (terminal there), as the original ``relabel_function`` does."""
    s, a, s2 = phase[:, :state_dim], phase[:, state_dim : state_dim + act_dim], phase[:, state_dim + act_dim :]
    goal = np.broadcast_to(s2[-1], s.shape)
    return cut_at_success(np.concatenate([s, goal], axis=1).astype(np.float32), a,
                          np.concatenate([s2, goal], axis=1).astype(np.float32), is_success)


def demo_prefix_relabel(demos, state_dim: int, act_dim: int, is_success) -> dict[str, np.ndarray]:
    """The original code's ``relabel_offline_data`` (``data_multiplier``): for every demo and every state s_j it reaches
    (j = 1..L), one copy of the demo's first j transitions with goal s_j, cut at its first success for that goal
    (:func:`final_state_relabel`), so each copy ends terminal with reward 1. Returned as one flat demo set (``add_demo``
    keyword arrays): about L^2 / 2 transitions per demo of length L."""
    sd = state_dim
    rows = np.concatenate([demos.observations[:, :sd], demos.actions, demos.next_observations[:, :sd]], axis=1)
    starts, segment = demo_segments(demos.terminals)
    ends = np.append(starts[1:], len(segment))
    copies = [final_state_relabel(rows[a : a + j], sd, act_dim, is_success)
              for a, b in zip(starts, ends) for j in range(1, b - a + 1)]
    return {k: np.concatenate([c[k] for c in copies]) for k in copies[0]}


class LagrangeMultiplier:
    """One scalar per member, >= 0, minimised by Adam on mean(lambda * (V_chosen - threshold)) over the subgoals chosen
    since the last step: it grows while chosen subgoals are below the threshold (subgoals move toward the goal) and
    shrinks otherwise (toward rho0)."""

    def __init__(self, num_members: int, lr: float, upper: float):
        self.lr, self.upper = lr, upper
        self.value = np.zeros(num_members)
        self.m, self.v = np.zeros(num_members), np.zeros(num_members)
        self.t = np.zeros(num_members, dtype=np.int64)
        self.pending: list[list[float]] = [[] for _ in range(num_members)]

    def record(self, i: int, value: float) -> None:
        self.pending[i].append(float(value))

    def step(self, threshold: float) -> None:
        (b1, b2) = ADAM_BETAS
        for i, vals in enumerate(self.pending):
            if not vals:
                continue
            g = float(np.mean(vals)) - threshold
            self.t[i] += 1
            self.m[i] = b1 * self.m[i] + (1 - b1) * g
            self.v[i] = b2 * self.v[i] + (1 - b2) * g * g
            lr_t = self.lr * math.sqrt(1 - b2 ** self.t[i]) / (1 - b1 ** self.t[i])
            self.value[i] = min(max(self.value[i] - lr_t * self.m[i] / (math.sqrt(self.v[i]) + ADAM_EPS), 0.0),
                                self.upper)
            self.pending[i] = []

    def state_dict(self) -> dict[str, Any]:
        return {"value": self.value.copy(), "m": self.m.copy(), "v": self.v.copy(), "t": self.t.copy(),
                "pending": [list(p) for p in self.pending]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for k in ("value", "m", "v", "t"):
            getattr(self, k)[:] = state[k]
        self.pending = [list(p) for p in state["pending"]]
