"""EARL's kitchen (``kitchen``, ``earl/Kitchen-v0``) on MuJoCo 3: a Franka arm driven through a mocap weld.

EARL (github.com/architsharma97/earl_benchmark) builds its ``Kitchen`` (``envs/kitchen.py``) on the adept_envs
``KitchenTaskRelaxV1`` / ``KitchenV0`` (``envs/kitchen_assets/adept_envs/adept_envs/franka/kitchen_multitask_v0.py``),
its ``Robot_VelAct`` (``franka/robot/franka_robot.py``, limits and noise from ``franka/robot/franka_config.xml``) and
mujoco-py. This is not Gymnasium-Robotics' FrankaKitchen. Written afresh from EARL's code; what it does:

Model: EARL's scene ``franka_kitchen_jntpos_act_ab.xml`` and its includes, unchanged on disk, found in the EARL data
directory (``assets/kitchen``). The includes are inlined in memory and ``kettle_asset.xml``'s top-level
``<default class="kettle">`` is wrapped in a plain ``<default>``: MuJoCo 3 refuses to rename its top-level class,
MuJoCo 2 (EARL's) merged it into the top-level class. Compiled, the two differ only in two visual fields (the floor
geom's group, the mocap box's material); every physical parameter is equal (checked on MuJoCo 2.2.1). The arm's 7
joints have no actuators: a weld pulls ``panda0_link7`` to the mocap body ``vive_controller`` (fixed orientation).
Timestep 2 ms, frame skip 40 (``KitchenV0(frame_skip=40)``): one env step is 0.08 s.

Step (``KitchenV0.step`` + ``Robot_VelAct.step``): ``a = 2 * clip(a, -1, 1)`` (``act_mid`` 0, ``act_amp`` 2);
mocap position ``+= a[:3] * 0.01``, clipped to ``[-0.7, -0.1, 1.8]``-``[0.4, 0.5, 2.6]``; joint targets
``last_observed_qpos[:9] + clip(a, -10, 10) * 0.08`` clipped to the config's position bounds, of which only the first
two reach ``data.ctrl`` (the model has 2 actuators, the finger position servos, ctrlrange [0, 0.04]: EARL's
``do_simulation`` copies ``ctrl[:nu]``) -- so ``a[0:3]`` move the end effector, ``a[0]`` / ``a[1]`` also set the two
finger targets through arm joints 0 / 1, and ``a[3:9]`` have no effect, as in EARL; then 40 ``mj_step``.

Observation (46, float32): robot qpos (9) + object qpos (14) with EARL's uniform noise (``robot_noise_ratio`` 0.1
times the config's ``pos_noise_amp``: 0.01 rad on the arm and fingers, 0.0005 on burners 0 and light/slide, 5e-5 on
burners 1-3 (qpos 11-16), 0.01 on the hinge cabinet and microwave), then the 23-dim goal. Every observation draws 46
uniforms (robot qpos, robot qvel, object qpos, object qvel noise, as EARL does) from ``self.np_random``; the noisy
robot qpos is also EARL's "observation cache" that the next step's joint targets start from (part of the state).

Reward (``Kitchen._get_reward_n_score``, dense, on the noisy observation, float64):
``-10 ||s[9:23] - g[9:23]||``, plus, for each object in EARL's order (burner0-3, light switch, slide cabinet, hinge
cabinet, microwave), ``+1`` if within ``0.01 x (its dof count)`` of the goal, else, for the first such object only,
``-0.5 ||mocap position - its handle site||``. Success: ``||s[9:23] - g[9:23]|| <= 0.3``. The maximum is 8. The
learners' task reward (``KITCHEN_SPEC.compute_reward``, from observations only) is the same formula with the mocap and
sites estimated from the observed joints (:class:`ObsReward`; within 0.01 per step of the env's on average).

Reset (``Kitchen.reset_model`` + ``Robot.reset``): one of EARL's 6 ``all_pairs`` initial states drawn uniformly
(EARL: ``np.random.randint``; here ``self.np_random``): qpos = ``KitchenV0.init_qpos[:9]`` (arm) + the pair's
object qpos, qvel 0; EARL's observation cache is refilled (5 noisy reads at noise ratio 1); the mocap is put at
``(-0.44, 0.1, 2.226)``; 10 zero-action robot steps (400 substeps, joint targets = the cache's last read, i.e. the
fingers at 0.04 / 0); the goal is EARL's single goal; the observation is drawn.

Differences from EARL: MuJoCo 3.3 instead of mujoco-py / MuJoCo 2 (same Euler integrator, Newton solver, weld);
randomness only from ``self.np_random`` (EARL: ``np.random`` for the pair, the env's own for the noise); the kettle
patch above; ``reset(options=...)`` (``state``, ``goal``, ``initial_index``) is ours. EARL's step reward reads the
sites from the last ``mj_step``'s forward pass (one substep stale, as mujoco-py did); so does ours.
"""

