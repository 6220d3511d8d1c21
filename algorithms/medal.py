"""MEDAL: Matching Expert Distributions for Autonomous Learning (Sharma, Ahmad, Finn, ICML 2022).

ALGORITHMS.md section 9. A forward SAC agent solves the task (sparse task reward); a backward SAC
agent is rewarded for visiting states that a discriminator C cannot tell apart from the forward
demonstrations' states, r_b = -log(1 - C(s') + 1e-10), so that the backward policy brings the
system to the states the expert visits (rho*) rather than back to rho0. Controllers alternate
every 300 steps, or when the forward controller succeeds; EARL's hard reset (every H_T) starts a
forward phase.

Per training step, in the reference code's order (9.4): choose the action with the active
controller -> one SAC update of the active controller only -> one discriminator step every 10th
step (both controllers' phases) -> env step -> store. No update of either kind before
``seed_steps``.

Conditioning (9.2): both agents see [s, g] with the same task goal g; a new goal is drawn at each
forward->backward switch and kept for the following forward phase. The discriminator sees the
full observation. Buffers (9.5): forward <- forward demos + forward phases; backward <- forward
demos + backward demos relabelled with every task goal + backward phases; positives <- forward
demo states (first state of each demo included); negatives <- every backward-phase state.

Where the reference code is buggy we follow its intended behaviour (3.6, 9.7):
- its replay buffer calls a boolean as a function on first sample; ours filters segment starts;
- its discriminator sampler draws without replacement and returns the state one slot before the
  index (and fails on door, whose positive set has exactly 400 states); we sample positives and
  negatives with replacement and use the stored states themselves;
- the actor loss's gradients never reach the critic (separate gradient computations).

``reward_form="logc"`` gives the section-10 ablation (``medal_logc``); ``positives="rho0"`` the
section-11 one (``fbrl_vice``): both are registered by their own small modules.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import Algorithm, DemoSet, Task
from algorithms.common import SACAlgoConfig, Timers, load_rng_states, member_rngs, rng_states, with_goal
from algorithms.core.buffer import SegmentReplayBuffer, StateBuffer
from algorithms.core.discriminator import Discriminator
from algorithms.core.sac import SAC

FORWARD, BACKWARD = 0, 1


@dataclass
class MEDALConfig(SACAlgoConfig):
    """MEDAL defaults = the reference code's (ALGORITHMS.md 9.3)."""

    switch_every: int = 300  # policy_switch_frequency
    disc_every: int = 10  # one discriminator step every 10 env steps
    disc_batch: int = 400  # positives per step (and as many negatives): 800 in all
    disc_hidden: int = 128
    disc_lr: float = 3e-4
    disc_mixup: bool = True
    reward_form: str = "medal"  # "medal": -log(1 - C + eps); "logc": log(C + eps) (section 10)
    positives: str = "demos"  # "demos": forward demo states; "rho0": initial states x task goals (section 11)


def demo_states(demos) -> np.ndarray:
    """Every state of every demo trajectory: its first observation plus all next observations."""
    starts = np.concatenate([[0], np.flatnonzero(demos.terminals)[:-1] + 1])
    return np.concatenate([demos.observations[starts], demos.next_observations]).astype(np.float32)


def rho0_states(task: Task) -> np.ndarray:
    """All pairs [s0, g]: EARL initial states x task goals (FBRL+VICE positives, section 11 DEFAULT)."""
    s0, g = task.initial_states, task.goal_states
    return np.concatenate([np.repeat(s0, len(g), 0), np.tile(g, (len(s0), 1))], 1).astype(np.float32)


def relabel_all_goals(demos, goals: np.ndarray, state_dim: int) -> list[dict[str, np.ndarray]]:
    """Copies of ``demos`` with the goal half overwritten by each goal in turn (9.5)."""
    out = []
    for g in goals:
        d = {k: np.array(getattr(demos, k)) for k in ("observations", "actions", "rewards", "terminals", "next_observations")}
        d["observations"][:, state_dim:] = g
        d["next_observations"][:, state_dim:] = g
        out.append(d)
    return out


