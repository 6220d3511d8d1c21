"""VaPRL: value-accelerated persistent RL (Sharma et al., NeurIPS 2021), ALGORITHMS.md 8.

One goal-conditioned SAC agent and one buffer (forward + backward demos, each with its own goal)
for both phases, as in RISC's re-implementation (8.1, 8.4 DEFAULT; :mod:`algorithms.goal_conditioned`).
Forward phases command the task goal g* (uniform over the task goals); backward phases command the
curriculum subgoal C(g*) for the g* of the NEXT forward phase (8.3). A phase ends on success with
its own goal (terminal), at ``phase_step_limit`` (200 / 300 / 200) or at a hard reset (-> forward
phase). SAC as in RISC (14.2): log sigma clamp [-20, 10], 10k uniform warm-up steps, and
timeout-aware bootstrapping (RISC calls the non-bootstrapping VaPRL variant a bug, 8.4).

Curriculum (8.2), recomputed at the start of every backward phase (DEFAULT): candidates are the
state halves of the forward demos' observations followed by the backward demos' (final
next-states excluded); their distance to rho0 is the time index inside their demo (forward: steps
since the demo start; backward: steps remaining to the demo end, computed cleanly per demo, 8.1).
V(c, g*) = mean over 5 policy actions of min(Q1, Q2) of a separate value critic trained on the
SAC batches without entropy, each head bootstrapping from its own target (8.1). C(g*) = the
feasible candidate (V >= eps) nearest to rho0; if none is feasible, the candidate with the largest
V (DEFAULT). eps = kappa * V_max, V_max = reward_scale = 10 (sparse reward 1 at a terminal
success); kappa per env in suites/algorithms/vaprl.yaml, DEFAULT 0.5 everywhere (NOT FOUND).

Relabelling (8.3, DEFAULT): every online transition gets ``n_sampled_goals`` = 4 relabelled
copies, goals 50% future next-states of the same phase (own next state included) and 50% demo
candidate states; reward and terminal recomputed with ``task.is_success([s', g_new])``. The
copies are inserted when the phase ends (the future states are known only then), each as a
one-transition segment closed by ``truncated`` unless terminal (so it bootstraps under TAB).
Demo transitions are not relabelled. The buffer holds 1 + 2 * 4 steps per env step, hence the
large ``buffer_capacity`` bound (storage grows on demand).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import DemoSet, Task, demo_segments
from algorithms.common import load_rng_states, member_rngs, rng_states
from algorithms.goal_conditioned import FORWARD, AuxCritic, GCConfig, GoalConditioned

VALUE_STREAM, RELABEL_STREAM = 40, 43  # AuxCritic uses stream .. stream + 2


@dataclass
class VaPRLConfig(GCConfig):
    """Defaults: 8.1-8.3 (phase limit of tabletop; per-env values in suites/algorithms/vaprl.yaml)."""

    kappa: float = 0.5  # eps = kappa * V_max (DEFAULT, per-env values NOT FOUND)
    v_max: float = 10.0  # reward_scale * max reward, with termination at success
    n_sampled_goals: int = 4
    future_fraction: float = 0.5  # relabelled goals from future states of the phase; the rest demo states
    buffer_capacity: int = 100_000_000


def demo_time_index(terminals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position inside its demo, that demo's length) for every transition; demos end at terminals."""
    starts, demo = demo_segments(terminals)
    return np.arange(len(demo)) - starts[demo], np.bincount(demo)[demo]