from __future__ import annotations

import functools
import os
import xml.etree.ElementTree as ET
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from harness.data import asset_path
from harness.envs.base import EarlEnv, unpickle_env
from harness.envs.kitchen_task import COMPONENTS, INITIAL_STATES, KITCHEN_SPEC
from harness.envs.mujoco_render import MujocoRendering

SCENE = ("adept_envs", "adept_envs", "franka", "assets", "franka_kitchen_jntpos_act_ab.xml")
_KETTLE_ASSET = "kettle_asset.xml"

# -- EARL's constants (kitchen_multitask_v0.py KitchenV0.__init__; franka_config.xml) ---------------------------------
FRAME_SKIP = 40
#: ``KitchenV0.init_qpos`` ("For the microwave kettle slide hinge"), arm and fingers; the objects come from the pair
INIT_ROBOT_QPOS = np.array([1.48388023e-01, -1.76848573e+00, 1.84390296e+00, -2.47685760e+00, 2.60252026e-01,
                            7.12533105e-01, 1.59515394e+00, 4.79267505e-02, 3.71350919e-02])
MOCAP_MIDPOINT = np.array([-0.440, 0.1, 2.226])
MOCAP_STEP = 0.01  # KitchenV0.range
MOCAP_LOW = np.array([-0.7, -0.1, 1.8])
MOCAP_HIGH = np.array([0.4, 0.5, 2.6])
ACT_AMP = 2.0  # act_mid 0, act_amp 2
ROBOT_NOISE_RATIO = 0.1  # KitchenV0.robot_noise_ratio
RESET_STEPS = 10  # zero-action robot steps of Kitchen.reset_model
CACHE_SIZE = 5  # BaseRobot observation_cache_maxsize: the reset's refresh reads the state this many times
#: franka_config.xml: pos_noise_amp of qpos0..22, pos_bound and vel_bound of the 9 robot dofs
POS_NOISE_AMP = np.array([0.1] * 9 + [0.005] * 2 + [0.0005] * 6 + [0.005] * 3 + [0.1] * 3)
VEL_BOUND = 10.0
POS_BOUND = np.array([[-2.9, 2.9], [-1.8, 1.8], [-2.9, 2.9], [-3.1, 0.0], [-2.9, 2.9], [0.0, 3.8], [-2.9, 2.9],
                      [0.0, 0.04], [0.0, 0.04]])
#: Kitchen._get_reward_n_score's task_to_site
REACH_SITES = {"microwave": "microhandle_site", "hinge_cabinet": "hinge_site2", "slide_cabinet": "slide_site",
               "burner0": "knob1_site", "burner1": "knob2_site", "burner2": "knob3_site", "burner3": "knob4_site",
               "light_switch": "light_site"}
N_ROBOT, N_OBJ = 9, 14
_N_NOISE = 2 * (N_ROBOT + N_OBJ)  # qp, qv, obj qp, obj qv noise: 46 uniforms per observation


def _inline(path: str) -> ET.Element:
    """The MJCF tree of ``path`` with every ``<include>`` replaced by the included file's children (MuJoCo's include
    semantics, recursively), the kettle asset's top-level class wrapped in a plain ``<default>``."""
    root = ET.parse(path).getroot()
    _expand(root, os.path.dirname(path))
    return root


def _expand(el: ET.Element, base: str) -> None:
    i = 0
    while i < len(el):
        child = el[i]
        if child.tag != "include":
            _expand(child, base)
            i += 1
            continue
        inc = os.path.normpath(os.path.join(base, child.get("file")))
        kids = list(ET.parse(inc).getroot())
        if os.path.basename(inc) == _KETTLE_ASSET:
            kids = [_wrap_default(k) if k.tag == "default" and k.get("class") else k for k in kids]
        for k in kids:
            _expand(k, os.path.dirname(inc))
        el[i:i + 1] = kids
        i += len(kids)


def _wrap_default(el: ET.Element) -> ET.Element:
    outer = ET.Element("default")
    outer.append(el)
    return outer


@functools.lru_cache(maxsize=4)
def _model_xml(scene: str) -> str:
    root = _inline(scene)
    here = os.path.dirname(scene)
    for comp in root.iter("compiler"):  # from_xml_string has no model directory: make the asset dirs absolute
        for key in ("meshdir", "texturedir"):
            if comp.get(key):
                comp.set(key, os.path.normpath(os.path.join(here, comp.get(key))))
    return ET.tostring(root, encoding="unicode")


