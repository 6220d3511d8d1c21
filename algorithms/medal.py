"""MEDAL: Matching Expert Distributions for Autonomous Learning (Sharma, Ahmad, Finn, ICML 2022).

docs/algorithms.md section 9. A forward SAC agent solves the task (sparse task reward); a backward SAC
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

The controller/phase machinery (switching, goals, buffers, checkpoints) is ``algorithms.forward_backward``; this module
adds the discriminator: its buffers, its reward and its update schedule.

``reward_form="logc"`` gives the section-10 ablation (``medal_logc``); ``positives="rho0"`` the
section-11 one (``fbrl_vice``): both are registered by their own small modules.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import DemoSet, Task, demo_arrays, demo_segments, setting
from algorithms.core.buffer import StateBuffer
from algorithms.core.discriminator import Discriminator
from algorithms.core.nets import Stream
from algorithms.forward_backward import ForwardBackward, ForwardBackwardConfig

__all__ = ["MEDAL", "MEDALConfig", "demo_states", "relabel_all_goals", "rho0_states"]


@dataclass
class MEDALConfig(ForwardBackwardConfig):
    """MEDAL defaults = the reference code's (docs/algorithms.md 9.3); switch_every = 300."""

    disc_every: int = setting(10, "one discriminator step every this many env steps", ge=1, le=10**9)
    disc_batch: int = setting(400, "positives per discriminator step (and as many negatives)", ge=1, le=65_536)
    disc_hidden: int = setting(128, "hidden width of the discriminator", ge=1, le=65_536)
    disc_lr: float = setting(3e-4, "Adam learning rate of the discriminator", gt=0, le=1)
    disc_mixup: bool = setting(True, "mixup (Beta(1,1)) of discriminator inputs and labels")
    reward_form: str = setting("medal", "backward reward: medal = -log(1 - C + eps), logc = log(C + eps)",
                               choices=("medal", "logc"))
    positives: str = setting("demos", "discriminator positives: forward demo states, or rho0 (initial states x "
                                      "task goals, FBRL + VICE)", choices=("demos", "rho0"))


def demo_states(demos) -> np.ndarray:
    """Every state of every demo trajectory: its first observation plus all next observations."""
    starts, _ = demo_segments(demos.terminals)
    return np.concatenate([demos.observations[starts], demos.next_observations]).astype(np.float32)


def rho0_states(task: Task) -> np.ndarray:
    """All pairs [s0, g]: EARL initial states x task goals (FBRL+VICE positives, section 11 DEFAULT)."""
    s0, g = task.initial_states, task.goal_states
    return np.concatenate([np.repeat(s0, len(g), 0), np.tile(g, (len(s0), 1))], 1).astype(np.float32)


def relabel_all_goals(demos, goals: np.ndarray, state_dim: int) -> list[dict[str, np.ndarray]]:
    """Copies of ``demos`` with the goal half overwritten by each goal in turn (9.5)."""
    out = []
    for g in goals:
        d = {k: np.array(v) for k, v in demo_arrays(demos).items()}
        d["observations"][:, state_dim:] = g
        d["next_observations"][:, state_dim:] = g
        out.append(d)
    return out


class MEDAL(ForwardBackward):
    """MEDAL: backward policy matches the demonstrations' state distribution (ICML 2022)."""

    label = "MEDAL"
    Config = MEDALConfig
    needs_demos = True  # the discriminator's positives are the forward demos' states (positives=demos)

    @classmethod
    def requires_demos(cls, cfg: MEDALConfig) -> bool:
        """Only positives=demos needs them (positives=rho0, FBRL + VICE, uses EARL's initial states)."""
        return cfg.positives == "demos"

    def __init__(self, task: Task, demos: DemoSet, cfg: MEDALConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        E, O = self.E, task.obs_dim
        self.disc = Discriminator(O, seeds, device, hidden_dim=cfg.disc_hidden, lr=cfg.disc_lr, mixup=cfg.disc_mixup)
        pos = demo_states(demos.forward) if cfg.positives == "demos" else rho0_states(task)
        self.pos_buf = StateBuffer(E, len(pos), O, device, seeds, stream=Stream.EXPERT_STATES,
                                   name="discriminator positives")
        self.pos_buf.extend(pos)
        self.neg_buf = StateBuffer(E, cfg.buffer_capacity, O, device, seeds, stream=Stream.AGENT_STATES,
                                   name="discriminator negatives")
        self._visited_mark = np.zeros(E, dtype=np.int64)  # negatives already counted in c_visited (a diagnostic)

    def backward_demos(self) -> list[dict[str, np.ndarray]]:
        """Forward demos + backward demos relabelled with every task goal (9.5)."""
        relabelled = relabel_all_goals(self.demos.reverse, self.task.goal_states, self.task.state_dim)
        return [demo_arrays(self.demos.forward), *relabelled]

    def backward_reward(self, batch, mask):
        return self.disc.reward(batch["next_obs"], self.cfg.reward_form)  # current discriminator (9.6)

    def on_backward_states(self, obs, mask):
        self.neg_buf.add(obs, mask=mask)  # every backward-phase state is a negative

    def learn_extra(self, bwd_batch, bwd_mask):
        """One discriminator step every ``disc_every`` global steps, whichever controller acts (9.3)."""
        cfg = self.cfg
        ready = self.neg_buf.size > 0
        if self.step % cfg.disc_every == 0 and ready.any():
            with self.timers("discriminator"):
                pos = self.pos_buf.sample(cfg.disc_batch, mask=ready)
                neg = self.neg_buf.sample(cfg.disc_batch, mask=ready)
                self.log.add("discriminator/", self.disc.update(pos, neg, ready), ready)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "disc": self.disc.state_dict(), "pos_buf": self.pos_buf.state_dict(),
                "neg_buf": self.neg_buf.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        for name in ("disc", "pos_buf", "neg_buf"):
            getattr(self, name).load_state_dict(state[name])
        self._visited_mark = self.neg_buf.size.copy()

    def metrics(self) -> dict[str, np.ndarray]:
        """As the forward-backward base, plus discriminator/c_visited: mean C, by the discriminator now, of the states
        the backward controller visited since the last call (the negatives added since then; NaN where none). The
        discriminator's own batches mix the whole history; the state-distribution matching shows as this number rising
        toward c_positives. Computed here, once per call, not on the per-step path."""
        out, size = super().metrics(), self.neg_buf.size
        c = np.full(self.E, np.nan)
        for i in np.flatnonzero(size > self._visited_mark):
            new = self.neg_buf.data["x"][i, self._visited_mark[i] : size[i]]  # member i's new negatives
            c[i] = self.disc.prob(new.expand(self.E, -1, -1))[i].mean().item()  # scored by member i's discriminator
        self._visited_mark = size.copy()
        return {**out, "discriminator/c_visited": c}