class MEDAL(Algorithm):
    """MEDAL: backward policy matches the demonstrations' state distribution (ICML 2022)."""

    Config = MEDALConfig

    def __init__(self, task: Task, demos: DemoSet, cfg: MEDALConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        E, O, A = self.E, task.obs_dim, task.act_dim
        sac_cfg = cfg.sac()
        self.forward = SAC(O, A, [s * 2 for s in seeds], sac_cfg, device)
        self.backward = SAC(O, A, [s * 2 + 1 for s in seeds], sac_cfg, device)
        self.disc = Discriminator(O, seeds, device, hidden_dim=cfg.disc_hidden, lr=cfg.disc_lr, mixup=cfg.disc_mixup)
        cap = cfg.buffer_capacity
        self.fwd_buf = SegmentReplayBuffer(E, cap, O, A, device, seeds, stream=10, name="forward buffer")
        self.bwd_buf = SegmentReplayBuffer(E, cap, O, A, device, seeds, stream=11, name="backward buffer")
        self.fwd_buf.add_demo(**_arrays(demos.forward))
        self.bwd_buf.add_demo(**_arrays(demos.forward))
        for d in relabel_all_goals(demos.reverse, task.goal_states, task.state_dim):
            self.bwd_buf.add_demo(**d)
        pos = demo_states(demos.forward) if cfg.positives == "demos" else rho0_states(task)
        self.pos_buf = StateBuffer(E, len(pos), O, device, seeds, stream=12, name="discriminator positives")
        self.pos_buf.extend(pos)
        self.neg_buf = StateBuffer(E, cap, O, device, seeds, stream=13, name="discriminator negatives")

        self.rngs = member_rngs(seeds, stream=7)  # task-goal draws at forward->backward switches
        self.phase = np.zeros(E, dtype=np.int64)
        self.phase_steps = np.zeros(E, dtype=np.int64)
        self.goal = np.zeros((E, task.state_dim), dtype=np.float32)
        self.step = 0
        self._obs = np.zeros((E, O), dtype=np.float32)
        self._action = np.zeros((E, A), dtype=np.float32)
        self.timers = Timers(device)

    # -- the protocol interface ------------------------------------------------------------------
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Hard reset (or start): forward phase with the reset observation's goal (9.4)."""
        self.goal[mask] = obs[mask, self.task.state_dim :]
        self.phase[mask] = FORWARD
        self.phase_steps[mask] = 0
        self.fwd_buf.start_segment(obs, mask)

    def act(self, obs: np.ndarray) -> np.ndarray:
        cfg, t = self.cfg, self.timers
        fwd = self.phase == FORWARD
        bwd = ~fwd
        self._obs = o = with_goal(obs, self.goal, self.task.state_dim)
        with t("act"):
            ot = torch.as_tensor(o, device=self.device)
            if fwd.all():
                a = self.forward.act(ot)
            elif bwd.all():
                a = self.backward.act(ot)
            else:
                a_f = self.forward.act(ot, mask=fwd)
                a_b = self.backward.act(ot, mask=bwd)
                a = torch.where(torch.as_tensor(fwd, device=self.device)[:, None], a_f, a_b)
            self._action = a.cpu().numpy()
        if self.step >= cfg.seed_steps:
            self._update(fwd, bwd)
        return self._action

    def _update(self, fwd: np.ndarray, bwd: np.ndarray) -> None:
        cfg, t = self.cfg, self.timers
        if fwd.any():
            with t("buffer"):
                batch = self.fwd_buf.sample(cfg.batch_size, mask=fwd)
            with t("update"):
                self.forward.update(batch, fwd)
        if bwd.any():
            with t("buffer"):
                batch = self.bwd_buf.sample(cfg.batch_size, mask=bwd)
            with t("update"):
                reward = self.disc.reward(batch["next_obs"], cfg.reward_form)  # recomputed now (9.6)
                self.backward.update(batch, bwd, reward=reward)
        if self.step % cfg.disc_every == 0:
            ready = self.neg_buf.size > 0
            if ready.any():
                with t("discriminator"):
                    pos = self.pos_buf.sample(cfg.disc_batch, mask=ready)
                    neg = self.neg_buf.sample(cfg.disc_batch, mask=ready)
                    self.disc.update(pos, neg, ready)

    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        cfg, sd = self.cfg, self.task.state_dim
        no = with_goal(next_obs, self.goal, sd)
        success = np.asarray(self.task.is_success(no), dtype=bool)
        reward = success.astype(np.float32)
        fwd = self.phase == FORWARD
        bwd = ~fwd
        self.phase_steps += 1
        switch = (self.phase_steps >= cfg.switch_every) | (fwd & success)
        terminal = fwd & success
        truncated = (switch | hard_reset) & ~terminal
        with self.timers("buffer"):
            for buf, m in ((self.fwd_buf, fwd), (self.bwd_buf, bwd)):
                if m.any():
                    buf.add(self._action, reward, no, terminal, truncated, m)
            if bwd.any():
                self.neg_buf.add(no, mask=bwd)
            # switches (hard resets are handled by on_reset after the env reset)
            sw = switch & ~hard_reset
            to_bwd, to_fwd = sw & fwd, sw & bwd
            if to_bwd.any():
                for i in np.flatnonzero(to_bwd):  # new task goal, kept for the next forward phase
                    goals = self.task.goal_states
                    self.goal[i] = goals[self.rngs[i].integers(len(goals))]
                first = with_goal(next_obs, self.goal, sd)
                self.bwd_buf.start_segment(first, to_bwd)
                self.neg_buf.add(first, mask=to_bwd)
            if to_fwd.any():
                self.fwd_buf.start_segment(no, to_fwd)
        self.phase[to_bwd] = BACKWARD
        self.phase[to_fwd] = FORWARD
        self.phase_steps[sw] = 0
        self.step += 1
        return np.zeros(self.E, dtype=bool)

    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        return self.forward.act(torch.as_tensor(obs, device=self.device), deterministic=True).cpu().numpy()

    # -- checkpointing -----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "forward": self.forward.state_dict(),
            "backward": self.backward.state_dict(),
            "disc": self.disc.state_dict(),
            "fwd_buf": self.fwd_buf.state_dict(),
            "bwd_buf": self.bwd_buf.state_dict(),
            "pos_buf": self.pos_buf.state_dict(),
            "neg_buf": self.neg_buf.state_dict(),
            "rngs": rng_states(self.rngs),
            "phase": self.phase.copy(),
            "phase_steps": self.phase_steps.copy(),
            "goal": self.goal.copy(),
            "step": self.step,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.forward.load_state_dict(state["forward"])
        self.backward.load_state_dict(state["backward"])
        self.disc.load_state_dict(state["disc"])
        for name in ("fwd_buf", "bwd_buf", "pos_buf", "neg_buf"):
            getattr(self, name).load_state_dict(state[name])
        load_rng_states(self.rngs, state["rngs"])
        self.phase[:] = state["phase"]
        self.phase_steps[:] = state["phase_steps"]
        self.goal[:] = state["goal"]
        self.step = state["step"]

    def metrics(self) -> dict[str, np.ndarray]:
        return {"backward_fraction": (self.phase == BACKWARD).astype(np.float64)}


def _arrays(demos) -> dict[str, np.ndarray]:
    return {k: getattr(demos, k) for k in ("observations", "actions", "rewards", "terminals", "next_observations")}
