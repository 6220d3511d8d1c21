"""EARL's Sawyer door and peg tasks on MuJoCo 3 / Meta-World 3.

EARL (Sharma et al. 2021, github.com/architsharma97/earl_benchmark, ``envs/sawyer_door.py`` and ``envs/sawyer_peg.py``)
subclassed Meta-World v2 (mujoco-py, MuJoCo 2) environments. Here the same tasks subclass Meta-World 3's
:class:`SawyerDoorCloseEnvV3` / :class:`SawyerPegInsertionSideEnvV3` *and* the project's
:class:`~harness.envs.base.EarlEnv`.

What is EARL-exact
  - the MuJoCo model files: EARL's copies of the Meta-World Sawyer models, loaded from the EARL data directory
    (``assets/metaworld_earl``). They differ from Meta-World 3's only in the door (hinge range [-1.4, 0], density 50: a
    light door) and two cameras;
  - the observation ``[hand xyz, gripper opening, handle / peg-head xyz, goal (7)]`` (14 dims, no clipping), the action
    (mocap xyz delta ``clip(a, -1, 1) * 0.01`` clipped to the hand box, gripper control ``[a3, -a3]``, 5 substeps of
    2.5 ms), the sparse reward ``1[success]`` computed from the returned observation (``EnvSpec.compute_reward``), and
    no episode limit (EARL sets ``max_path_length = 1e8``; the time limits are gymnasium wrappers outside the env);
  - the reset: 50 hand-settling steps with the mocap at EARL's ``hand_init_pos`` and the gripper open, then the object:
    door hinge at ``-pi/3 + U(0, pi/20)`` (EARL's ``random_init`` branch); peg body at
    ``U((0, .5, .02), (.2, .7, .02))`` with the box at ``goal - (.03, 0, .13)``; goal = the task goal. EARL's listed
    door initial state is the noise-0 sample (angle exactly ``-pi/3``; our handle matches it to 2e-8); pass
    ``angle_noise=False`` to always reset there. EARL's 15 peg initial states are 15 samples of the peg distribution
    (head = body + (-0.1, 0, 0)).

What differs (MuJoCo 3 / Meta-World 3) and why
  - physics is MuJoCo 3 with Meta-World 3's weld settings (``reset_mocap_welds``: relpose quat (-1, 0, 0, 0),
    torquescale 5) and MuJoCo 3's Euler integrator with implicit joint damping. The hand therefore settles 1-2 mm away
    from EARL's published position (published hand ``[0.0062, 0.6002, 0.1943]``, ours ``[0.0046, 0.6014, 0.1951]`` for
    peg), and open-loop replays of EARL's demos drift (see ``tests/test_sawyer.py``);
  - observations are computed after ``mj_kinematics`` on the post-step state (Meta-World 3 calls ``mj_forward``;
    mujoco-py's EARL read positions one substep stale). Positions only, so it is cheap;
  - randomness comes only from ``self.np_random`` (seeded by ``reset(seed=...)``); Meta-World 3.1.1 ignores
    ``reset(seed=)`` and draws from the global ``np.random`` in ``_get_state_rand_vec``: we never call it, and never
    touch the global RNG;
  - one ``mj_resetData`` per reset (Meta-World 3's ``reset`` resets the model twice);
  - the door body is placed at EARL's ``obj_init_pos`` once in ``__init__`` (EARL moved it after the first hand
    settling; the hand never touches the door there, so resets are identical);
  - ``reset(options={"state": obs})`` is ours (EARL had no such option), see :meth:`reset`.

EARL's constants, the two :class:`~harness.envs.base.EnvSpec` and their catalogue entries are in
:mod:`harness.envs.sawyer_tasks` (importable without Meta-World)."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from metaworld.envs.sawyer_door_close_v3 import SawyerDoorCloseEnvV3
from metaworld.envs.sawyer_peg_insertion_side_v3 import SawyerPegInsertionSideEnvV3

from harness.data import asset_path
from harness.envs.base import EarlEnv, unpickle_env
from harness.envs.mujoco_render import MujocoRendering
from harness.envs.sawyer_tasks import DOOR_SPEC, PEG_GOAL_STATES, PEG_SPEC

_MOCAP_QUAT = np.array([1.0, 0.0, 1.0, 0.0])  # Meta-World's fixed gripper orientation
_HAND_SETTLE_STEPS = 50  # Meta-World's _reset_hand(steps=50)


class _SawyerEarl(MujocoRendering, EarlEnv):
    """Shared EARL Sawyer logic, mixed in *before* a Meta-World 3 env class.

    ``class SawyerXEnv(_SawyerEarl, MetaWorldXEnvV3)``: the MRO is ours -> ``MujocoRendering`` -> ``EarlEnv`` ->
    Meta-World's env -> ``SawyerXYZEnv`` -> ``MujocoEnv`` -> ``gym.Env``. ``__init__`` runs Meta-World's constructor
    (which builds the MuJoCo model from :attr:`model_name`, overridden to EARL's file, and applies Meta-World 3's weld
    settings) and then ``EarlEnv.__init__`` (EARL's spaces). ``reset``/``step``/``render`` are ours; Meta-World's
    helpers (``tcp_center``, ``_get_site_pos``...) keep working.

    Subclasses set ``spec_``, ``_xml``, ``_hand_init`` and implement the object hooks.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 80}  # 1 / (5 x 2.5 ms): MujocoEnv asserts it
    _xml: str
    _hand_init: np.ndarray
    _render_camera: str
    _mw_cls: type

    def __init__(self, render_mode: str | None = None, width: int = 480, height: int = 480,
                 camera_name: str | None = None):
        self._ctor_kwargs = {"render_mode": render_mode, "width": width, "height": height, "camera_name": camera_name}
        self._mw_cls.__init__(self)  # Meta-World 3 constructor on EARL's model (see model_name)
        EarlEnv.__init__(self, render_mode)
        self._set_task_called = True  # lets Meta-World's own helpers run if someone calls them
        self._partially_observable = False
        m = self.model
        self._hand_id = m.body("hand").id
        self._rclaw_id = m.body("rightclaw").id
        self._lclaw_id = m.body("leftclaw").id
        self._goal_site = m.site("goal").id
        self._finger_adr = (m.joint("r_close").qposadr.item(), m.joint("l_close").qposadr.item())
        self._finger_rng = (m.jnt_range[m.joint("r_close").id].copy(), m.jnt_range[m.joint("l_close").id].copy())
        self._state_spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self._state_size = mujoco.mj_stateSize(m, self._state_spec)
        self._goal = self.spec_.goal_states[0].astype(np.float64)
        self._obs = np.zeros(self.spec_.obs_dim, dtype=np.float32)
        self._render_size = (height, width)
        self._camera = camera_name or self._render_camera
        self._renderer = None
        self.obj_init_pos = None
        self._object_setup()
        self.reset(seed=None)

    # -- Meta-World hooks --------------------------------------------------------------------------
    @property
    def model_name(self) -> str:  # read by Meta-World's constructor: EARL's model, not Meta-World 3's
        return str(asset_path("metaworld_earl", "sawyer_xyz", self._xml))

    def reset_model(self):  # Meta-World's reset_model draws from the global RNG: never used here
        raise NotImplementedError("use reset(); Meta-World's reset_model is replaced by EARL's reset")

    # -- object hooks (subclasses) -----------------------------------------------------------------
    def _object_setup(self) -> None:
        """One-time model edits (object/box body placement, ids)."""

    def _object_random_reset(self) -> None:
        """EARL's object randomisation at reset (after the hand settled), from ``self.np_random``."""
        raise NotImplementedError

    def _object_pos(self) -> np.ndarray:
        """The observed object point (door handle / peg head), world xyz."""
        raise NotImplementedError

    def _object_set_from_obs(self, p: np.ndarray) -> None:
        """Put the object (qpos, zero qvel) where its observed point is ``p``."""
        raise NotImplementedError

    # -- observation -------------------------------------------------------------------------------
    def _gripper_opening(self) -> float:
        x = self.data.xpos
        v = x[self._rclaw_id] - x[self._lclaw_id]
        return min(max(math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) / 0.1, 0.0), 1.0)

    def _make_obs(self) -> np.ndarray:
        obs = np.empty(14, dtype=np.float32)
        obs[0:3] = self.data.xpos[self._hand_id]
        obs[3] = self._gripper_opening()
        obs[4:7] = self._object_pos()
        obs[7:14] = self._goal
        return obs

    def _set_goal(self, goal) -> None:
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        if g.shape != (7,):
            raise ValueError(f"goal must have 7 entries, got shape {g.shape}")
        self._goal = g.copy()
        self._target_pos = g[4:7].copy()  # Meta-World's name for the goal point
        self.model.site_pos[self._goal_site] = g[4:7]  # visual only (sites have no physics)

    # -- reset -------------------------------------------------------------------------------------
    def _settle_hand(self, mocap_target: np.ndarray, steps: int = _HAND_SETTLE_STEPS) -> None:
        """Meta-World's ``_reset_hand``: hold the mocap at the target, gripper open, ``steps`` x 5 substeps. The
        mocap is set to the same value at each of Meta-World's 50 iterations, so one ``mj_step(nstep=250)`` is
        bitwise identical."""
        d = self.data
        d.mocap_pos[0] = mocap_target
        d.mocap_quat[0] = _MOCAP_QUAT
        d.ctrl[0], d.ctrl[1] = -1.0, 1.0
        mujoco.mj_step(self.model, d, nstep=steps * self.frame_skip)

    def _set_gripper_opening(self, opening: float) -> None:
        """Set the finger slide joints so that the observed opening equals ``opening`` (bisection)."""
        if opening >= self._gripper_opening() - 1e-9:
            return  # already as open as the fingers go
        (ra, la), (rr, lr) = self._finger_adr, self._finger_rng
        q, d, m = self.data.qpos, self.data, self.model
        lo, hi = 0.0, 1.0  # fraction of the closing stroke
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            q[ra], q[la] = rr[0] + mid * (rr[1] - rr[0]), lr[1] + mid * (lr[0] - lr[1])
            mujoco.mj_kinematics(m, d)
            if self._gripper_opening() > opening:
                lo = mid
            else:
                hi = mid
        d.qvel[self.model.jnt_dofadr[m.joint("r_close").id]] = 0.0
        d.qvel[self.model.jnt_dofadr[m.joint("l_close").id]] = 0.0

    def _reset_to_obs_state(self, s: np.ndarray) -> None:
        """Simulator state from a 7-dim EARL state (see :meth:`reset`)."""
        target = np.asarray(s[0:3], dtype=np.float64)
        mocap = target.copy()
        for _ in range(4):
            mujoco.mj_resetData(self.model, self.data)
            self._object_set_from_obs(s[4:7])
            self._settle_hand(mocap)
            mujoco.mj_kinematics(self.model, self.data)
            err = target - self.data.xpos[self._hand_id]
            if np.max(np.abs(err)) < 1e-5:
                break
            mocap = mocap + err
        self._object_set_from_obs(s[4:7])  # the hand may have nudged it while settling
        self._set_gripper_opening(float(s[3]))
        mujoco.mj_kinematics(self.model, self.data)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """EARL's reset, seeded only through ``self.np_random``. Resets the simulator once.

        Options:

        - ``{"goal": g}``: goal ``g`` instead of the task goal.
        - ``{"state": obs}``: the state of a full 14-dim observation (goal = its goal half unless
          ``"goal"`` is given). Object point exact (door: hinge angle from the handle xy, clipped to
          the hinge range, z is fixed by the model; peg: peg lying flat along x, head at the given
          xyz, at rest, which is exact for every state a reset produces); hand: the 50-step hand
          settling of a reset is run from ``mj_resetData`` with the mocap at the target, and the mocap
          target is corrected (target + residual) up to 4 times until the hand is within 1e-5 m;
          gripper opening: fingers set by bisection on their slide joints when the requested opening
          is below the fully open value. Velocities are those of a settled reset (object at rest).
        """
        gym.Env.reset(self, seed=seed)
        options = options or {}
        if "state" in options:
            o = np.asarray(options["state"], dtype=np.float64).reshape(-1)
            self._set_goal(options["goal"] if options.get("goal") is not None else o[7:14])
            self._reset_to_obs_state(o[:7])
        else:
            self._set_goal(options["goal"] if options.get("goal") is not None else self.sample_goal())
            mujoco.mj_resetData(self.model, self.data)
            self._settle_hand(self._hand_init)
            self._object_random_reset()
            mujoco.mj_kinematics(self.model, self.data)
        self.init_tcp = self.tcp_center.copy()
        self.curr_path_length = 0
        obs = self._make_obs()
        self._obs = obs
        return obs.copy(), {"success": bool(self.spec_.is_success(obs))}

    # -- step --------------------------------------------------------------------------------------
    def step(self, action):
        """One EARL step: mocap delta ``clip(a[:3], -1, 1) * action_scale`` clipped to the hand box, gripper control
        ``[a3, -a3]`` (clipped to the actuators' ctrlrange [-1, 1]), 5 substeps. Reward ``1[success]`` on the returned
        observation; never terminates or truncates."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        d = self.data
        pos = d.mocap_pos[0] + a[:3] * self.action_scale
        np.clip(pos, self.mocap_low, self.mocap_high, out=pos)
        d.mocap_pos[0] = pos
        d.mocap_quat[0] = _MOCAP_QUAT
        d.ctrl[0] = a[3]
        d.ctrl[1] = -a[3]
        mujoco.mj_step(self.model, d, nstep=self.frame_skip)
        mujoco.mj_kinematics(self.model, d)
        self.curr_path_length += 1
        obs = self._make_obs()
        self._obs = obs
        success = bool(self.spec_.is_success(obs))
        return obs.copy(), float(success), False, False, {"success": success}

    # -- checkpointing -----------------------------------------------------------------------------
    def get_sim_state(self) -> dict[str, Any]:
        """MuJoCo's full integration state (time, qpos, qvel, act, solver warm start, ctrl, mocap pos/quat,
        eq_active...), the goal and the RNG state; a picklable dict of numpy arrays."""
        st = np.empty(self._state_size)
        mujoco.mj_getState(self.model, self.data, st, self._state_spec)
        return {
            "mj_state": st,
            "qpos": self.data.qpos.copy(),
            "qvel": self.data.qvel.copy(),
            "mocap_pos": self.data.mocap_pos.copy(),
            "mocap_quat": self.data.mocap_quat.copy(),
            "act": self.data.act.copy(),
            "time": float(self.data.time),
            "goal": self._goal.copy(),
            "rng": self._rng_state(),
            "curr_path_length": self.curr_path_length,
        }

    def set_sim_state(self, state: dict[str, Any]) -> None:
        mujoco.mj_setState(self.model, self.data, np.asarray(state["mj_state"], dtype=np.float64), self._state_spec)
        self._set_goal(state["goal"])
        self._set_rng_state(state["rng"])
        self.curr_path_length = state.get("curr_path_length", 0)
        mujoco.mj_kinematics(self.model, self.data)
        self._obs = self._make_obs()

    def __reduce__(self):
        """Pickle as (constructor arguments, ``get_sim_state()``): Meta-World's ``__getstate__`` would
        rebuild the model from the file and lose our model edits (object placement, goal site)."""
        return (unpickle_env, (type(self), self._ctor_kwargs, self.get_sim_state()))

    def current_obs(self) -> np.ndarray:
        """The last observation (a copy)."""
        return self._obs.copy()

    # -- rendering ---------------------------------------------------------------------------------
    def render(self):
        """An RGB frame (H, W, 3 uint8) from EARL's camera via ``mujoco.Renderer`` (``render_mode="rgb_array"``)."""
        return self._rgb_frame(self._camera)


