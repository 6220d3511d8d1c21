"""Naive RL: one forward SAC agent run reset-free on the task reward (docs/algorithms.md section 4).

The episodic approach dropped into the autonomous setting: no backward policy, only EARL's hard resets every H_T.
The card's segmenting is a DEFAULT (NOT FOUND in the sources): the stream is cut into pseudo-episodes of
``episode_steps`` = 300 steps (MEDAL's policy_switch_frequency), a pseudo-episode ending early on task success
(stored terminal, like MEDAL's forward phase); at each cut the step is stored LAST, and a new segment starts from the
current state with a freshly drawn task goal (tabletop: one of 4; door/peg: the single goal). The env is never reset
by the algorithm. A hard reset starts a new segment with the reset observation's goal. Buffer <- forward demos
(``buffer_demos``).
No bootstrapping across cuts ([MC]-style, ``bootstrap_on_truncation=False``).

:class:`Naive` is also the single-controller base of :mod:`algorithms.oracle` (``episodic``: the env is reset at every
episode end, through ``observe``'s return value) and of :mod:`algorithms.gail` (hooks :meth:`Naive.reward` and
:meth:`Naive.learn_extra`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import Algorithm, DemoSet, Task, demo_arrays, setting
from algorithms.common import SACAlgoConfig, Timers, TrainLog, load_rng_states, member_rngs, rng_states, with_goal
from algorithms.core.buffer import SegmentReplayBuffer
from algorithms.core.nets import Stream
from algorithms.core.sac import SAC


@dataclass
class NaiveConfig(SACAlgoConfig):
    episode_steps: int = setting(300, "pseudo-episode length; 0 = the env's eval horizon H_E", ge=0, le=10**9)
    end_on_success: bool = setting(True, "success ends the (pseudo-)episode, stored terminal")
    random_seed_actions: bool = setting(False, "uniform actions in [-1, 1] during the seed phase (oracle.py of [MC])")
    buffer_demos: bool = setting(True, "the forward demos seed the replay buffer ([MC]); false: it starts empty "
                                 "(TF-Agents reset_free.py without --offline_dir)")


class Naive(Algorithm):
    """Forward SAC only; pseudo-episodes with a fresh task goal, no resets but EARL's hard ones."""

    label = "naive RL"
    Config = NaiveConfig
    state_goals = False  # only the env's own goals: runs where the goal is a few state coordinates (minitaur)
    task_reward = True  # the env's reward: EARL's dense reward on kitchen and minitaur
    episodic = False  # True: ask the loop to reset the env at every episode end instead of cutting

    def __init__(self, task: Task, demos: DemoSet, cfg: NaiveConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        E, O, A = self.E, task.obs_dim, task.act_dim
        self.agent = SAC(O, A, [s * 2 for s in seeds], cfg.sac(), device)
        self.buf = SegmentReplayBuffer(E, cfg.buffer_capacity, O, A, device, seeds, stream=Stream.REPLAY,
                                       name="replay buffer")
        # the demos end where success ends an episode: terminal if it does here, else a time-out (GAIL's 13.3)
        if cfg.buffer_demos:
            self.buf.add_demo(**demo_arrays(demos.forward), ends_terminal=cfg.end_on_success)
        self.horizon = cfg.episode_steps or task.eval_horizon
        self.rngs = member_rngs(seeds, stream=Stream.TASK_GOALS)  # task-goal draws at cuts, seed-phase actions
        self.goal = np.zeros((E, task.goal_dim), dtype=np.float32)
        self.episode_steps = np.zeros(E, dtype=np.int64)
        self.step = 0
        self._action = np.zeros((E, A), dtype=np.float32)
        self.timers = Timers(device)
        self.log = TrainLog(E, device)
        # The critic's Q at each (pseudo-)episode's first step beside the discounted, scaled task return the episode
        # then collected (episode/q_start, episode/return): with no bootstrap at the episode's end, Q(s0, a0)'s fixed
        # point is that return's expectation plus the entropy bonus (< 0 once the entropy is below zero), so a
        # q_start above the return is the critic overestimating. Task reward only (GAIL learns its own).
        self.q_start = np.full(E, np.nan)
        self.ret, self.ret_discount = np.zeros(E), np.ones(E)
        self._log_return = type(self).reward is Naive.reward

    # -- hooks for learned rewards (GAIL) ------------------------------------------------------------------------
    def reward(self, batch: dict[str, torch.Tensor]) -> torch.Tensor | None:
        """Rewards (E, B) for a sampled batch, recomputed now; None keeps the stored task reward."""
        return None

    def learn_extra(self, batch: dict[str, torch.Tensor]) -> None:
        """Extra learning after each SAC update (past the seed phase)."""

    # -- the protocol interface -----------------------------------------------------------------------------------
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        """Env reset (hard, or asked for): a new episode with the reset observation's goal."""
        self.goal[mask] = obs[mask, self.task.state_dim :]
        self.episode_steps[mask] = 0
        self.buf.start_segment(obs, mask)

    def act(self, obs: np.ndarray) -> np.ndarray:
        cfg = self.cfg
        seeding = self.step < cfg.seed_steps
        with self.timers("act"):
            if seeding and cfg.random_seed_actions:
                self._action = np.stack([r.uniform(-1.0, 1.0, self.task.act_dim) for r in self.rngs]).astype(np.float32)
            else:
                o = torch.as_tensor(with_goal(obs, self.goal, self.task.state_dim), device=self.device)
                action = self.agent.act(o)
                self._action = action.cpu().numpy()
                starts = self.episode_steps == 0
                if self._log_return and not seeding and starts.any():
                    self.q_start[starts] = self.agent.q_value(o, action).cpu().numpy()[starts]
        return self._action

    def update(self) -> None:
        """One SAC update on a replay batch (rewards from :meth:`reward`), then :meth:`learn_extra`; none in the seed
        phase."""
        if self.step < self.cfg.seed_steps:
            return
        with self.timers("buffer"):
            batch = self.buf.sample(self.cfg.batch_size)
        with self.timers("update"):
            self.log.add("sac/", self.agent.update(batch, reward=self.reward(batch)))
        self.learn_extra(batch)

    def metrics(self) -> dict[str, np.ndarray]:
        """sac/*: the agent's update diagnostics; episode/end_success: share of (pseudo-)episodes ending in success;
        episode/q_start and episode/return: mean Q(s0, a0) and discounted scaled task return of the episodes that
        ended (those started after the seed phase)."""
        return self.log.pop()

    def store(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> None:
        no = with_goal(next_obs, self.goal, self.task.state_dim)
        success = np.asarray(self.task.is_success(no), dtype=bool)
        # the task reward: 1[success] (EARL's sparse envs), or the env's dense reward (minitaur: EnvSpec.reward_fn)
        reward = np.asarray(self.task.compute_reward(no), dtype=np.float32)
        self.episode_steps += 1
        terminal = success & self.cfg.end_on_success
        cut = (self.episode_steps >= self.horizon) | terminal
        truncated = (cut | hard_reset) & ~terminal
        with self.timers("buffer"):
            self.buf.add(self._action, reward, no, terminal, truncated)
        self._stored = reward, terminal, cut

    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        """Episode ends: cut (a fresh task goal, a new segment) or, episodic, ask the loop for a reset."""
        sd = self.task.state_dim
        reward, terminal, cut = self._stored
        self.log.add_host("episode/", {"end_success": terminal}, cut | hard_reset)
        self._log_q_and_return(reward, cut | hard_reset)
        self.step += 1
        if self.episodic:
            return cut  # the loop resets these envs and calls on_reset
        new = cut & ~hard_reset  # hard resets start their segment in on_reset
        for i in np.flatnonzero(new):
            goals = self.task.goal_states
            self.goal[i] = goals[self.rngs[i].integers(len(goals))]
        if new.any():
            self.buf.start_segment(with_goal(next_obs, self.goal, sd), new)
            self.episode_steps[new] = 0
        return np.zeros(self.E, dtype=bool)

    def _log_q_and_return(self, reward: np.ndarray, ended: np.ndarray) -> None:
        if not self._log_return:
            return
        sac = self.agent.cfg
        self.ret += self.ret_discount * sac.reward_scale * reward
        self.ret_discount *= sac.gamma
        logged = ended & ~np.isnan(self.q_start)
        if logged.any():
            self.log.add_host("episode/", {"q_start": np.nan_to_num(self.q_start), "return": self.ret}, logged)
        self.q_start[ended], self.ret[ended], self.ret_discount[ended] = np.nan, 0.0, 1.0

    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        return self.agent.act(torch.as_tensor(obs, device=self.device), deterministic=True).cpu().numpy()

    # -- checkpointing --------------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"agent": self.agent.state_dict(), "buf": self.buf.state_dict(), "rngs": rng_states(self.rngs),
                "goal": self.goal.copy(), "episode_steps": self.episode_steps.copy(), "step": self.step,
                "q_and_return": np.stack([self.q_start, self.ret, self.ret_discount])}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.agent.load_state_dict(state["agent"])
        self.buf.load_state_dict(state["buf"])
        load_rng_states(self.rngs, state["rngs"])
        self.goal[:], self.episode_steps[:], self.step = state["goal"], state["episode_steps"], state["step"]
        if "q_and_return" in state:  # checkpoints before 2026-12-03 lack it: their open episodes go unlogged
            self.q_start[:], self.ret[:], self.ret_discount[:] = state["q_and_return"]
