"""VaPRL: value-accelerated persistent RL (Sharma et al., NeurIPS 2021), docs/reproduction.md "VaPRL".

Two registered variants share this file:

- ``vaprl`` -- the method as published: the behaviour of the ORIGINAL VaPRL code (google-research
  ``reset_free_learning/reset_free.py``, TF-Agents, the code behind the EARL curves), wherever that code fixes it:
  plain 256-256 MLPs without the LayerNorm trunk, no bootstrapping across a phase end or hard reset (TF-Agents ends
  the episode there: discount 0), phases that end when the goal or subgoal is reached (a termination, then the goal
  switches: the code's ``use_reset_goals`` 3, ``GoalTerminalResetFreeWrapper``), hindsight relabelling of each
  finished phase with its final achieved state (``goal_relabel_type`` 0), subgoals chosen by the Lagrangian rule
  ``argmin_c ||c - mean(rho0)|| - lambda * V(c, g*)`` with lambda starting at 0 and raised by a dual Adam step
  whenever the chosen subgoals' value is below the threshold, V from the SAC critic itself (min over its two heads,
  mean over policy actions, ``use_minimum``: min(V(s_now -> c), V(c -> g*))).
- ``vaprl_risc`` -- RISC's re-implementation (Patil et al. 2024, ``gc_vaprl_sac``): LayerNorm trunk, timeout-aware
  bootstrapping, phases that end on success, 4 relabelled goals per transition (future states and demo states), a
  separate no-entropy value critic and the "nearest feasible demo state by time index" rule. It learns much faster
  than the published VaPRL curve (docs/reproduction.md, the VaPRL ablation).

Settings the original code leaves to per-experiment flags that were not published (DEFAULT, documented in
docs/reproduction.md): success ends the phase (``use_reset_goals`` 3; the flag's default 1, ``ResetFreeWrapper``, lets
the phase run on to its limit after the goal is reached: with it ``vaprl`` never succeeded to 300k on tabletop, 2 seeds,
while with 3 it passes the published 200k-300k window -- the ablation's ``vaprl_goal_terminal``), phase length
200 / 300 / 200 (RISC's values; the code's flag default is 400), the value threshold ``kappa * V_max`` with kappa 0.5
and V_max the most one phase can earn in the critic's units (:func:`value_ceiling`: one scaled reward, 10, when success
ends the phase; 866 for a 200-step phase that runs on), the multiplier's learning rate 3e-4 (flag default) and no upper
bound (flag default), one policy action per value estimate (flag default ``num_action_samples`` 1), no relabelling of
the demos (``relabel_demos`` off: the flag default of ``relabel_offline_data``; the ablation's ``vaprl_demo_relabel``
turns it on).

The curriculum's and relabelling's parts (subgoal rules, the Lagrange multiplier, relabelling, the goal test) are
plain functions in :mod:`algorithms.vaprl_curriculum`. Every config switch below selects one behaviour of one of the two codes, so an ablation restores one of them at a time.

Shared: ONE goal-conditioned SAC agent and ONE buffer holding the forward and backward demos
(:mod:`algorithms.goal_conditioned`); forward phases command a task goal g* (uniform); backward phases command the
curriculum subgoal C(g*) for the g* of the NEXT forward phase; a hard reset starts a forward phase; candidates are
the state halves of the forward then backward demos' observations (final next-states excluded), recomputed at the
start of every backward phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import FORWARD, DemoSet, Task, demo_segments, setting
from algorithms.common import load_rng_states, member_rngs, rng_states
from algorithms.core.nets import Stream, generator_states, load_generator_states, member_generators
from algorithms.goal_conditioned import AuxCritic, GCConfig, GoalConditioned, policy_value
from algorithms.vaprl_curriculum import (
    LagrangeMultiplier,
    choose_subgoal,
    cut_at_success,
    demo_prefix_relabel,
    final_state_relabel,
    goal_test,
    lagrangian_subgoal,
    parse_coords,
    subgoal_candidates,
    value_ceiling,
)

RELABEL = ("final", "final_failed", "future_demo", "none")
CURRICULUM = ("lagrangian", "nearest_feasible")
CANDIDATES = ("demos", "replay")
VALUE_CRITIC = ("sac", "separate")
TASK_GOAL_TEST = ("agent", "task")


@dataclass
class VaPRLConfig(GCConfig):
    """``vaprl``: the original code's behaviour (module docstring); per-env values in suites/algorithms/vaprl.yaml."""

    use_trunk: bool = False  # TF-Agents ActorDistributionNetwork / CriticNetwork: plain 256-256 MLPs
    bootstrap_on_truncation: bool = False  # phase end = TF-Agents termination (discount 0)
    success_ends_phase: bool = setting(True, "reaching the goal ends the phase (terminal; use_reset_goals 3); False: "
                                             "it earns reward and the phase runs to its limit (ResetFreeWrapper)")
    relabel: str = setting("final", "hindsight relabelling: final = one copy per phase with its final state, "
                                    "final_failed = only of phases that missed their goal, future_demo = RISC's "
                                    "n_sampled_goals per transition, none", choices=RELABEL)
    n_sampled_goals: int = setting(4, "future_demo: relabelled copies per transition", ge=1, le=1024)
    future_fraction: float = setting(0.5, "future_demo: share of goals from future states (the rest demo states)",
                                     ge=0, le=1)
    curriculum: str = setting("lagrangian", "subgoal rule: lagrangian = argmin L2(c, rho0) - lambda V, "
                                            "nearest_feasible = RISC's", choices=CURRICULUM)
    value_critic: str = setting("sac", "value for the curriculum: the SAC critic, or a separate no-entropy critic",
                                choices=VALUE_CRITIC)
    value_actions: int = 1  # num_action_samples of the original code
    candidates: str = setting("demos", "subgoal candidates: demos = the demo states (fixed), replay = num_candidates "
                                       "states drawn from the replay buffer once per phase_step_limit steps (the "
                                       "original code's flag default, num_reset_candidates)", choices=CANDIDATES)
    num_candidates: int = setting(1000, "replay: candidates per draw", ge=1, le=1_000_000)
    relabel_demos: bool = setting(False, "before training, add every demo prefix once more per later demo state, that "
                                         "state as its goal, cut at its first success (the original code's "
                                         "relabel_offline_data)")
    use_minimum: bool = setting(True, "V = min(V(s_now -> c), V(c -> g*)) (use_minimum)")
    exclude_solved: bool = setting(False, "never pick a candidate that already meets g*'s success test (not in the "
                                          "original; on sawyer_door such subgoals are reached without moving)")
    goal_coords: str = setting("", "state coordinates on which the agent judges reaching any goal (relabelled, subgoal, "
                                   "g*), comma-separated, e.g. 0,1,2,4,5,6; empty: the task's success coordinates")
    goal_threshold: float = setting(0.0, "L2 threshold of that judgement; 0: the task's success threshold", ge=0)
    task_goal_test: str = setting("agent", "which test judges reaching g* (the task's goal states) when goal_coords / "
                                           "goal_threshold set another: agent = that test, as every other goal; task = "
                                           "the task's own (EARL's)", choices=TASK_GOAL_TEST)
    kappa: float = setting(0.5, "value threshold = kappa * v_max (a DEFAULT: the per-env values were not found in the "
                                "sources)", ge=0, le=1e3)
    v_max: float = setting(0.0, "the threshold's unit; 0: the most one phase can earn in the critic's units, "
                                "reward_scale x (1 if success ends the phase, else (1 - gamma^H) / (1 - gamma), "
                                "H = phase_step_limit)", ge=0, le=1e9)
    lagrange_lr: float = setting(3e-4, "Adam learning rate of the multiplier (one step per phase_step_limit steps)",
                                 ge=0, le=1)
    lagrange_max: float = setting(math.inf, "upper clip of the multiplier", ge=0)
    buffer_capacity: int = 100_000_000

    def validate(self) -> None:
        super().validate()
        if self.candidates == "replay" and self.curriculum != "lagrangian":
            raise ValueError("candidates=replay needs curriculum=lagrangian (replay states have no demo time index)")
        parse_coords(self.goal_coords)