class SawyerDoorEnv(_SawyerEarl, SawyerDoorCloseEnvV3):
    """EARL ``sawyer_door`` (``SawyerDoorV2``): close a light door opened at ``-pi/3 + U(0, pi/20)``.

    State: hand xyz, gripper opening, door-handle xyz (``geom('handle').xpos``); success: handle within
    0.02 of the goal's handle. ``angle_noise=False`` reproduces EARL's listed initial state (angle -pi/3).
    """

    spec_ = DOOR_SPEC
    _xml = "sawyer_door_pull.xml"
    _mw_cls = SawyerDoorCloseEnvV3
    _render_camera = "topview"  # EARL's SawyerDoorV2.render
    # EARL's init_config (float32 arrays as in EARL)
    _hand_init = np.array([0, 0.4, 0.2], dtype=np.float32).astype(np.float64)
    _door_body_pos = np.array([0.1, 0.95, 0.1], dtype=np.float32).astype(np.float64)
    INIT_ANGLE = -np.pi / 3
    ANGLE_NOISE = np.pi / 20

    def __init__(self, render_mode: str | None = None, angle_noise: bool = True, **kwargs):
        self.angle_noise = bool(angle_noise)
        super().__init__(render_mode=render_mode, **kwargs)
        self._ctor_kwargs["angle_noise"] = self.angle_noise

    def _object_setup(self) -> None:
        m = self.model
        m.body("door").pos = self._door_body_pos
        self._handle_geom = m.geom("handle").id
        jid = m.joint("doorjoint").id
        self._door_range = m.jnt_range[jid].copy()
        self.obj_init_pos = self._door_body_pos.copy()
        self.obj_init_angle = self.INIT_ANGLE
        self.hand_init_pos = self._hand_init.copy()
        # hinge axis point and the handle's polar angle at hinge angle 0 (for handle xy -> angle)
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        self._hinge_xy = d.xanchor[jid][:2].copy()
        r0 = d.geom_xpos[self._handle_geom][:2] - self._hinge_xy
        self._handle_phase0 = math.atan2(r0[1], r0[0])

    def _object_random_reset(self) -> None:
        angle = self.INIT_ANGLE
        if self.angle_noise:
            angle += self.np_random.uniform(0.0, self.ANGLE_NOISE)
        self._set_obj_xyz(np.array(angle))
        self.door_angle_init = angle

    def _object_pos(self) -> np.ndarray:
        return self.data.geom_xpos[self._handle_geom]

    def handle_to_angle(self, handle_xyz) -> float:
        """The hinge angle whose handle xy is ``handle_xyz[:2]`` (clipped to the hinge range)."""
        r = np.asarray(handle_xyz[:2], dtype=np.float64) - self._hinge_xy
        ang = math.atan2(r[1], r[0]) - self._handle_phase0
        ang = (ang + math.pi) % (2 * math.pi) - math.pi
        return float(np.clip(ang, *self._door_range))

    def door_angle(self) -> float:
        return float(self.data.qpos[self.door_qpos_adr])

    def _object_set_from_obs(self, p: np.ndarray) -> None:
        q = self.data.qpos
        q[self.door_qpos_adr] = self.handle_to_angle(p)
        self.data.qvel[self.door_qvel_adr] = 0.0
        mujoco.mj_kinematics(self.model, self.data)


