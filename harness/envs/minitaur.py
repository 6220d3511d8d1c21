"""EARL's goal-conditioned Minitaur on raw pybullet calls, one pybullet client per env.

EARL (Sharma et al. 2021, github.com/architsharma97/earl_benchmark, ``envs/minitaur_gym_env.py``, ``envs/minitaur.py``,
``envs/motor.py``) ran Ghost Robotics' Minitaur quadruped in pybullet, inside a pen of 12 wall tiles, with a goal
position for its base. This module writes the same simulation afresh on ``pybullet`` (no ``gym``, no
``pybullet_envs``, whose package import registers gym envs and breaks with today's gym); the constants and their EARL
sources are in :mod:`harness.envs.minitaur_task`.

The task (every number from EARL unless said otherwise)
  - world: plane (``pybullet_data/plane.urdf``), gravity -10, pybullet step 0.002 s with 60 solver iterations, 12 wall
    tiles (EARL's ``wall_tile.urdf``, from the data directory's ``assets/minitaur``) at x = +-1.5 or y = +-1.5 facing
    inwards, the robot ``pybullet_data/quadruped/minitaur.urdf`` at (0, 0, 0.2) with self collision and a
    point-to-point constraint closing each leg's two knees;
  - action (8) in [-1, 1]: EARL's leg model (4 swing + 4 extension components) -> 8 desired motor angles, held for
    5 pybullet steps; each step the command is clipped to +-0.3 rad of the motor angle (velocity limit 150 rad/s x
    0.002 s) and turned into torque by EARL's DC motor model (PD gains 1.0 / 0.02 on the PWM, 16 V, 0.186 Ohm,
    back-EMF, 50 V clipping, the saturating current-torque table) with its overheat shutdown (> 2.45 Nm for 1 s);
  - observation (32, float32): motor angles [0:8], velocities [8:16], observed torques [16:24] (motor frame, EARL's
    ``MOTOR_NAMES`` order), base orientation quaternion xyzw [24:28], base xy [28:30], goal xy [30:32];
  - reward: EARL's dense ``-2 (|x - gx| + |y - gy|) - 0.005 |tau . qdot| 0.002`` (``minitaur_reward``; RISC's
    ``reward_type: dense``; EARL's env has no other); success: base xy within 0.1 of the goal (EARL: ``< 0.1``, here
    ``<= 0.1``, as every env of the harness); never terminates (EARL's ``_termination`` is False);
  - reset: goal drawn, robot put back in EARL's pose (base at (0, 0, 0.2) level, motors at pi/2, knees at -2.1834,
    zero velocities), pybullet's ``MinitaurEnvRandomizer`` applied (base mass and leg/motor masses x U(0.8, 1.2),
    battery U(14.8, 16.8) V, motor viscous damping U(0, 0.01), foot friction U(0.8, 1.5)), then 100 pybullet steps
    commanding pi/2 on every motor;
  - H_T 100,000, H_E 1000 (``deployment_eval_config['minitaur']``), no demonstrations (``has_demos()``).

Goals: RISC's 4, not EARL's 12
  EARL's env class defaults to 12 goal positions (x in +-0.2, +-0.4; y in 0, 0.2, 0.4) and EARL's loader builds it
  without arguments (its config's ``num_goals: 4`` is never read). The only published minitaur curves are RISC's
  (``load_published()``: source risc_paper, risc and two ablations, metric deployed_return), and RISC installs a fork
  of EARL (dapatil211/earl_benchmark at fa4a75c, pinned in its requirements.txt) whose loader passes
  ``goal_locations=[[0.4, 0], [0.2, 0], [-0.2, 0], [-0.4, 0]]`` to both envs; RISC's ``get_goals`` then reads the
  env's ``_goal_locations``. So the task here is RISC's 4 goals on the x axis (also EARL's ``num_goals: 4``), so that
  the published curves are the reference; EARL's 12 are kept as ``minitaur_task.EARL_DEFAULT_GOALS``
  (``reset(options={"goal": g})`` takes any). The returns agree: RISC's first published evaluations (step 10k, an
  untrained policy) are -560 to -738 per seed; a 1000-step episode of zero actions returns about -615 averaged over
  the 4 goals here (random actions -632), and about -1015 over EARL's 12 (``tests/test_minitaur.py``).

What differs from EARL, and why
  - randomness: goals and the randomizer draw from ``self.np_random`` (seeded by ``reset(seed=...)``), in EARL's
    order (goal; base mass, 2 leg masses, voltage, damping, friction); EARL drew from the global ``np.random`` and
    Python's ``random``;
  - ``deterministicOverlappingPairs=1``: pybullet's save/restore of a world with contacts is exact only with it
    (bullet3 issues 2982 and 4722; without it a restored step already differs by 2e-3), and checkpoints must resume
    bit for bit. It changes the order in which contact pairs are solved: with the same setting on its client, EARL's
    own code agrees with this env bit for bit (reset state; 1000 steps of float64 actions with and without the
    randomizer; returns: ``scripts/minitaur_earl_compare.py``); with pybullet's default order EARL's reset state is
    within 3.4e-3 (velocities) and trajectories drift apart as contact-rich simulations do (the fork that RISC ran
    pinned pybullet 3.2.0, this is 3.2.7: not bitwise either way);
  - float32 actions: EARL wrote the leg model's float64 motor angles into a copy of the action, so a float32 action
    gave float32-rounded commands (with numpy 1.x, EARL's era); so do we. EARL's code under numpy 2 computes part of
    the leg model in float32 (NEP 50) and differs from both by ~4e-6 rad;
  - every reset restores the freshly built world first (``restoreState`` of a snapshot taken right after building),
    then does EARL's reset: a reset is a function of its draws only, not of the contacts left by the previous
    episode (EARL's later resets kept pybullet's contact cache);
  - the action is clipped to [-1, 1] (EARL raised beyond +-1.01);
  - ``reset(options={"state": obs})`` is ours: a reset, then the base moved to the observation's xy (the other 28
    coordinates are the reset's: an observation does not determine the knees, base height or velocities);
  - pybullet's C code prints on import (stderr) and on loading the wall tiles (stdout): silenced.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from typing import Any

import gymnasium as gym
import numpy as np

from harness.data import asset_path
from harness.envs import minitaur_task as T
from harness.envs.base import EarlEnv, unpickle_env


@contextlib.contextmanager
def _quiet(fd: int = 1):
    """Silence a file descriptor: pybullet's C code prints ``processing wall_link`` (URDF merge) to stdout and its
    build time to stderr on import."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, OSError):
            stream.flush()
    try:
        saved = os.dup(fd)
    except OSError:  # no such descriptor
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, fd)
    try:
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(null)


