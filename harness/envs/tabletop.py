"""EARL's tabletop organization task (``tabletop_manipulation``), as pure kinematics.

EARL's ``TabletopManipulation`` is a MuJoCo env that never steps physics: every action sets the
gripper ("fist") and mug positions directly (``set_state`` + ``forward``). We reproduce that
arithmetic exactly, in float64 like MuJoCo's qpos, without MuJoCo: 4 planar coordinates and a
grasp flag. The MuJoCo model (``assets/tabletop/tabletop_manipulation.xml`` from the EARL data
directory) is loaded only to render.

Semantics (docs/algorithms.md 1.1, EARL ``envs/tabletop_manipulation.py``):

- observation (12, float32): fist xy, mug xy, attached flag pair ((-1,-1) free, (0,0) holding),
  then the 6-dim goal with the same layout;
- action (3) in [-1, 1], clipped, mapped affinely to [-0.2, 0.2]; ``a[2] > 0`` grasps the mug if
  it is within 0.4 of the fist (before moving), ``<= 0`` releases; positions are clipped to +-2.8;
- reset: fist (0, 0), mug (2.5, 0), free; goal drawn uniformly from the 4 task goals;
- sparse reward / success: ``||s[0:4] - g[0:4]|| <= 0.2``.

Differences from EARL, on purpose: goals are drawn from ``self.np_random`` (EARL used the global
``random`` module, unseeded), and ``reset(options=...)`` can set any state and goal.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from harness.envs.base import EarlEnv, EnvInfo, EnvSpec

INITIAL_STATE = np.array([0.0, 0.0, 2.5, 0.0, -1.0, -1.0])
GOAL_STATES = np.array(
    [
        [0.0, 0.0, -2.5, -1.0, -1.0, -1.0],
        [0.0, 0.0, -2.5, 1.0, -1.0, -1.0],
        [0.0, 0.0, 0.0, 2.0, -1.0, -1.0],
        [0.0, 0.0, 0.0, -2.0, -1.0, -1.0],
    ]
)

TABLETOP_SPEC = EnvSpec(
    name="tabletop_manipulation",
    gym_id="earl/TabletopManipulation-v0",
    state_dim=6,
    act_dim=3,
    success_idx=(0, 1, 2, 3),
    success_threshold=0.2,
    train_horizon=200_000,
    eval_horizon=200,
    initial_states=INITIAL_STATE[None].copy(),
    goal_states=GOAL_STATES.copy(),
)

GRASP_RADIUS = 0.4
LIMIT = 2.8
_LB, _UB = -0.2, 0.2


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class TabletopManipulationEnv(EarlEnv):
    """Gymnasium env ``earl/TabletopManipulation-v0`` (see module docstring)."""

    spec_ = TABLETOP_SPEC

    def __init__(self, render_mode: str | None = None, width: int = 240, height: int = 240):
        super().__init__(render_mode)
        self._fist = [0.0, 0.0]
        self._mug = [2.5, 0.0]
        self._attached = False
        self._set_goal(GOAL_STATES[0].copy())
        self._render_size = (height, width)
        self._renderer = None

    # -- gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "state" in options:
            obs = np.asarray(options["state"], dtype=np.float64)
            if obs.shape != (12,):
                raise ValueError(f"options['state'] must be a 12-dim observation, got shape {obs.shape}")
            self._fist = [float(obs[0]), float(obs[1])]
            self._mug = [float(obs[2]), float(obs[3])]
            self._attached = bool(obs[4] > -0.5)
            goal = obs[6:]
        else:
            self._fist = [float(INITIAL_STATE[0]), float(INITIAL_STATE[1])]
            self._mug = [float(INITIAL_STATE[2]), float(INITIAL_STATE[3])]
            self._attached = False
            goal = None
        if "goal" in options:
            goal = np.asarray(options["goal"], dtype=np.float64)
            if goal.shape != (6,):
                raise ValueError(f"options['goal'] must be a 6-dim state, got shape {goal.shape}")
        self._set_goal(np.array(goal, dtype=np.float64) if goal is not None else self.sample_goal())
        obs = self._obs()
        return obs, {"success": bool(self.spec_.is_success(obs))}

    def step(self, action):
        # EARL: np.clip(float32 action, float64 bounds) then an affine map, in float64.
        a0, a1, a2 = (action.tolist() if isinstance(action, np.ndarray) else list(action))[:3]
        dx = _LB + (_clip(a0, -1.0, 1.0) + 1.0) * 0.5 * (_UB - _LB)
        dy = _LB + (_clip(a1, -1.0, 1.0) + 1.0) * 0.5 * (_UB - _LB)
        grip = _LB + (_clip(a2, -1.0, 1.0) + 1.0) * 0.5 * (_UB - _LB)
        fx, fy = self._fist
        if grip > 0:
            if not self._attached:
                ex, ey = fx - self._mug[0], fy - self._mug[1]
                self._attached = math.sqrt(ex * ex + ey * ey) < GRASP_RADIUS
        else:
            self._attached = False
        nx, ny = _clip(fx + dx, -LIMIT, LIMIT), _clip(fy + dy, -LIMIT, LIMIT)
        if self._attached:
            self._mug = [
                _clip(self._mug[0] + (nx - fx), -LIMIT, LIMIT),
                _clip(self._mug[1] + (ny - fy), -LIMIT, LIMIT),
            ]
        self._fist = [nx, ny]
        obs = self._obs()
        d = obs[0:4] - obs[6:10]  # EARL's predicate on the float32 observation
        success = bool(math.sqrt(float(np.dot(d, d))) <= TABLETOP_SPEC.success_threshold)
        return obs, float(success), False, False, {"success": success}

    def _set_goal(self, goal: np.ndarray) -> None:
        self._goal = goal
        self._goal_list = goal.tolist()

    def _obs(self) -> np.ndarray:
        flag = 0.0 if self._attached else -1.0
        return np.array([*self._fist, *self._mug, flag, flag, *self._goal_list], dtype=np.float32)

    # -- checkpointing ---------------------------------------------------------------------------
    def get_sim_state(self) -> dict[str, Any]:
        return {
            "fist": list(self._fist),
            "mug": list(self._mug),
            "attached": self._attached,
            "goal": self._goal.copy(),
            "rng": self._rng_state(),
        }

    def set_sim_state(self, state: dict[str, Any]) -> None:
        self._fist = list(state["fist"])
        self._mug = list(state["mug"])
        self._attached = bool(state["attached"])
        self._set_goal(np.array(state["goal"], dtype=np.float64))
        self._set_rng_state(state["rng"])

    # -- rendering through EARL's MuJoCo model -----------------------------------------------------
    def render(self):
        if self.render_mode != "rgb_array":
            return None
        import mujoco

        from harness.data import asset_path

        if self._renderer is None:
            model = mujoco.MjModel.from_xml_path(str(asset_path("tabletop", "tabletop_manipulation.xml")))
            self._mj = (model, mujoco.MjData(model))
            try:
                self._renderer = mujoco.Renderer(model, *self._render_size)
            except Exception as e:  # no GL backend
                raise RuntimeError(
                    f"cannot render: no OpenGL backend for MuJoCo ({type(e).__name__}); "
                    "install libosmesa6 and set MUJOCO_GL=osmesa (or MUJOCO_GL=egl with a GPU)"
                ) from e
        model, data = self._mj
        data.qpos[:4] = [*self._fist, *self._mug]
        data.qpos[4] = -10.0  # EARL parks its unused 'random_joint' here
        mujoco.mj_forward(model, data)
        self._renderer.update_scene(data)
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


#: the harness's catalogue entry (registered in ``harness.envs.ENVS``)
TABLETOP = EnvInfo(
    spec=TABLETOP_SPEC,
    label="Tabletop Organization",
    env_class=TabletopManipulationEnv,
    default_steps=3_000_000,
    experts=("harness.envs.experts:tabletop_expert", "harness.envs.experts:tabletop_expert"),
    scripted_demos=(12, 12),
    bench_steps=50_000,
    in_table1=True,
)