class SawyerPegEnv(_SawyerEarl, SawyerPegInsertionSideEnvV3):
    """EARL ``sawyer_peg`` (``SawyerPegV2``): pick the peg up and insert it sideways into the box.

    State: hand xyz, gripper opening, peg-head xyz (``site('pegHead')``); success: peg head within
    0.05 of the goal's peg head. The peg body is drawn uniformly in ``[0, .2] x [.5, .7] x {.02}`` at
    reset (EARL's ``random_init`` branch; its rejection test against the box never fires there).
    """

    spec_ = PEG_SPEC
    _xml = "sawyer_peg_insertion_side.xml"
    _mw_cls = SawyerPegInsertionSideEnvV3
    _render_camera = "clearview"  # EARL's SawyerPegV2.render
    _hand_init = np.array([0.0, 0.6, 0.2])
    OBJ_LOW = np.array([0.0, 0.5, 0.02])
    OBJ_HIGH = np.array([0.2, 0.7, 0.02])
    HEAD_OFFSET = np.array([-0.1, 0.0, 0.0])  # pegHead site in the peg body frame

    def _object_setup(self) -> None:
        m = self.model
        # EARL: box body at goal - (0.03, 0, 0.13) (fixed: single task goal)
        m.body("box").pos = PEG_GOAL_STATES[0][4:] - np.array([0.03, 0.0, 0.13])
        self._head_site = m.site("pegHead").id
        jnt = m.body("peg").jntadr.item()
        self._peg_qpos = m.jnt_qposadr[jnt].item()
        self._peg_qvel = m.jnt_dofadr[jnt].item()
        self.hand_init_pos = self._hand_init.copy()
        self.obj_init_pos = np.array([0.0, 0.6, 0.02])

    def _object_random_reset(self) -> None:
        pos = self.np_random.uniform(self.OBJ_LOW, self.OBJ_HIGH)
        self.obj_init_pos = pos
        self._set_obj_xyz(pos)  # EARL: position only; the (settled, ~identity) orientation is kept
        self.peg_head_pos_init = self._get_site_pos("pegHead")

    def _object_pos(self) -> np.ndarray:
        return self.data.site_xpos[self._head_site]

    def _object_set_from_obs(self, p: np.ndarray) -> None:
        a, v = self._peg_qpos, self._peg_qvel
        self.data.qpos[a:a + 3] = np.asarray(p, dtype=np.float64) - self.HEAD_OFFSET
        self.data.qpos[a + 3:a + 7] = (1.0, 0.0, 0.0, 0.0)
        self.data.qvel[v:v + 6] = 0.0
        mujoco.mj_kinematics(self.model, self.data)
        self.obj_init_pos = self.data.qpos[a:a + 3].copy()