def scene_path() -> str:
    return str(asset_path("kitchen", *SCENE))


def load_model() -> mujoco.MjModel:
    """EARL's kitchen scene as an ``MjModel`` (a new one each call; the patched XML is cached per process), with
    MuJoCo 2's weld regularisation (:func:`mujoco2_weld`)."""
    m = mujoco.MjModel.from_xml_string(_model_xml(scene_path()))
    mujoco2_weld(m)
    return m


def mujoco2_weld(m: mujoco.MjModel) -> None:
    """Give the weld's rotational rows the constraint regularisation they had in MuJoCo < 3.0 (EARL's engine).

    ``mj_diagApprox`` before MuJoCo 3.0.0 reset its weld row counter on every row (``efc_type`` is never
    ``mjEQ_WELD``), so all 6 rows of a weld used the bodies' *translational* inverse weight; 3.0.0 (commit 1bd6c94e)
    gives rows 3-5 the rotational one (132.7 against 0.39 for ``panda0_link7``), a much softer rotational weld: the
    redundant arm then settles up to 0.26 rad elsewhere than in EARL (joint 6 at reset). Setting each weld body's
    rotational ``body_invweight0`` to its translational one restores the old rows exactly; nothing else reads them
    here (the weld is the only constraint on link 7 that has rotational rows; its geoms are condim 3). With it, resets
    and 400-step episodes match MuJoCo 2.2.1 running EARL's logic (``scripts/kitchen_engine_compare.py``)."""
    for i in np.flatnonzero(m.eq_type == mujoco.mjtEq.mjEQ_WELD):
        for b in (m.eq_obj1id[i], m.eq_obj2id[i]):
            m.body_invweight0[b, 1] = m.body_invweight0[b, 0]


def reach_terms(m: mujoco.MjModel) -> list[tuple[tuple[int, ...], float, int]]:
    """Per object in EARL's order: its state indices, its "closed" tolerance (0.01 per dof), its handle site's id."""
    return [(COMPONENTS[k], len(COMPONENTS[k]) * 0.01, m.site(REACH_SITES[k]).id) for k in COMPONENTS]


def earl_reward(obs: np.ndarray, mocap: np.ndarray, site_xpos: np.ndarray, reach) -> float:
    """``Kitchen._get_reward_n_score`` of one 46-dim observation (float64) given the mocap position and site positions."""
    s, g = obs[:23], obs[23:]
    r = -10.0 * float(np.linalg.norm(s[9:23] - g[9:23]))
    reaching = False
    for idx, tol, site in reach:
        i = list(idx)
        if np.linalg.norm(s[i] - g[i]) < tol:
            r += 1.0
        elif not reaching:
            reaching = True
            r += -0.5 * float(np.linalg.norm(mocap - site_xpos[site]))
    return r


class ObsReward:
    """EARL's dense reward computed from observations alone: the learners' task reward (``EnvSpec.reward_fn``).

    EARL's reward also reads the mocap position and the handle sites, which the observation does not hold. Here the
    sites come from forward kinematics of the observed (noisy) object qpos and the mocap from that of the observed arm
    (link 7's position minus the weld's offset, the pose the weld holds at rest). Against the env's own step reward
    (|r| about 6.6 per step) it differs by 0.003 (zero actions), 0.006 (random) and 0.014 (random actions held 20
    steps, the arm lagging its mocap) per step on average, 0.1 at most (``tests/test_kitchen.py``)."""

    def __init__(self):
        self.model = m = load_model()
        self.data = mujoco.MjData(m)
        self.reach = reach_terms(m)
        self.link7 = m.body("panda0_link7").id
        weld = int(np.flatnonzero(m.eq_type == mujoco.mjtEq.mjEQ_WELD)[0])
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.body_quat[m.eq_obj1id[weld]])  # the mocap's fixed orientation
        self.offset = rot.reshape(3, 3) @ m.eq_data[weld, 3:6]

    def __call__(self, obs) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float64)
        flat = o.reshape(-1, o.shape[-1])
        out = np.empty(len(flat))
        m, d = self.model, self.data
        for k, row in enumerate(flat):
            d.qpos[:] = row[:23]
            mujoco.mj_kinematics(m, d)
            out[k] = earl_reward(row, d.xpos[self.link7] - self.offset, d.site_xpos, self.reach)
        return out.reshape(o.shape[:-1])


_OBS_REWARD: ObsReward | None = None


