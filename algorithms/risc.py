"""RISC: Reset-free RL with Intelligently Switching Controller (Patil et al., ICLR 2024), docs/algorithms.md 14.

One goal-conditioned SAC agent and one buffer (forward + backward demos) for both directions
(:mod:`algorithms.goal_conditioned`). Forward goals are drawn uniformly from the task goals,
backward goals uniformly from EARL's initial states, at the start of every phase. A phase ends on
success (terminal), at ``phase_step_limit`` steps, on a hard reset, or by the success-probability
switcher (14.4): at phase step t (counted from 1, evaluated on s_t before the transition, in both
directions), if t >= ``minimum_steps`` the step is eligible with probability
``trajectory_proportion`` -- redrawn at EVERY step, as the published code effectively does
(14.7.2) -- and an eligible step switches with probability P_hat(s_t, g) * (1 - c^t).

Success critic (14.3): twin heads squashed by (1 - cos x) / 2, target
terminal + (1 - terminal) * gamma * min_j P_target_j(s', a'), a' ~ pi(.|s', g), no reward scale,
no entropy, bootstrapping through truncations always; loss 0.5 * sum_j MSE; Adam 3e-4, Polyak
0.005; trained on every SAC update batch. P_hat(s, g) = mean over 5 policy actions of the min head.

SAC (14.2): log sigma clamp [-20, 10], trunk Linear-LayerNorm-Tanh, 10k steps of uniform random
actions without updates, then one update per step. ``RISC`` bootstraps through time-outs and
switches (TAB, the paper's method, 14.7.1 DEFAULT); ``RISCNoTAB`` treats them as terminal.

Deviations (documented):
- The success critic has its own trunk (same architecture) instead of sharing the Q-critic's trunk
  module: the core SAC owns its trunk's optimizer state (a flat member-batched Adam), which a second
  optimizer cannot share without changing algorithms/core.
- The success critic is updated before the SAC update on the same batch (RISC: Q-critic, success
  critic, actor, ...): with separate networks this is the same computation (same actor state).
Not a deviation: the switcher also runs during the warm-up (on the untrained success critic), as in RISC's code,
whose agent asks ``should_switch`` at every training step, warm-up included.
Per-env values (14.4) live in suites/algorithms/risc.yaml; the dataclass defaults are tabletop's (minitaur: its
risc_minitaur.yaml; kitchen, which RISC never ran: the phase limit is the evaluation horizon, as in every released
config). On kitchen and minitaur the reward is the env's dense reward under the phase's goal (RISC's minitaur config:
``reward_type: dense``, ``env.compute_reward`` of the observation with the goal). Minitaur's goal is the base xy only:
backward goals come from :meth:`RISC.backward_goal_pools` (``backward_goal``; DEFAULT what RISC's released code does).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from algorithms.api import FORWARD, DemoSet, Task, setting
from algorithms.common import load_rng_states, member_rngs, rng_states
from algorithms.core.nets import Stream
from algorithms.goal_conditioned import AuxCritic, GCConfig, GoalConditioned


@dataclass
class RISCConfig(GCConfig):
    """Defaults: risc_tm.yaml with timeout-aware bootstrapping on (14.2, 14.4, 14.7.1)."""

    config_file: ClassVar[str] = "risc"  # risc_no_tab shares the per-env values of suites/algorithms/risc.yaml

    phase_step_limit: int = 200
    conservative_factor: float = setting(0.9, "c of the switch probability P_hat * (1 - c^t)", ge=0, le=1)
    minimum_steps: int = setting(100, "no early switch before this phase step", ge=0, le=10**9)
    trajectory_proportion: float = setting(1.0, "probability that a step may switch early", ge=0, le=1)
    backward_goal: str = setting(
        "reset_observation", "backward goals where the goal is a few state coordinates (minitaur): reset_observation = "
        "the goal coordinates of one reset observation per run, as RISC's released code takes them (on minitaur: the "
        "task goal drawn at that reset); initial_state = the initial states' goal coordinates (the start position)",
        choices=("reset_observation", "initial_state"))


@dataclass
class RISCNoTABConfig(RISCConfig):
    """RISC w/o timeout-aware bootstrapping (the released yaml's trunc_as_terminal: true)."""

    bootstrap_on_truncation: bool = False


def success_squash(x: torch.Tensor) -> torch.Tensor:
    return (1.0 - torch.cos(x)) / 2.0


def success_target(terminal: torch.Tensor, next_heads: torch.Tensor, gamma: float) -> torch.Tensor:
    """terminal + (1 - terminal) * gamma * min_j P_target_j(s', a'); terminal (E, B), next_heads (E, 2, B)."""
    t = terminal.float()
    return t + (1.0 - t) * gamma * next_heads.min(dim=1).values


def switch_probability(p_hat: np.ndarray, t: np.ndarray, c: float, minimum_steps: int) -> np.ndarray:
    """Probability that an ELIGIBLE step t switches: P_hat * (1 - c^t) once t >= minimum_steps, else 0."""
    t = np.asarray(t, dtype=np.float64)
    return np.where(t >= minimum_steps, np.asarray(p_hat, dtype=np.float64) * (1.0 - c**t), 0.0)


class RISC(GoalConditioned):
    """RISC with timeout-aware bootstrapping (the method of the paper)."""

    label = "RISC"
    Config = RISCConfig
    state_goals = False  # backward goals are projected onto the goal coordinates (backward_goal_pools)
    task_reward = True  # the task's reward under the phase's goal: dense on kitchen and minitaur (RISC: reward_type)

    def __init__(self, task: Task, demos: DemoSet, cfg: RISCConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        self.success = AuxCritic(task.obs_dim, task.act_dim, seeds, cfg.sac(), device, Stream.SUCCESS_CRITIC,
                                 success_squash)
        self.switch_rngs = member_rngs(seeds, Stream.SWITCH)
        self.switches = np.zeros(self.E)  # early switches so far (diagnostic)
        self.backward_pools = self.backward_goal_pools(cfg.backward_goal)

    def backward_goal_pools(self, how: str) -> list[np.ndarray]:
        """Per member, the goals its backward phases draw from: EARL's initial states, or where the goal is only some
        state coordinates (minitaur) their goal coordinates (``initial_state``) or, as RISC's released code computes
        them, the goal half of one reset observation (``reset_observation``: ``risc/envs/earl.py`` keeps
        ``initial_states[:, -goal_dim:]`` of the 32-dim observation its EARL fork returns, which is the goal that reset
        drew, not the start position). That goal is drawn here, once per member, from its goal generator."""
        task = self.task
        if task.goal_dim == task.state_dim:
            return [task.initial_states] * self.E
        if how == "initial_state":
            return [task.goal_of(task.initial_states)] * self.E
        return [task.goal_states[r.integers(len(task.goal_states))][None] for r in self.goal_rngs]

    def phase_goals(self, mask: np.ndarray) -> np.ndarray:
        out = np.zeros_like(self.goal)
        for i in np.flatnonzero(mask):
            pool = self.task.goal_states if self.direction[i] == FORWARD else self.backward_pools[i]
            out[i] = pool[self.goal_rngs[i].integers(len(pool))]
        return out

    def success_probability(self, obs: torch.Tensor, mask=None) -> torch.Tensor:
        """P_hat(s, g) for obs (E, O) -> (E,) on the device (14.3)."""
        p = self.success.policy_value(self.sac.actor, obs[:, None], mask, self.cfg.value_actions)
        return p[:, 0]

    def switch_request(self, obs: torch.Tensor) -> torch.Tensor | None:
        """Which members may switch at this step (host draws, kept for :meth:`early_switch`) and, if any, their P_hat
        (E,) on the device."""
        cfg = self.cfg
        t = self.phase_steps + 1
        self._eligible = eligible = np.zeros(self.E, dtype=bool)
        for i in np.flatnonzero(t >= cfg.minimum_steps):
            eligible[i] = self.switch_rngs[i].random() < cfg.trajectory_proportion
        return self.success_probability(obs, eligible) if eligible.any() else None

    def early_switch(self, p_hat: np.ndarray | None) -> np.ndarray:
        """Switch an eligible member with probability P_hat * (1 - c^t) (14.4)."""
        switch = np.zeros(self.E, dtype=bool)
        if p_hat is None:
            return switch
        cfg = self.cfg
        p = switch_probability(p_hat, self.phase_steps + 1, cfg.conservative_factor, cfg.minimum_steps)
        for i in np.flatnonzero(self._eligible):
            switch[i] = self.switch_rngs[i].random() < p[i]
        self.switches += switch
        return switch

    def update_aux(self, batch: dict) -> None:
        gamma = self.cfg.gamma
        loss = self.success.update(self.sac.actor, batch, lambda nxt: success_target(batch["terminal"], nxt, gamma))
        self.log.add("success_critic/", {"loss": loss})

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "success": self.success.state_dict(),
                "switch_rngs": rng_states(self.switch_rngs), "switches": self.switches.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.success.load_state_dict(state["success"])
        load_rng_states(self.switch_rngs, state["switch_rngs"])
        self.switches[:] = state["switches"]

    def metrics(self) -> dict[str, np.ndarray]:
        return {**super().metrics(), "switch/early_switches_total": self.switches.copy()}


class RISCNoTAB(RISC):
    """RISC w/o timeout-aware bootstrapping: truncations (time limit, switch, hard reset) mask the bootstrap."""

    label = "RISC w/o TAB"
    Config = RISCNoTABConfig