@dataclass
class VaPRLRISCConfig(VaPRLConfig):
    """``vaprl_risc``: RISC's re-implementation (gc_vaprl_sac); per-env values in suites/algorithms/vaprl_risc.yaml."""

    use_trunk: bool = True
    bootstrap_on_truncation: bool = True
    success_ends_phase: bool = True
    relabel: str = "future_demo"
    curriculum: str = "nearest_feasible"
    value_critic: str = "separate"
    value_actions: int = 5
    use_minimum: bool = False
    v_max: float = 10.0  # reward_scale x one terminal reward (success ends the phase): RISC's V range


class VaPRL(GoalConditioned):
    """VaPRL: demo-state subgoal curriculum chosen by value, with hindsight relabelling (module docstring)."""

    label = "VaPRL"
    Config = VaPRLConfig
    needs_demos = True  # the subgoal candidates are demo states

    @classmethod
    def check_task(cls, cfg: VaPRLConfig, task: Task) -> None:
        goal_test(task, cfg)  # goal_coords must name coordinates of this task's state

    def __init__(self, task: Task, demos: DemoSet, cfg: VaPRLConfig, seeds: list[int], device: torch.device):
        self.earl_task = task
        task = goal_test(task, cfg)
        super().__init__(task, demos, cfg, seeds, device)
        self.candidates, self.time_distance = subgoal_candidates(demos.forward, demos.reverse, task.state_dim)
        self.rho0 = np.asarray(task.initial_states, dtype=np.float32).mean(axis=0)
        self.l2_distance = np.linalg.norm(self.candidates - self.rho0, axis=1)
        if cfg.relabel_demos:
            for d in (demos.forward, demos.reverse):
                self.buffer.add_demo(**demo_prefix_relabel(d, task.state_dim, task.act_dim, task.is_success))
        self.value = (AuxCritic(task.obs_dim, task.act_dim, seeds, cfg.sac(), device, Stream.VALUE_CRITIC)
                      if cfg.value_critic == "separate" else None)
        self.sac_value_gens = member_generators(seeds, self.device, Stream.SAC_VALUE)
        self.lagrange = LagrangeMultiplier(self.E, cfg.lagrange_lr, cfg.lagrange_max)
        self.relabel_rngs = member_rngs(seeds, Stream.RELABEL)
        self.task_goal = np.zeros_like(self.goal)  # g* of the current / next forward phase
        self.subgoal_index = np.full(self.E, -1)  # last chosen candidate (diagnostic)
        self.replay_candidates: np.ndarray | None = None  # candidates=replay: this period's draw (E, N, state_dim)
        self._phase: list[list[np.ndarray]] = [[] for _ in range(self.E)]  # [s, a, s'] rows of the open phase

    def demo_rows(self, demos: DemoSet) -> list[dict[str, np.ndarray]]:
        """Under EARL's test the demos as given (each trajectory ends at its first success); under another goal test
        each trajectory re-judged by it (:func:`cut_at_success`), one ``add_demo`` call per trajectory."""
        if self.task is self.earl_task:
            return super().demo_rows(demos)
        rows = []
        for d in (demos.forward, demos.reverse):
            starts, segment = demo_segments(d.terminals)
            for a, b in zip(starts, np.append(starts[1:], len(segment))):
                rows.append(cut_at_success(d.observations[a:b], d.actions[a:b], d.next_observations[a:b],
                                           self.task.is_success))
        return rows

    @property
    def threshold(self) -> float:
        return self.cfg.kappa * value_ceiling(self.cfg)

    def success_ends_phase(self) -> bool:
        return self.cfg.success_ends_phase

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
            cands, l2, time = self.current_candidates(bwd)
            values = self.candidate_values(cands, bwd)
            allowed = [None] * self.E  # exclude_solved: only candidates not meeting g*'s test (all, if none is left)
            if self.cfg.exclude_solved:
                allowed = [a if a.any() else None for a in ~self.solved(cands)]
            for i in np.flatnonzero(bwd):
                if self.cfg.curriculum == "lagrangian":
                    k = lagrangian_subgoal(values[i], l2[i], self.lagrange.value[i], allowed[i])
                    self.lagrange.record(i, values[i, k])
                else:
                    k = choose_subgoal(values[i], time[i], self.threshold, allowed[i])
                self.subgoal_index[i] = k
                out[i] = cands[i, k]
                self.log.add_host("curriculum/", {"subgoal_value": values[:, k], "subgoal_l2_distance":
                                                  np.full(self.E, l2[i, k]), "subgoal_time_distance":
                                                  np.full(self.E, float(time[i, k]))}, np.arange(self.E) == i)
        return out

    def current_candidates(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per member: candidate states (E, N, state_dim), their L2 distance to mean(rho0) (E, N) and demo time
        index (E, N; NaN for replay states). ``demos``: the fixed demo states; ``replay``: ``num_candidates`` states
        each member drew from its replay buffer (demos, visited states, relabelled copies) at the period's start, as the
        original code's ``replay_buffer.get_next(num_reset_candidates)``."""
        E, sd = self.E, self.task.state_dim
        if self.cfg.candidates == "demos":
            n = len(self.candidates)
            return (np.broadcast_to(self.candidates, (E, n, sd)), np.broadcast_to(self.l2_distance, (E, n)),
                    np.broadcast_to(self.time_distance.astype(np.float64), (E, n)))
        if self.replay_candidates is None:
            self.draw_replay_candidates()
        states = self.replay_candidates
        return states, np.linalg.norm(states - self.rho0, axis=2), np.full(states.shape[:2], np.nan)

    def draw_replay_candidates(self) -> None:
        """candidates=replay: every member draws ``num_candidates`` states from its own buffer, kept until the next
        draw. The original draws once per ``reset_goal_frequency`` iterations (the phase length), so the subgoal
        choices of one period share a draw; the first draw comes at the first choice."""
        sd = self.task.state_dim
        self.replay_candidates = self.buffer.sample_states(self.cfg.num_candidates)[:, :, :sd].cpu().numpy()

    def _values(self, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """V(o) for obs (E, N, O): the configured critic, mean over ``value_actions`` policy actions of min_j Q_j."""
        obs_t = torch.as_tensor(obs, device=self.device)
        if self.value is not None:
            v = self.value.policy_value(self.sac.actor, obs_t, mask, self.cfg.value_actions)
        else:
            v = policy_value(self.sac.critic, self.sac.actor, obs_t, self.sac_value_gens, self.task.act_dim, mask,
                             self.cfg.value_actions)
        return v.cpu().numpy()

    def solved(self, cands: np.ndarray) -> np.ndarray:
        """(E, N): whether each member's candidate already meets the success test of its task goal g*."""
        return np.asarray(self.task.is_success(np.concatenate(
            [cands, np.broadcast_to(self.task_goal[:, None], cands.shape)], axis=2)), dtype=bool)

    def candidate_values(self, cands: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """V(c, g*) for each member's candidates ``cands`` (E, N, state_dim) and task goal: (E, N); with
        ``use_minimum`` the min with V(s_now, c), the value of reaching c from the state the backward phase starts
        in."""
        sd, N = self.task.state_dim, cands.shape[1]
        obs = np.empty((self.E, N, self.task.obs_dim), dtype=np.float32)
        obs[:, :, :sd] = cands
        obs[:, :, sd:] = self.task_goal[:, None]
        values = self._values(obs, mask)
        if self.cfg.use_minimum:
            obs[:, :, :sd] = self.phase_obs[:, None, :sd]
            obs[:, :, sd:] = cands
            values = np.minimum(values, self._values(obs, mask))
        return values

    # -- the loop ------------------------------------------------------------------------------------
    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        out = super().observe(next_obs, hard_reset)
        if self.cfg.curriculum == "lagrangian" and self.step % self.cfg.phase_step_limit == 0:
            self.lagrange.step(self.threshold)
            if self.cfg.candidates == "replay":
                self.draw_replay_candidates()
        return out

    # -- relabelling -----------------------------------------------------------------------------------
    def stored(self, obs: np.ndarray, next_obs: np.ndarray, end: np.ndarray) -> None:
        if self.cfg.relabel == "none":
            return
        sd = self.task.state_dim
        rows = np.concatenate([obs[:, :sd], self._action, next_obs[:, :sd]], axis=1)
        for i in range(self.E):
            self._phase[i].append(rows[i])
        for i in np.flatnonzero(end):
            phase = np.stack(self._phase[i])
            self._phase[i] = []
            if self.cfg.relabel == "future_demo":
                self._insert_relabelled(i, phase)
            elif self.cfg.relabel == "final" or not self.task.is_success(next_obs[i : i + 1])[0]:
                # final_failed: only phases whose last state misses their own goal (goal_relabel_type 1)
                copy = final_state_relabel(phase, sd, self.task.act_dim, self.task.is_success)
                self.buffer.add_demo(**copy, mask=np.arange(self.E) == i)

    def relabelled(self, i: int, phase: np.ndarray) -> dict[str, np.ndarray]:
        """``future_demo``: n_sampled_goals copies of every transition of member i's phase rows [s, a, s'] (T, .)."""
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
        # a copy is truncated only where the phase itself ended (its limit, a switch or a hard reset: not bootstrapped
        # without timeout-aware bootstrapping); a copy of any earlier transition bootstraps like the original
        truncated = ~success & (src == T - 1)
        return {"obs": np.concatenate([s[src], goal], axis=1).astype(np.float32), "action": a[src],
                "next_obs": next_obs, "reward": success.astype(np.float32), "terminal": success,
                "truncated": truncated}

    def _insert_relabelled(self, i: int, phase: np.ndarray) -> None:
        """Each relabelled transition as its own segment: FIRST [s, g] then the step to [s', g], terminal on success,
        truncated only for the phase's last transition (:meth:`relabelled`)."""
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
            "truncated": interleave(zeros.astype(bool), r["truncated"]),
        }
        self.buffer._append_steps(np.array([i]), steps, np.tile([True, False], n))

    # -- value critic ------------------------------------------------------------------------------------
    def update_aux(self, batch: dict) -> None:
        if self.value is None:
            return
        cfg = self.cfg
        m = self.sac.bootstrap_mask(batch["terminal"], batch["truncated"])
        scaled = cfg.reward_scale * batch["reward"]
        loss = self.value.update(self.sac.actor, batch, lambda nxt: scaled[:, None] + cfg.gamma * m[:, None] * nxt)
        self.log.add("value_critic/", {"loss": loss})

    # -- checkpointing -------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        width = 2 * self.task.state_dim + self.task.act_dim
        phase = [np.stack(p) if p else np.zeros((0, width), dtype=np.float32) for p in self._phase]
        state = {**super().state_dict(), "relabel_rngs": rng_states(self.relabel_rngs),
                 "sac_value_gens": generator_states(self.sac_value_gens), "lagrange": self.lagrange.state_dict(),
                 "task_goal": self.task_goal.copy(), "subgoal_index": self.subgoal_index.copy(), "phase": phase,
                 "replay_candidates": None if self.replay_candidates is None else self.replay_candidates.copy()}
        if self.value is not None:
            state["value"] = self.value.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        if self.value is not None:
            self.value.load_state_dict(state["value"])
        load_rng_states(self.relabel_rngs, state["relabel_rngs"])
        load_generator_states(self.sac_value_gens, state["sac_value_gens"])
        self.lagrange.load_state_dict(state["lagrange"])
        self.task_goal[:] = state["task_goal"]
        self.subgoal_index[:] = state["subgoal_index"]
        self._phase = [list(p) for p in state["phase"]]
        cands = state.get("replay_candidates")
        self.replay_candidates = None if cands is None else np.array(cands)

    def metrics(self) -> dict[str, np.ndarray]:
        """As the goal-conditioned base, plus curriculum/*: value and distances (L2 to rho0, time index) of the
        subgoals chosen in the period, and the Lagrange multiplier now; value_critic/loss (vaprl_risc)."""
        return {**super().metrics(), "curriculum/lagrange_multiplier": self.lagrange.value.copy()}


class VaPRLRISC(VaPRL):
    """RISC's re-implementation of VaPRL (gc_vaprl_sac); see the module docstring."""

    label = "VaPRL (RISC's re-implementation)"
    Config = VaPRLRISCConfig