def subgoal_candidates(forward, reverse, state_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Candidate states (N, state_dim), forward demos first, and their distance to rho0 (N,) (8.1)."""
    pos_f, _ = demo_time_index(forward.terminals)
    pos_b, len_b = demo_time_index(reverse.terminals)
    states = np.concatenate([forward.observations[:, :state_dim], reverse.observations[:, :state_dim]])
    return states.astype(np.float32), np.concatenate([pos_f, len_b - pos_b])


def choose_subgoal(values: np.ndarray, distance: np.ndarray, eps: float) -> int:
    """Index of the feasible (value >= eps) candidate with the smallest distance; if none, the largest value."""
    feasible = values >= eps
    if not feasible.any():
        return int(np.argmax(values))
    return int(np.argmin(np.where(feasible, distance, np.iinfo(np.int64).max)))


class VaPRL(GoalConditioned):
    """VaPRL: demo-state subgoal curriculum chosen by value, with HER-style relabelling."""

    Config = VaPRLConfig

    def __init__(self, task: Task, demos: DemoSet, cfg: VaPRLConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        self.candidates, self.distance = subgoal_candidates(demos.forward, demos.reverse, task.state_dim)
        self.value = AuxCritic(task.obs_dim, task.act_dim, seeds, cfg.sac(), device, VALUE_STREAM)
        self.relabel_rngs = member_rngs(seeds, RELABEL_STREAM)
        self.task_goal = np.zeros_like(self.goal)  # g* of the current / next forward phase
        self.subgoal_index = np.full(self.E, -1)  # last chosen candidate (diagnostic)
        self._phase: list[list[np.ndarray]] = [[] for _ in range(self.E)]  # [s, a, s'] rows of the open phase

    # -- goals ---------------------------------------------------------------------------------------
    def _draw_task_goals(self, mask: np.ndarray) -> None:
        goals = self.task.goal_states
        for i in np.flatnonzero(mask):
            self.task_goal[i] = goals[self.goal_rngs[i].integers(len(goals))]

    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        self._draw_task_goals(mask)
        super().on_reset(obs, mask)

    def phase_goals(self, mask: np.ndarray) -> np.ndarray:
        out = self.task_goal.copy()
        bwd = mask & (self.direction != FORWARD)
        if bwd.any():
            self._draw_task_goals(bwd)  # the backward subgoal serves the next forward phase's goal
            values = self.candidate_values(bwd)
            for i in np.flatnonzero(bwd):
                self.subgoal_index[i] = choose_subgoal(values[i], self.distance, self.cfg.kappa * self.cfg.v_max)
                out[i] = self.candidates[self.subgoal_index[i]]
        return out

    def candidate_values(self, mask: np.ndarray) -> np.ndarray:
        """V(c, g*) for every candidate c and each member's task goal: (E, N)."""
        sd = self.task.state_dim
        obs = np.empty((self.E, len(self.candidates), self.task.obs_dim), dtype=np.float32)
        obs[:, :, :sd] = self.candidates
        obs[:, :, sd:] = self.task_goal[:, None]
        obs_t = torch.as_tensor(obs, device=self.device)
        return self.value.policy_value(self.sac.actor, obs_t, mask, self.cfg.value_actions).cpu().numpy()

    # -- relabelling -----------------------------------------------------------------------------------
    def stored(self, obs: np.ndarray, next_obs: np.ndarray, end: np.ndarray) -> None:
        sd = self.task.state_dim
        rows = np.concatenate([obs[:, :sd], self._action, next_obs[:, :sd]], axis=1)
        for i in range(self.E):
            self._phase[i].append(rows[i])
        for i in np.flatnonzero(end):
            self._insert_relabelled(i, np.stack(self._phase[i]))
            self._phase[i] = []

    def relabelled(self, i: int, phase: np.ndarray) -> dict[str, np.ndarray]:
        """n_sampled_goals copies of every transition of member i's phase rows [s, a, s'] (T, .)."""
        sd, A, k = self.task.state_dim, self.task.act_dim, self.cfg.n_sampled_goals
        s, a, s2 = phase[:, :sd], phase[:, sd : sd + A], phase[:, sd + A :]
        T, rng = len(phase), self.relabel_rngs[i]
        src = np.repeat(np.arange(T), k)
        future = rng.random(T * k) < self.cfg.future_fraction
        future_goal = s2[rng.integers(src, T)]
        demo_goal = self.candidates[rng.integers(len(self.candidates), size=T * k)]
        goal = np.where(future[:, None], future_goal, demo_goal)
        next_obs = np.concatenate([s2[src], goal], axis=1).astype(np.float32)
        success = np.asarray(self.task.is_success(next_obs), dtype=bool)
        return {"obs": np.concatenate([s[src], goal], axis=1).astype(np.float32), "action": a[src],
                "next_obs": next_obs, "reward": success.astype(np.float32), "terminal": success}

    def _insert_relabelled(self, i: int, phase: np.ndarray) -> None:
        """Each relabelled transition as its own segment: FIRST [s, g] then the step to [s', g]."""
        r = self.relabelled(i, phase)
        n = len(r["reward"])

        def interleave(first, step):
            out = np.stack([first, step], axis=1)
            return torch.as_tensor(out.reshape(2 * n, *out.shape[2:]))[None]

        zeros = np.zeros(n, dtype=np.float32)
        steps = {
            "obs": interleave(r["obs"], r["next_obs"]),
            "action": interleave(np.zeros_like(r["action"]), r["action"]),
            "reward": interleave(zeros, r["reward"]),
            "terminal": interleave(zeros.astype(bool), r["terminal"]),
            "truncated": interleave(zeros.astype(bool), ~r["terminal"]),
        }
        self.buffer._append_steps(np.array([i]), steps, np.tile([True, False], n))

    # -- value critic ------------------------------------------------------------------------------------
    def update_aux(self, batch: dict) -> None:
        cfg = self.cfg
        m = self.sac.bootstrap_mask(batch["terminal"], batch["truncated"])
        scaled = cfg.reward_scale * batch["reward"]
        self.value.update(self.sac.actor, batch, lambda nxt: scaled[:, None] + cfg.gamma * m[:, None] * nxt)

    # -- checkpointing -------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        width = 2 * self.task.state_dim + self.task.act_dim
        phase = [np.stack(p) if p else np.zeros((0, width), dtype=np.float32) for p in self._phase]
        return {**super().state_dict(), "value": self.value.state_dict(), "relabel_rngs": rng_states(self.relabel_rngs),
                "task_goal": self.task_goal.copy(), "subgoal_index": self.subgoal_index.copy(), "phase": phase}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.value.load_state_dict(state["value"])
        load_rng_states(self.relabel_rngs, state["relabel_rngs"])
        self.task_goal[:] = state["task_goal"]
        self.subgoal_index[:] = state["subgoal_index"]
        self._phase = [list(p) for p in state["phase"]]

    def metrics(self) -> dict[str, np.ndarray]:
        d = self.distance[np.maximum(self.subgoal_index, 0)]
        return {**super().metrics(), "subgoal_distance": np.where(self.subgoal_index >= 0, d, np.nan)}
