"""Forward/backward controllers: the machinery FBRL, R3L, MEDAL and MEDAL's ablations share (docs/algorithms.md 6, 7, 9-11).

A forward SAC agent solves the task (the task reward on [s', g]: EARL's 1[success], or the env's dense reward on
kitchen and minitaur; the evaluated policy); a backward SAC agent
"resets" the system in its own way. Per member, the controllers alternate: a phase lasts ``switch_every`` (300) steps,
or ends early when the forward controller succeeds (and, where ``backward_ends_on_success``, when the backward one
reaches its own goal: FBRL). EARL's hard reset (every H_T) starts a forward phase with the reset observation's goal.

Per training step, in the reference code's order (9.4): choose the action with the active controller -> one SAC
update of the active controller only (a backward batch's reward may be recomputed now, :meth:`backward_reward`) ->
extra learning (:meth:`learn_extra`: discriminator, RND predictor) -> env step -> store. No update of any kind before
``seed_steps``.

Storage (2.1, 3.5): o and o' are stored with the goal that was active when the action was taken; the step ending a
phase is terminal (success) or truncated (time limit, hard reset), and the new phase starts a new segment (a FIRST
step carrying the new goal) in the new controller's buffer, so no transition spans two phases.

Subclasses choose through small hooks: the backward buffer's initial contents (:meth:`backward_demos`), the goal of a
new phase (:meth:`next_goal`; default = MEDAL's: a fresh task goal when the backward phase starts, kept for the
following forward phase), the backward reward (:meth:`backward_reward`; default the stored task reward under the
backward goal), the backward early-success rule (``backward_ends_on_success``), every stored backward state
(:meth:`on_backward_states`) and extra per-step learning (:meth:`learn_extra`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import BACKWARD, FORWARD, Algorithm, DemoSet, Task, demo_arrays, setting
from algorithms.common import SACAlgoConfig, Timers, TrainLog, load_rng_states, member_rngs, rng_states, with_goal
from algorithms.core.buffer import SegmentReplayBuffer
from algorithms.core.nets import Stream
from algorithms.core.sac import SAC


@dataclass
class ForwardBackwardConfig(SACAlgoConfig):
    switch_every: int = setting(300, "phase length in env steps (policy_switch_frequency, 6.2, 9.3)", ge=1, le=10**9)


class ForwardBackward(Algorithm):
    """Forward + backward SAC with per-member phases (see the module docstring); not registered itself."""

    Config = ForwardBackwardConfig
    phase_split_updates = True  # the forward and the backward controller each learn only in their members' phases
    backward_ends_on_success = False  # the backward phase also ends when [s', g_backward] succeeds (FBRL)

    def __init__(self, task: Task, demos: DemoSet, cfg: ForwardBackwardConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        E, O, A = self.E, task.obs_dim, task.act_dim
        sac_cfg = cfg.sac()
        self.forward = SAC(O, A, [s * 2 for s in seeds], sac_cfg, device)
        self.backward = SAC(O, A, [s * 2 + 1 for s in seeds], sac_cfg, device)
        cap = cfg.buffer_capacity
        self.fwd_buf = SegmentReplayBuffer(E, cap, O, A, device, seeds, stream=Stream.REPLAY, name="forward buffer")
        self.bwd_buf = SegmentReplayBuffer(E, cap, O, A, device, seeds, stream=Stream.BACKWARD_REPLAY,
                                           name="backward buffer")
        self.fwd_buf.add_demo(**demo_arrays(demos.forward))
        for d in self.backward_demos():
            self.bwd_buf.add_demo(**d)

        self.rngs = member_rngs(seeds, stream=Stream.TASK_GOALS)  # goal draws at switches
        self.phase = np.zeros(E, dtype=np.int64)
        self.phase_steps = np.zeros(E, dtype=np.int64)
        self.goal = np.zeros((E, task.goal_dim), dtype=np.float32)
        self.step = 0
        self._action = np.zeros((E, A), dtype=np.float32)
        self.timers = Timers(device)
        self.log = TrainLog(E, device)

    # -- hooks -------------------------------------------------------------------------------------
    def backward_demos(self) -> list[dict[str, np.ndarray]]:
        """Initial contents of the backward buffer, as ``add_demo`` keyword dicts (none by default)."""
        return []

    def next_goal(self, i: int, phase: int) -> np.ndarray:
        """Member i's goal for the phase it switches to (9.2): a fresh task goal for the backward phase, kept for the
        following forward phase."""
        return self.draw(i, self.task.goal_states) if phase == BACKWARD else self.goal[i]

    def backward_reward(self, batch: dict[str, torch.Tensor], mask: np.ndarray) -> torch.Tensor | None:
        """Rewards (E, B) for a sampled backward batch, recomputed now; None keeps the stored ones."""
        return None

    def on_backward_states(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Called with every observation stored in the backward buffer (FIRST states included)."""

    def learn_extra(self, bwd_batch: dict[str, torch.Tensor] | None, bwd_mask: np.ndarray) -> None:
        """Extra learning once per step past the seed phase, after the SAC updates."""

    def draw(self, i: int, options: np.ndarray) -> np.ndarray:
        """A uniform choice among ``options`` (rows) from member i's generator."""
        return options[self.rngs[i].integers(len(options))]

    # -- the protocol interface ----------------------------------------------------------------------
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Hard reset (or start): forward phase with the reset observation's goal (9.4)."""
        self.goal[mask] = obs[mask, self.task.state_dim :]
        self.phase[mask] = FORWARD
        self.phase_steps[mask] = 0
        self.fwd_buf.start_segment(obs, mask)

    def act(self, obs: np.ndarray) -> np.ndarray:
        fwd = self.phase == FORWARD
        bwd = ~fwd
        o = with_goal(obs, self.goal, self.task.state_dim)
        with self.timers("act"):
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
        return self._action

    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        return self.forward.act(torch.as_tensor(obs, device=self.device), deterministic=True).cpu().numpy()

    def update(self) -> None:
        """Past the seed phase: the acting controller of each member learns (forward: the task reward; backward:
        :meth:`backward_reward`), then :meth:`learn_extra` (MEDAL's discriminator, R3L's RND, ...)."""
        if self.step < self.cfg.seed_steps:
            return
        cfg, t = self.cfg, self.timers
        fwd = self.phase == FORWARD
        bwd = ~fwd
        if fwd.any():
            with t("buffer"):
                batch = self.fwd_buf.sample(cfg.batch_size, mask=fwd)
            with t("update"):
                self.log.add("forward/", self.forward.update(batch, fwd), fwd)
        bwd = bwd & (self.bwd_buf.n_valid > 0)  # a backward buffer may start empty (R3L)
        bwd_batch = None
        if bwd.any():
            with t("buffer"):
                bwd_batch = self.bwd_buf.sample(cfg.batch_size, mask=bwd)
            with t("update"):
                reward = self.backward_reward(bwd_batch, bwd)
                self.log.add("backward/", self.backward.update(bwd_batch, bwd, reward=reward), bwd)
        self.learn_extra(bwd_batch, bwd)

    def store(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> None:
        """The step into the acting controller's buffer with the task's reward under the phase's goal (1[success], or
        the env's dense reward), terminal on success (forward; backward where it ends on success), truncated at a
        switch or a hard reset."""
        no = with_goal(next_obs, self.goal, self.task.state_dim)
        success = np.asarray(self.task.is_success(no), dtype=bool)
        reward = np.asarray(self.task.compute_reward(no), dtype=np.float32)
        fwd = self.phase == FORWARD
        bwd = ~fwd
        self.phase_steps += 1
        terminal = success & (fwd | self.backward_ends_on_success)
        switch = (self.phase_steps >= self.cfg.switch_every) | terminal
        truncated = (switch | hard_reset) & ~terminal
        with self.timers("buffer"):
            for buf, m in ((self.fwd_buf, fwd), (self.bwd_buf, bwd)):
                if m.any():
                    buf.add(self._action, reward, no, terminal, truncated, m)
            if bwd.any():
                self.on_backward_states(no, bwd)
        self._stored = terminal, switch

    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        """Phase switches: at success or after ``switch_every`` steps, to the other controller with its next goal."""
        sd = self.task.state_dim
        terminal, switch = self._stored
        fwd = self.phase == FORWARD
        bwd = ~fwd
        with self.timers("buffer"):
            # switches (hard resets are handled by on_reset after the env reset)
            sw = switch & ~hard_reset
            to_bwd, to_fwd = sw & fwd, sw & bwd
            self.log.add_host("phase/", {"backward": bwd})
            self.log.add_host("phase/", {"forward_end_success": terminal}, fwd & (switch | hard_reset))
            for i in np.flatnonzero(to_bwd):
                self.goal[i] = self.next_goal(i, BACKWARD)
            for i in np.flatnonzero(to_fwd):
                self.goal[i] = self.next_goal(i, FORWARD)
            first = with_goal(next_obs, self.goal, sd)
            if to_bwd.any():
                self.bwd_buf.start_segment(first, to_bwd)
                self.on_backward_states(first, to_bwd)
            if to_fwd.any():
                self.fwd_buf.start_segment(first, to_fwd)
        self.phase[to_bwd] = BACKWARD
        self.phase[to_fwd] = FORWARD
        self.phase_steps[sw] = 0
        self.step += 1
        return np.zeros(self.E, dtype=bool)

    # -- checkpointing -------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "forward": self.forward.state_dict(),
            "backward": self.backward.state_dict(),
            "fwd_buf": self.fwd_buf.state_dict(),
            "bwd_buf": self.bwd_buf.state_dict(),
            "rngs": rng_states(self.rngs),
            "phase": self.phase.copy(),
            "phase_steps": self.phase_steps.copy(),
            "goal": self.goal.copy(),
            "step": self.step,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name in ("forward", "backward", "fwd_buf", "bwd_buf"):
            getattr(self, name).load_state_dict(state[name])
        load_rng_states(self.rngs, state["rngs"])
        for name in ("phase", "phase_steps", "goal"):  # in place: arrays keep their identity
            getattr(self, name)[:] = state[name]
        self.step = state["step"]

    def metrics(self) -> dict[str, np.ndarray]:
        """forward/* and backward/*: SAC diagnostics of each controller (while it acted); phase/backward: share of
        steps in the backward phase; phase/forward_end_success: share of forward phases that ended in success."""
        return self.log.pop()