with _quiet(2):
    import pybullet
    import pybullet_data
    from pybullet_utils import bullet_client

_DIRECTION = np.array(T.MOTOR_DIRECTION)
_SETTLE_COMMAND = np.full(8, T.HALF_PI)
_CURRENT = np.array(T.CURRENT_TABLE)
_TORQUE = np.array(T.TORQUE_TABLE)
_SIGN = np.array([(-1.0) ** i * (-1.0 if i >= 4 else 1.0) for i in range(8)])  # leg model: extension sign per motor


def leg_model(action: np.ndarray) -> np.ndarray:
    """EARL's ``ConvertFromLegModel``: motor i = pi - pi/4 (a[4 + i//2] + 1.5) + sign_i pi/4 a[i//2], with
    sign_i = (-1)^i, negated for the right legs (i >= 4). The result has the action's dtype, as EARL wrote it into a
    copy of the action (a float32 action gives float32 commands)."""
    a = np.asarray(action)
    swing = a[4:8].astype(np.float64)[[0, 0, 1, 1, 2, 2, 3, 3]]
    ext = a[0:4].astype(np.float64)[[0, 0, 1, 1, 2, 2, 3, 3]]
    q = math.pi / 4
    out = math.pi + (-1 * q * (swing + 1.5)) + (_SIGN * q) * ext
    return out.astype(a.dtype if a.dtype.kind == "f" else np.float64).astype(np.float64)


