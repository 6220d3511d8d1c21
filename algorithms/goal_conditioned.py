"""Shared machinery of the goal-conditioned reset-free methods RISC (docs/algorithms.md 14) and VaPRL (8).

ONE goal-conditioned SAC agent serves both directions with ONE replay buffer (14.1, 14.5, 8.1):

- observations are [s, g] with g the goal of the current phase; each member has its own direction
  (FORWARD / BACKWARD), goal and phase step counter; every phase is one buffer segment;
- the buffer starts with the forward AND the backward demos, each with its own goal half (14.5);
- per step (14.6): act on [s_t, g] (uniform random actions during the first ``seed_steps`` steps,
  RISC's ``min_replay_history``, when ``random_warmup``) and ask the early-switch hook on s_t ->
  env step -> terminal = success([s_{t+1}, g]), r = the task reward of [s_{t+1}, g] (1[success], or the env's
  dense reward on kitchen and minitaur); truncated = not terminal and (phase limit or
  early switch or hard reset) -> store -> after the warm-up one update on a shared batch (the
  subclass's auxiliary critic first, then SAC) -> on terminal/truncated flip the direction and
  start the next phase with the goal hook's goal; a hard reset starts a forward phase instead.

Subclasses implement :meth:`GoalConditioned.phase_goals` and may override ``early_switch``
(RISC), ``stored`` (VaPRL's relabelling) and ``update_aux``. :class:`AuxCritic` is a second
member-batched twin-head critic of the SAC critic's architecture (RISC's success critic, VaPRL's
value critic). The algorithms/core SAC keeps its critic trunk inside its own optimizer, so an
auxiliary critic cannot share that trunk without core changes: it has a trunk of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch

from algorithms.api import AFTER_STORE, FORWARD, Algorithm, DemoSet, Task, demo_arrays, setting
from algorithms.common import (
    SACAlgoConfig,
    Timers,
    TrainLog,
    load_rng_states,
    member_rngs,
    rng_states,
    to_host,
    with_goal,
)
from algorithms.core import Stream, manual
from algorithms.core.buffer import SegmentReplayBuffer
from algorithms.core.nets import generator_states, host_mask, load_generator_states, member_generators, member_randn
from algorithms.core.optim import FlatMembers, MemberAdam, polyak_update
from algorithms.core.sac import SAC, Actor, Critic, SACConfig


@dataclass
class GCConfig(SACAlgoConfig):
    """SAC as used by RISC (14.2): log sigma clamp [-20, 10], timeout-aware bootstrapping."""

    log_std_max: float = 10.0
    bootstrap_on_truncation: bool = True
    phase_step_limit: int = setting(200, "steps after which a phase ends (200 / 300 / 200 per env)", ge=1, le=10**9)
    random_warmup: bool = setting(True, "uniform actions during seed_steps (RISC min_replay_history)")
    value_actions: int = setting(5, "policy actions per value estimate (num_actions_value_computation)", ge=1,
                                 le=1024)


@torch.no_grad()
def policy_value(heads: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], actor: Actor, obs: torch.Tensor,
                 generators: list[torch.Generator], act_dim: int, mask=None, n: int = 5) -> torch.Tensor:
    """Mean over n actions a ~ pi(.|o) of min_j heads(o, a)_j, for obs (E, N, O) -> (E, N); ``heads`` returns
    (E, 2, B) (a twin-head critic). Noise from each member's ``generators``; members outside ``mask`` draw none and
    their rows are meaningless."""
    E, N, _ = obs.shape
    rep = obs.repeat_interleave(n, dim=1)
    eps = member_randn(generators, (N * n, act_dim), host_mask(mask, E), obs.device)
    action, _ = actor.sample(rep, eps)
    return heads(rep, action).min(dim=1).values.view(E, N, n).mean(-1)


class AuxCritic:
    """Twin-head critic with the SAC critic's architecture (trunk, two heads on concat(features, a)), its own
    Polyak target, Adam and per-member noise streams; ``squash`` maps head outputs (e.g. to [0, 1])."""

    def __init__(self, obs_dim: int, act_dim: int, seeds: list[int], cfg: SACConfig, device, stream: int,
                 squash: Callable[[torch.Tensor], torch.Tensor] | None = None):
        E, self.act_dim, self.tau, self.device = len(seeds), act_dim, cfg.tau, torch.device(device)
        init = member_generators(seeds, "cpu", stream)
        self.net = Critic(E, obs_dim, act_dim, cfg, init).to(self.device)
        self.target = Critic(E, obs_dim, act_dim, cfg, init).to(self.device).requires_grad_(False)
        self.target.load_state_dict(self.net.state_dict())
        self.opt = MemberAdam(list(self.net.parameters()), E, lr=cfg.lr)
        self.target_flat = FlatMembers(list(self.target.parameters()), E)
        self.update_gens = member_generators(seeds, self.device, stream + 1)
        self.value_gens = member_generators(seeds, self.device, stream + 2)
        self.squash = squash

    def heads(self, obs: torch.Tensor, action: torch.Tensor, target: bool = False) -> torch.Tensor:
        """(E, 2, B) head outputs (squashed) at obs (E, B, O), action (E, B, A)."""
        x = (self.target if target else self.net)(obs, action)
        return x if self.squash is None else self.squash(x)

    def policy_value(self, actor: Actor, obs: torch.Tensor, mask=None, n: int = 5) -> torch.Tensor:
        """Mean over n actions a ~ pi(.|o) of min_j head_j(o, a), for obs (E, N, O) -> (E, N) (8.1, 14.3)."""
        return policy_value(self.heads, actor, obs, self.value_gens, self.act_dim, mask, n)

    def update(self, actor: Actor, batch: dict, target_fn: Callable[[torch.Tensor], torch.Tensor], mask=None):
        """One step on 0.5 * sum_j MSE(head_j(o, a), y), y = target_fn(target heads at (o', a')), a' ~ pi(.|o');
        then Polyak. ``target_fn`` returns (E, B) (one target for both heads) or (E, 2, B)."""
        E, B = batch["obs"].shape[:2]
        mask_host = host_mask(mask, E)
        with torch.no_grad():
            eps = member_randn(self.update_gens, (B, self.act_dim), mask_host, self.device)
            next_action, _ = actor.sample(batch["next_obs"], eps)
            y = target_fn(self.heads(batch["next_obs"], next_action, target=True))
            y = y.unsqueeze(1) if y.dim() == 2 else y
            x, cache = manual.critic_forward(self.net, batch["obs"], batch["action"])
        # dL/d head output through the squash by autograd on the small (E, 2, B) tensor; the networks' backward
        # passes are the hand-written ones of the SAC critic (algorithms.core.manual)
        x = x.requires_grad_()
        heads = x if self.squash is None else self.squash(x)
        loss = 0.5 * (heads - y).square().mean(dim=2).sum(dim=1)
        (d_x,) = torch.autograd.grad(loss.sum(), x)
        with torch.no_grad():
            grads, _ = manual.critic_backward(self.net, cache, d_x)
        self.opt.step(mask_host, grads)
        polyak_update(self.target_flat, self.opt.members, self.tau, mask_host)
        return loss.detach()

    def state_dict(self) -> dict[str, Any]:
        return {"net": self.net.state_dict(), "target": self.target.state_dict(), "opt": self.opt.state_dict(),
                "gens": generator_states(self.update_gens + self.value_gens)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.net.load_state_dict(state["net"])
        self.target.load_state_dict(state["target"])
        self.opt.load_state_dict(state["opt"])
        load_generator_states(self.update_gens + self.value_gens, state["gens"])


class GoalConditioned(Algorithm):
    """One goal-conditioned SAC agent for both directions; see the module docstring."""

    Config = GCConfig
    update_at = AFTER_STORE  # RISC's order: the critic learns from the step before the next goal is picked

    def __init__(self, task: Task, demos: DemoSet, cfg: GCConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        E, O, A = self.E, task.obs_dim, task.act_dim
        self.sac = SAC(O, A, seeds, cfg.sac(), device)
        self.buffer = SegmentReplayBuffer(E, cfg.buffer_capacity, O, A, device, seeds, stream=Stream.GC_REPLAY,
                                          name="replay buffer")
        for rows in self.demo_rows(demos):
            self.buffer.add_demo(**rows)
        self.goal_rngs = member_rngs(seeds, Stream.GC_GOALS)
        self.warmup_rngs = member_rngs(seeds, Stream.GC_WARMUP)
        self.direction = np.zeros(E, dtype=np.int64)
        self.phase_steps = np.zeros(E, dtype=np.int64)  # actions taken in the current phase
        self.phase_hit = np.zeros(E, dtype=bool)  # the current phase has reached its goal at some step
        self.goal = np.zeros((E, task.goal_dim), dtype=np.float32)
        self.step = 0
        self._obs = np.zeros((E, O), dtype=np.float32)
        self._action = np.zeros((E, A), dtype=np.float32)
        self._switch = np.zeros(E, dtype=bool)
        self.phase_obs = np.zeros((E, O), dtype=np.float32)  # env observation at the start of the newest phase
        self.timers = Timers(device)
        self.log = TrainLog(E, device)

    # -- hooks -------------------------------------------------------------------------------------
    def phase_goals(self, mask: np.ndarray) -> np.ndarray:
        """Goals (E, goal_dim) for the members in ``mask`` starting a phase in ``self.direction``."""
        raise NotImplementedError

    def switch_request(self, obs: torch.Tensor) -> torch.Tensor | None:
        """Device values (E,) that :meth:`early_switch` needs for s_t, or None; they reach the host together with the
        action, in one transfer."""
        return None

    def early_switch(self, values: np.ndarray | None) -> np.ndarray:
        """(E,) bool: end the phase after this step (decided on s_t, before the transition), from the host copy of
        :meth:`switch_request`'s values."""
        return np.zeros(self.E, dtype=bool)

    def stored(self, obs: np.ndarray, next_obs: np.ndarray, end: np.ndarray) -> None:
        """Called after each step is stored; ``end`` marks members whose phase just ended."""

    def update_aux(self, batch: dict) -> None:
        """Auxiliary-critic update on the SAC update's batch (before SAC's, as in 14.6 step 4)."""

    def success_ends_phase(self) -> bool:
        """Whether reaching the goal is terminal and ends the phase (RISC, 14.1). When False, success only earns the
        reward and the phase runs to its step limit (the original VaPRL code's default wrapper, 8.5)."""
        return True

    # -- the protocol interface ------------------------------------------------------------------
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Start (or hard reset): a forward phase (14.1)."""
        self.direction[mask] = FORWARD
        self.phase_steps[mask] = 0
        self.phase_hit[mask] = False
        self._begin_phase(obs, mask)

    def demo_rows(self, demos: DemoSet) -> list[dict[str, np.ndarray]]:
        """The demos as ``add_demo`` keyword arrays (one call each): as given, judged by EARL's success test."""
        return [demo_arrays(d) for d in (demos.forward, demos.reverse)]

    def _begin_phase(self, obs: np.ndarray, mask: np.ndarray) -> None:
        self.phase_obs = obs  # the state each new phase starts from (read by goal hooks)
        self.goal[mask] = self.phase_goals(mask)[mask]
        start = with_goal(obs, self.goal, self.task.state_dim)
        self.buffer.start_segment(start, mask)
        # how far each new phase starts from its goal on the success coordinates: a phase that starts at its goal
        # practises nothing (a curriculum stuck on subgoals its backward phases reach without moving shows here)
        fwd = self.direction == FORWARD
        distance = np.asarray(self.task.goal_distance(start), dtype=np.float64)
        at_goal = distance <= self.task.success_threshold
        # how far each forward phase starts from the evaluation's start states (rho0), on the whole state: the deployed
        # policy is tested from rho0, which reset-free training may rarely revisit between hard resets
        rho0 = np.linalg.norm(obs[:, None, : self.task.state_dim] - self.task.initial_states, axis=-1).min(axis=1)
        self.log.add_host("phase/", {"forward_start_distance": distance, "forward_starts_at_goal": at_goal,
                                     "forward_start_rho0_distance": rho0}, mask & fwd)
        self.log.add_host("phase/", {"backward_start_distance": distance, "backward_starts_at_goal": at_goal},
                          mask & ~fwd)

    def act(self, obs: np.ndarray) -> np.ndarray:
        self._obs = with_goal(obs, self.goal, self.task.state_dim)
        ot = torch.as_tensor(self._obs, device=self.device)
        with self.timers("act"):
            warmup = self.cfg.random_warmup and self.step < self.cfg.seed_steps
            action = None if warmup else self.sac.act(ot)
            action, values = to_host(action, self.switch_request(ot))  # the step's one device->host transfer
            if warmup:
                action = np.stack([r.uniform(-1.0, 1.0, self.task.act_dim) for r in self.warmup_rngs])
            self._action = action.astype(np.float32, copy=False)
        with self.timers("switch"):
            self._switch = self.early_switch(values)
        return self._action

    def store(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> None:
        """The step with the task's reward under the phase's goal (1[success], or the env's dense reward), terminal on
        success where success ends the phase, truncated at the phase's step limit, an early switch or a hard reset;
        then :meth:`stored` (relabelling)."""
        no = with_goal(next_obs, self.goal, self.task.state_dim)
        success = np.asarray(self.task.is_success(no), dtype=bool)
        reward = np.asarray(self.task.compute_reward(no), dtype=np.float32)
        terminal = success if self.success_ends_phase() else np.zeros_like(success)
        self.phase_steps += 1
        self.phase_hit |= success
        limit = self.phase_steps >= self.cfg.phase_step_limit
        truncated = ~terminal & (limit | self._switch | hard_reset)
        end = terminal | truncated
        with self.timers("buffer"):
            self.buffer.add(self._action, reward, no, terminal, truncated)
            self.stored(self._obs, no, end)
        self._stored = success, end

    def update(self) -> None:
        """Past the seed phase: :meth:`update_aux` (RISC's success critic, VaPRL's value critic), then one SAC update,
        on one replay batch that already holds the step just taken."""
        if self.step < self.cfg.seed_steps:
            return
        with self.timers("buffer"):
            batch = self.buffer.sample(self.cfg.batch_size)
        with self.timers("update"):
            self.update_aux(batch)
            self.log.add("sac/", self.sac.update(batch))

    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        """Phase ends: flip direction and pick the next goal (with the critic just updated)."""
        success, end = self._stored
        fwd = self.direction == FORWARD
        self.log.add_host("phase/", {"backward": ~fwd})
        self.log.add_host("phase/", {"forward_end_success": success, "forward_early_switch": self._switch & ~success},
                          fwd & end)
        self.log.add_host("phase/", {"backward_end_success": success}, ~fwd & end)
        self.log.add_host("phase/", {"forward_any_success": self.phase_hit}, fwd & end)
        self.log.add_host("phase/", {"backward_any_success": self.phase_hit}, ~fwd & end)
        self.phase_hit[end] = False
        flip = end & ~hard_reset  # a hard reset starts a forward phase in on_reset
        self.direction[flip] = 1 - self.direction[flip]
        self.phase_steps[end] = 0
        if flip.any():
            with self.timers("goals"):
                self._begin_phase(next_obs, flip)
        self.step += 1
        return np.zeros(self.E, dtype=bool)

    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        return self.sac.act(torch.as_tensor(obs, device=self.device), deterministic=True).cpu().numpy()

    # -- checkpointing -----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "sac": self.sac.state_dict(), "buffer": self.buffer.state_dict(),
            "goal_rngs": rng_states(self.goal_rngs), "warmup_rngs": rng_states(self.warmup_rngs),
            "direction": self.direction.copy(), "phase_steps": self.phase_steps.copy(), "goal": self.goal.copy(),
            "step": self.step, "phase_hit": self.phase_hit.copy(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.sac.load_state_dict(state["sac"])
        self.buffer.load_state_dict(state["buffer"])
        load_rng_states(self.goal_rngs, state["goal_rngs"])
        load_rng_states(self.warmup_rngs, state["warmup_rngs"])
        self.direction[:] = state["direction"]
        self.phase_steps[:] = state["phase_steps"]
        self.goal[:] = state["goal"]
        self.step = state["step"]
        self.phase_hit[:] = state.get("phase_hit", False)  # checkpoints before the any-success diagnostic: none yet

    def metrics(self) -> dict[str, np.ndarray]:
        """sac/*: the agent's update diagnostics; phase/*: share of steps in backward phases, and of forward
        (backward) phases that ended in success, that reached their goal at any step (the same when success ends the
        phase), or (RISC) ended by an early switch; of phases that began already at their goal, and their mean
        distance to it at the start (success coordinates); forward phases' mean distance at the start from the nearest
        initial state (whole state: how far from where the deployed policy is tested)."""
        return self.log.pop()
