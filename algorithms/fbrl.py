"""FBRL: forward-backward RL with a KNOWN reward for reaching rho0 (docs/algorithms.md section 6, [MC] fbrl.py).

Han et al. 2015 / Eysenbach et al. 2017 ("leave no trace"). Two SAC agents with identical settings:

- forward: obs [s, g_f], g_f drawn uniformly from the task goals at each backward->forward switch; r = 1[success(s', g_f)];
- backward: obs [s, g_b], g_b drawn uniformly from EARL's initial states (1 / 1 / 15) at each forward->backward switch
  (their goal coordinates where the goal is a few state coordinates: minitaur's start xy);
  r = 1[success(s', g_b)]: the task's own predicate and threshold applied with the initial state as goal (tabletop:
  gripper + mug within 0.2; door: handle within 0.02; peg: peg head within 0.05, hand ignored). This is the reward
  stored at collection time (the goal half of o' is g_b), so nothing is recomputed. On an env with a dense reward
  (kitchen, minitaur) both controllers store that reward under their goal instead, as EARL trained its baselines.
- switching: 300 steps, or success of the ACTIVE controller (early switch in both directions, stored terminal);
  hard reset -> forward phase with the reset observation's (freshly drawn) task goal.
- buffers: forward <- forward demos; backward <- backward demos as stored (their goal half is an initial state).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.api import BACKWARD, demo_arrays
from algorithms.forward_backward import ForwardBackward, ForwardBackwardConfig


@dataclass
class FBRLConfig(ForwardBackwardConfig):
    """fbrl.yaml of [MC]: the SAC defaults of section 3.3 and switch_every = 300."""


class FBRL(ForwardBackward):
    """Forward policy solves the task; backward policy returns to an EARL initial state."""

    label = "FBRL"
    Config = FBRLConfig
    backward_ends_on_success = True
    state_goals = False  # initial states become goals through their goal coordinates (Task.goal_of)
    task_reward = True

    def backward_demos(self) -> list[dict[str, np.ndarray]]:
        return [demo_arrays(self.demos.reverse)]

    def next_goal(self, i: int, phase: int) -> np.ndarray:
        return self.draw(i, self.task.goal_of(self.task.initial_states) if phase == BACKWARD else self.task.goal_states)