class MinitaurEnv(EarlEnv):
    """EARL ``minitaur`` (``GoalConditionedMinitaurBulletEnv``): walk the Minitaur's base to a goal xy in the pen.

    ``randomize=False`` skips pybullet's randomizer (nominal masses, 16 V, no damping, the URDF's foot friction):
    every reset is then EARL's listed initial state. See the module docstring for every fact and its source."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}  # one frame per env step of 0.01 s
    spec_ = T.MINITAUR_SPEC

    def __init__(self, render_mode: str | None = None, randomize: bool = True, width: int = 480, height: int = 260):
        super().__init__(render_mode)
        self._ctor_kwargs = {"render_mode": render_mode, "randomize": randomize, "width": width, "height": height}
        self.randomize = bool(randomize)
        self._render_size = (width, height)
        with _quiet():
            self._p = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
            self._build()
        self._goal = T.GOALS[0].astype(np.float64)
        self._params: dict[str, Any] | None = None  # the randomizer's draws of the current episode
        self._obs64 = np.zeros(self.spec_.obs_dim)
        self.reset(seed=None)

    # -- the world (MinitaurBulletEnv.reset with hard reset, Minitaur.Reset(reload_urdf=True)) --------------------
    def _build(self) -> None:
        p = self._p
        p.resetSimulation()
        p.setPhysicsEngineParameter(numSolverIterations=T.SOLVER_ITERATIONS, deterministicOverlappingPairs=1)
        p.setTimeStep(T.TIME_STEP)
        data = pybullet_data.getDataPath()
        plane = p.loadURDF(os.path.join(data, "plane.urdf"))
        p.changeVisualShape(plane, -1, rgbaColor=[1, 1, 1, 0.9])
        p.setGravity(0, 0, T.GRAVITY)
        wall = str(asset_path("minitaur", "wall_tile.urdf"))
        self._walls = [
            p.loadURDF(wall, basePosition=pos, baseOrientation=p.getQuaternionFromEuler([0, 0, math.atan2(fy, fx)]),
                       globalScaling=1.0, useFixedBase=True, flags=p.URDF_MERGE_FIXED_LINKS)
            for pos, (fx, fy) in zip(T.WALL_POSITIONS, T.WALL_FACINGS)
        ]
        r = self._robot = p.loadURDF(os.path.join(data, "quadruped", "minitaur.urdf"), T.INIT_POSITION,
                                     flags=p.URDF_USE_SELF_COLLISION)
        joints = {p.getJointInfo(r, j)[1].decode(): j for j in range(p.getNumJoints(r))}
        self._joints = joints
        self._motor_ids = [joints[n] for n in T.MOTOR_NAMES]
        self._urdf_base_mass = p.getDynamicsInfo(r, -1)[0]
        self._urdf_leg_masses = (p.getDynamicsInfo(r, T.LEG_LINK_ID[0])[0], p.getDynamicsInfo(r, T.MOTOR_LINK_ID[0])[0])
        self._reset_pose(add_constraints=True)
        self._fresh = p.saveState()  # the world as built: every reset starts here

    def _reset_pose(self, add_constraints: bool) -> None:
        """EARL's ``ResetPose``: per leg, motors at +-pi/2 and knees at +-2.1834 (x motor direction) with zero velocity,
        the knee constraint on the first build, and pybullet's default joint motors switched off (force 0)."""
        p, r, j = self._p, self._robot, self._joints
        for i, leg in enumerate(T.LEGS):
            d_left, d_right = T.MOTOR_DIRECTION[2 * i], T.MOTOR_DIRECTION[2 * i + 1]
            p.resetJointState(r, j[f"motor_{leg}L_joint"], d_left * T.HALF_PI, targetVelocity=0)
            p.resetJointState(r, j[f"knee_{leg}L_link"], d_left * T.KNEE_ANGLE, targetVelocity=0)
            p.resetJointState(r, j[f"motor_{leg}R_joint"], d_right * T.HALF_PI, targetVelocity=0)
            p.resetJointState(r, j[f"knee_{leg}R_link"], d_right * T.KNEE_ANGLE, targetVelocity=0)
            if add_constraints:
                p.createConstraint(r, j[f"knee_{leg}R_link"], r, j[f"knee_{leg}L_link"], p.JOINT_POINT2POINT,
                                   [0, 0, 0], T.KNEE_CONSTRAINT_POINT_RIGHT, T.KNEE_CONSTRAINT_POINT_LEFT)
            for name in (f"motor_{leg}L_joint", f"motor_{leg}R_joint", f"knee_{leg}L_link", f"knee_{leg}R_link"):
                p.setJointMotorControl2(bodyIndex=r, jointIndex=j[name], controlMode=p.VELOCITY_CONTROL,
                                        targetVelocity=0, force=0)

    # -- the randomizer (pybullet_envs' MinitaurEnvRandomizer, drawn from self.np_random) ---------------------------
    def _draw_params(self) -> dict[str, Any]:
        g = self.np_random
        m, (leg, motor) = self._urdf_base_mass, self._urdf_leg_masses
        base = g.uniform(m * (1.0 + T.BASE_MASS_ERROR[0]), m * (1.0 + T.BASE_MASS_ERROR[1]))
        legs = [g.uniform(x * (1.0 + T.LEG_MASS_ERROR[0]), x * (1.0 + T.LEG_MASS_ERROR[1])) for x in (leg, motor)]
        return {"base_mass": float(base), "leg_masses": [float(x) for x in legs],
                "voltage": float(g.uniform(*T.BATTERY_VOLTAGE)), "damping": float(g.uniform(*T.MOTOR_VISCOUS_DAMPING)),
                "foot_friction": float(g.uniform(*T.FOOT_FRICTION))}

    def _apply_params(self, params: dict[str, Any] | None) -> None:
        """Masses and foot friction into pybullet (pybullet recomputes each link's inertia from its collision shape
        when its mass changes, as under EARL); voltage and damping into the motor model. None: nominal (untouched)."""
        self._params = params
        if params is None:
            self._voltage, self._damping = T.MOTOR_VOLTAGE, 0.0
            return
        p, r = self._p, self._robot
        p.changeDynamics(r, -1, mass=params["base_mass"])
        for link in T.LEG_LINK_ID:
            p.changeDynamics(r, link, mass=params["leg_masses"][0])
        for link in T.MOTOR_LINK_ID:
            p.changeDynamics(r, link, mass=params["leg_masses"][1])
        self._voltage, self._damping = params["voltage"], params["damping"]
        for link in T.FOOT_LINK_ID:
            p.changeDynamics(r, link, lateralFriction=params["foot_friction"])

    # -- motors (Minitaur.ApplyAction with the accurate motor model, MotorModel.convert_to_torque) -----------------
    def _motor_state(self) -> tuple[np.ndarray, np.ndarray]:
        states = self._p.getJointStates(self._robot, self._motor_ids)
        q = np.array([s[0] for s in states]) * _DIRECTION
        qdot = np.array([s[1] for s in states]) * _DIRECTION
        return q, qdot

    def _apply_motor_commands(self, commands: np.ndarray) -> None:
        q, qdot = self._motor_state()
        limit = T.TIME_STEP * T.MOTOR_VELOCITY_LIMIT
        commands = np.clip(commands, q - limit, q + limit)
        pwm = np.clip(-T.MOTOR_KP * (q - commands) - T.MOTOR_KD * qdot, -1.0, 1.0)
        observed = np.clip(T.MOTOR_TORQUE_CONSTANT * (pwm * self._voltage / T.MOTOR_RESISTANCE),
                           -T.OBSERVED_TORQUE_LIMIT, T.OBSERVED_TORQUE_LIMIT)
        v_net = np.clip(pwm * self._voltage - (T.MOTOR_TORQUE_CONSTANT + self._damping) * qdot,
                        -T.VOLTAGE_CLIPPING, T.VOLTAGE_CLIPPING)
        current = v_net / T.MOTOR_RESISTANCE
        torque = np.sign(current) * np.interp(np.abs(current), _CURRENT, _TORQUE)
        hot = np.abs(torque) > T.OVERHEAT_SHUTDOWN_TORQUE
        self._overheat = np.where(hot, self._overheat + 1, 0)
        self._enabled &= ~(self._overheat > T.OVERHEAT_SHUTDOWN_STEPS)
        self._observed_torques = observed
        forces = np.where(self._enabled, torque * _DIRECTION, 0.0)
        self._p.setJointMotorControlArray(self._robot, self._motor_ids, self._p.TORQUE_CONTROL, forces=forces.tolist())

    # -- observation -----------------------------------------------------------------------------------------------
    def _observe(self) -> np.ndarray:
        q, qdot = self._motor_state()
        pos, orn = self._p.getBasePositionAndOrientation(self._robot)
        o = self._obs64
        o[0:8], o[8:16], o[16:24] = q, qdot, self._observed_torques
        o[24:28], o[28:30], o[30:32] = orn, pos[:2], self._goal
        return o.astype(np.float32)

    def _set_goal(self, goal) -> None:
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        if g.shape != (2,):
            raise ValueError(f"goal must be an xy position (2 entries), got shape {g.shape}")
        self._goal = g.copy()

    # -- gymnasium API ---------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """EARL's reset, drawing only from ``self.np_random`` (goal, then the randomizer). Options: ``{"goal": g}``
        (any xy); ``{"state": obs}``: the goal half of ``obs`` (unless ``"goal"``) and, after the reset, the base
        moved to ``obs[28:30]`` (the other state coordinates are the reset's)."""
        gym.Env.reset(self, seed=seed)
        options = options or {}
        state = None if options.get("state") is None else np.asarray(options["state"], dtype=np.float64).reshape(-1)
        if options.get("goal") is not None:
            self._set_goal(options["goal"])
        elif state is not None:
            self._set_goal(state[self.spec_.state_dim:])
        else:
            self._set_goal(self.sample_goal())
        p = self._p
        p.restoreState(self._fresh)
        p.resetBasePositionAndOrientation(self._robot, T.INIT_POSITION, T.INIT_ORIENTATION)
        p.resetBaseVelocity(self._robot, [0, 0, 0], [0, 0, 0])
        self._reset_pose(add_constraints=False)
        self._overheat = np.zeros(8)
        self._enabled = np.ones(8, dtype=bool)
        self._observed_torques = np.zeros(8)
        self._apply_params(self._draw_params() if self.randomize else None)
        for _ in range(T.SETTLE_STEPS):
            self._apply_motor_commands(_SETTLE_COMMAND)
            p.stepSimulation()
        if state is not None:
            pos, orn = p.getBasePositionAndOrientation(self._robot)
            p.resetBasePositionAndOrientation(self._robot, [state[28], state[29], pos[2]], orn)
        obs = self._observe()
        return obs, {"success": bool(self.spec_.is_success(obs))}

    def step(self, action):
        """EARL's step: leg model -> motor angles, 5 x (motor model, pybullet step); EARL's dense reward of the new
        state (float64, before the float32 observation); never terminates or truncates."""
        a = np.clip(np.asarray(action).reshape(-1), -1.0, 1.0)
        commands = leg_model(a)
        p = self._p
        for _ in range(T.NUM_SUBSTEPS):
            self._apply_motor_commands(commands)
            p.stepSimulation()
        obs = self._observe()
        reward = float(T.minitaur_reward(self._obs64))
        success = bool(self.spec_.is_success(obs))
        return obs, reward, False, False, {"success": success}

    # -- checkpointing ---------------------------------------------------------------------------------------------
    def get_sim_state(self) -> dict[str, Any]:
        """pybullet's world (``saveBullet``: every body's and joint's position and velocity and the contact points,
        exact with ``deterministicOverlappingPairs``), the randomizer's draws, the motor model's state, goal, RNG."""
        fd, path = tempfile.mkstemp(suffix=".bullet")
        os.close(fd)
        try:
            self._p.saveBullet(path)
            with open(path, "rb") as f:
                world = f.read()
        finally:
            os.unlink(path)
        return {"bullet": world, "params": None if self._params is None else dict(self._params),
                "observed_torques": self._observed_torques.copy(), "overheat": self._overheat.copy(),
                "enabled": self._enabled.copy(), "goal": self._goal.copy(), "rng": self._rng_state()}

    def set_sim_state(self, state: dict[str, Any]) -> None:
        self._apply_params(state["params"])
        fd, path = tempfile.mkstemp(suffix=".bullet")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(state["bullet"])
            self._p.restoreState(fileName=path)
        finally:
            os.unlink(path)
        self._observed_torques = np.array(state["observed_torques"], dtype=np.float64)
        self._overheat = np.array(state["overheat"], dtype=np.float64)
        self._enabled = np.array(state["enabled"], dtype=bool)
        self._set_goal(state["goal"])
        self._set_rng_state(state["rng"])

    def __reduce__(self):
        """Pickle as (constructor arguments, ``get_sim_state()``): a pybullet client does not pickle."""
        return (unpickle_env, (type(self), self._ctor_kwargs, self.get_sim_state()))

    def current_obs(self) -> np.ndarray:
        """The last observation (a copy)."""
        return self._observe()

    # -- rendering -------------------------------------------------------------------------------------------------
    def render(self):
        """An RGB frame (H, W, 3 uint8) from EARL's camera (1 m from the base, pitch -30 deg, fov 60), pybullet's
        software renderer."""
        if self.render_mode != "rgb_array":
            raise RuntimeError(f"render() needs render_mode='rgb_array' (got {self.render_mode!r})")
        p, (w, h) = self._p, self._render_size
        base, _ = p.getBasePositionAndOrientation(self._robot)
        view = p.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=base, distance=1.0, yaw=0, pitch=-30, roll=0,
                                                   upAxisIndex=2)
        proj = p.computeProjectionMatrixFOV(fov=60, aspect=w / h, nearVal=0.1, farVal=100.0)
        _, _, px, _, _ = p.getCameraImage(width=w, height=h, viewMatrix=view, projectionMatrix=proj,
                                          renderer=p.ER_TINY_RENDERER)
        return np.asarray(px, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]

    def close(self):
        if getattr(self, "_p", None) is not None:
            with contextlib.suppress(Exception):
                self._p.disconnect()
            self._p = None
        super().close()