def obs_reward(obs):
    """:class:`ObsReward` of ``obs`` (..., 46), numpy float64 (a torch tensor in: one of its dtype and device out)."""
    global _OBS_REWARD
    if _OBS_REWARD is None:
        _OBS_REWARD = ObsReward()
    if hasattr(obs, "detach"):  # torch
        import torch

        return torch.as_tensor(_OBS_REWARD(obs.detach().cpu().numpy()), dtype=obs.dtype, device=obs.device)
    return _OBS_REWARD(obs)


class KitchenEnv(MujocoRendering, EarlEnv):
    """EARL ``kitchen`` (task ``all_pairs``): close the two objects that a reset opened (see the module docstring).

    ``reset`` options: ``{"goal": g}`` (23), ``{"state": obs}`` (a 46-dim observation: qpos set from its state half,
    at rest, the mocap put where the weld holds the arm, the goal from its goal half unless ``goal`` is given) and
    ``{"initial_index": i}`` (EARL's reset with the i-th of the 6 pairs instead of a random one).
    """

    spec_ = KITCHEN_SPEC
    metadata = {"render_modes": ["rgb_array"], "render_fps": 12.5}  # 1 / (40 x 2 ms)

    def __init__(self, render_mode: str | None = None, width: int = 640, height: int = 480):
        super().__init__(render_mode)
        self._ctor_kwargs = {"render_mode": render_mode, "width": width, "height": height}
        self.model = m = load_model()
        self.data = mujoco.MjData(m)
        self.frame_skip = FRAME_SKIP
        self.dt = FRAME_SKIP * m.opt.timestep  # EARL's step_duration = skip x timestep
        self._n_substeps = int(self.dt / m.opt.timestep)  # Robot.step: int(step_duration / timestep) = 40
        self._reach = reach_terms(m)
        self._noise = ROBOT_NOISE_RATIO * POS_NOISE_AMP  # EARL multiplies ratio * amp, then the uniform
        self._link7 = m.body("panda0_link7").id
        weld = int(np.flatnonzero(m.eq_type == mujoco.mjtEq.mjEQ_WELD)[0])
        self._weld_relpos = m.eq_data[weld, 3:6].copy()  # link7 = mocap + R_mocap @ relpos at rest
        self._state_spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self._state_size = mujoco.mj_stateSize(m, self._state_spec)
        self._goal = self.spec_.goal_states[0].astype(np.float64)
        self._last_qp = np.zeros(N_ROBOT)  # EARL's observation cache: the last observed (noisy) robot qpos
        self._obs = np.zeros(self.spec_.obs_dim, dtype=np.float32)
        self.initial_index: int | None = None  # the pair of the last EARL reset (None after a reset to a state)
        self._render_size = (height, width)
        self._renderer = None
        self._camera = None
        self.reset(seed=None)

    # -- observation / reward ------------------------------------------------------------------------------------
    def _observe(self, noise_ratio: float = ROBOT_NOISE_RATIO) -> np.ndarray:
        """EARL's ``Robot.get_obs`` + goal: the noisy state (float64, 46); becomes the observation cache's last entry."""
        u = self.np_random.uniform(-1.0, 1.0, _N_NOISE)
        amp = self._noise if noise_ratio == ROBOT_NOISE_RATIO else noise_ratio * POS_NOISE_AMP
        q = self.data.qpos
        qp = q[:N_ROBOT] + amp[:N_ROBOT] * u[:N_ROBOT]
        qp_obj = q[N_ROBOT:] + amp[N_ROBOT:] * u[2 * N_ROBOT:2 * N_ROBOT + N_OBJ]
        self._last_qp = qp
        return np.concatenate([qp, qp_obj, self._goal])

    def dense_reward(self, obs: np.ndarray) -> float:
        """EARL's kitchen reward of a 46-dim observation (float64), with the mocap and handle sites of the sim now."""
        return earl_reward(np.asarray(obs, dtype=np.float64), self.data.mocap_pos[0], self.data.site_xpos, self._reach)

    def _set_goal(self, goal) -> None:
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        if g.shape != (23,):
            raise ValueError(f"goal must have 23 entries, got shape {g.shape}")
        self._goal = g.copy()

    # -- reset ---------------------------------------------------------------------------------------------------
    def _earl_reset(self, index: int) -> None:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:N_ROBOT] = INIT_ROBOT_QPOS
        d.qpos[N_ROBOT:] = INITIAL_STATES[index, N_ROBOT:]
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        for _ in range(CACHE_SIZE):  # Robot.reset refreshes the observation cache at noise ratio 1
            self._observe(noise_ratio=1.0)
        d.mocap_pos[0] = MOCAP_MIDPOINT
        target = np.clip(self._last_qp, POS_BOUND[:, 0], POS_BOUND[:, 1])  # zero velocity: the cached qpos
        d.ctrl[:] = target[: m.nu]
        mujoco.mj_step(m, d, nstep=RESET_STEPS * self._n_substeps)

    def _place(self, s: np.ndarray) -> None:
        """Simulator at the 23-dim state ``s`` at rest, the mocap where the weld holds link 7 there."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = s[:23]
        d.qvel[:] = 0.0
        mujoco.mj_kinematics(m, d)
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.mocap_quat[0])
        d.mocap_pos[0] = d.xpos[self._link7] - rot.reshape(3, 3) @ self._weld_relpos
        d.ctrl[:] = np.clip(s[: m.nu], POS_BOUND[: m.nu, 0], POS_BOUND[: m.nu, 1])
        self._last_qp = np.asarray(s[:N_ROBOT], dtype=np.float64).copy()
        mujoco.mj_forward(m, d)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        gym.Env.reset(self, seed=seed)
        options = options or {}
        goal = options.get("goal")
        if "state" in options:
            o = np.asarray(options["state"], dtype=np.float64).reshape(-1)
            self._set_goal(goal if goal is not None else o[23:46])
            self._place(o[:23])
            self.initial_index = None
        else:
            self._set_goal(goal if goal is not None else self.sample_goal())
            index = options.get("initial_index")
            if index is None:
                index = int(self.np_random.integers(len(INITIAL_STATES)))
            elif not 0 <= int(index) < len(INITIAL_STATES):
                raise ValueError(f"initial_index must be in 0..{len(INITIAL_STATES) - 1}, got {index!r}")
            self.initial_index = int(index)
            self._earl_reset(self.initial_index)
        obs = self._observe().astype(np.float32)
        self._obs = obs
        return obs.copy(), {"success": bool(self.spec_.is_success(obs))}

    # -- step ----------------------------------------------------------------------------------------------------
    def step(self, action):
        """One EARL step (module docstring); reward EARL's dense reward; never terminates or truncates."""
        m, d = self.model, self.data
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0) * ACT_AMP
        pos = d.mocap_pos[0] + a[:3] * MOCAP_STEP
        d.mocap_pos[0] = np.clip(pos, MOCAP_LOW, MOCAP_HIGH)
        target = self._last_qp + np.clip(a, -VEL_BOUND, VEL_BOUND) * self.dt
        target = np.clip(target, POS_BOUND[:, 0], POS_BOUND[:, 1])
        d.ctrl[:] = target[: m.nu]
        mujoco.mj_step(m, d, nstep=self._n_substeps)
        obs64 = self._observe()
        reward = self.dense_reward(obs64)
        obs = obs64.astype(np.float32)
        self._obs = obs
        success = bool(self.spec_.is_success(obs))
        return obs.copy(), reward, False, False, {"success": success}

    # -- checkpointing -------------------------------------------------------------------------------------------
    def get_sim_state(self) -> dict[str, Any]:
        """MuJoCo's integration state (qpos, qvel, warm start, ctrl, mocap...), EARL's observation cache, goal, RNG."""
        st = np.empty(self._state_size)
        mujoco.mj_getState(self.model, self.data, st, self._state_spec)
        return {"mj_state": st, "last_qp": self._last_qp.copy(), "goal": self._goal.copy(), "rng": self._rng_state(),
                "obs": self._obs.copy()}

    def set_sim_state(self, state: dict[str, Any]) -> None:
        mujoco.mj_setState(self.model, self.data, np.asarray(state["mj_state"], dtype=np.float64), self._state_spec)
        self._last_qp = np.array(state["last_qp"], dtype=np.float64)
        self._set_goal(state["goal"])
        self._set_rng_state(state["rng"])
        self._obs = np.array(state["obs"], dtype=np.float32)
        mujoco.mj_kinematics(self.model, self.data)  # for rendering; stepping recomputes everything

    def __reduce__(self):
        return (unpickle_env, (type(self), self._ctor_kwargs, self.get_sim_state()))

    def current_obs(self) -> np.ndarray:
        return self._obs.copy()

    # -- rendering -----------------------------------------------------------------------------------------------
    def render(self):
        """An RGB frame (H, W, 3 uint8) from EARL's viewer camera (``Kitchen.viewer_setup``: distance 3, elevation
        -30, azimuth 120, looking at the model centre)."""
        if self._camera is None:
            cam = mujoco.MjvCamera()
            mujoco.mjv_defaultFreeCamera(self.model, cam)
            cam.distance, cam.elevation, cam.azimuth = 3.0, -30.0, 120.0
            self._camera = cam
        return self._rgb_frame(self._camera)
