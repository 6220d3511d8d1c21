"""EARL's goal-conditioned Minitaur as the harness catalogues it: EARL's constants, the :class:`EnvSpec` and the
:class:`EnvInfo` record. Numpy only: the simulator (:mod:`harness.envs.minitaur`) imports pybullet, an optional extra
(``pip install 'earl-harness[minitaur]'``, Python <= 3.11), so the registry stays importable without it.

Sources (EARL: github.com/architsharma97/earl_benchmark at b05b000; RISC: github.com/chandar-lab/RISC, which installs
EARL's fork github.com/dapatil211/earl_benchmark at fa4a75c):

- ``envs/minitaur_gym_env.py``: ``MinitaurBulletEnv`` and ``GoalConditionedMinitaurBulletEnv`` (walls, reset, step,
  reward, success, goals); ``envs/minitaur.py``: the robot (pose, leg model, observation); ``envs/motor.py``: the DC
  motor model; pybullet's ``pybullet_envs/bullet/minitaur_env_randomizer.py``: the randomizer EARL passes by default;
- ``earl_benchmark/__init__.py``: ``deployment_eval_config['minitaur']`` (H_T, H_E, ``num_goals: 4``) and
  ``has_demos()`` (False for minitaur);
- RISC ``risc/configs/risc_minitaur.yaml`` (5M training steps, ``test_max_steps: 1000``, ``reward_type: dense``) and
  ``risc/envs/earl.py`` (``get_goals``: the env's own ``_goal_locations``).

See :class:`harness.envs.minitaur.MinitaurEnv` for the simulator and what differs from EARL.
"""

from __future__ import annotations

import math

import numpy as np

from harness.envs.base import EnvInfo, EnvSpec

# ------------------------------------------------------------------------------------------------
# The task (minitaur_gym_env.py GoalConditionedMinitaurBulletEnv; EARL/RISC configs)
# ------------------------------------------------------------------------------------------------

#: RISC's goals, the ones its published minitaur curves ran with: the fork's ``EARLEnvs.get_train_env`` /
#: ``get_eval_env`` pass ``goal_locations=[[0.4, 0.0], [0.2, 0.0], [-0.2, 0.0], [-0.4, 0.0]]`` (4 goals, matching
#: ``num_goals: 4`` of EARL's ``deployment_eval_config``)
GOALS = np.array([[0.4, 0.0], [0.2, 0.0], [-0.2, 0.0], [-0.4, 0.0]])
#: the 12 defaults of EARL's ``GoalConditionedMinitaurBulletEnv(goal_locations=...)``, which EARL's own loader uses
#: (it never reads ``num_goals``); not the task here (see the decision in harness.envs.minitaur)
EARL_DEFAULT_GOALS = np.array([[0.4, 0.2], [0.2, 0.2], [-0.2, 0.2], [-0.4, 0.2],
                               [0.4, 0.0], [0.2, 0.0], [-0.2, 0.0], [-0.4, 0.0],
                               [0.4, 0.4], [0.2, 0.4], [-0.2, 0.4], [-0.4, 0.4]])
SUCCESS_DISTANCE = 0.1  # is_successful: ||base xy - goal xy|| < 0.1
DISTANCE_WEIGHT = 2.0  # GoalConditionedMinitaurBulletEnv(distance_weight=2)
ENERGY_WEIGHT = 0.005  # MinitaurBulletEnv(energy_weight=0.005); shake_weight and drift_weight are 0

# ------------------------------------------------------------------------------------------------
# The simulation (minitaur_gym_env.py MinitaurBulletEnv.__init__ / reset with its defaults)
# ------------------------------------------------------------------------------------------------

NUM_SUBSTEPS = 5  # accurate_motor_model_enabled: time step / 5, solver iterations / 5, action repeat x 5
TIME_STEP = 0.01 / NUM_SUBSTEPS  # 0.002 s per pybullet step; 0.01 s per env step
SOLVER_ITERATIONS = int(300 / NUM_SUBSTEPS)  # 60
GRAVITY = -10.0
SETTLE_STEPS = 100  # reset: 100 x (ApplyAction([pi/2] * 8), stepSimulation)
MOTOR_VELOCITY_LIMIT = 150.0  # GoalConditionedMinitaurBulletEnv(motor_velocity_limit=150.)
#: the pen: 12 wall tiles (EARL's WALL_POSITIONS, and WALL_FACINGS as yaw = atan2(fy, fx))
WALL_POSITIONS = ((-1.5, -1.0, 0.0), (-1.5, 0.0, 0.0), (-1.5, 1.0, 0.0),
                  (1.5, -1.0, 0.0), (1.5, 0.0, 0.0), (1.5, 1.0, 0.0),
                  (-1.0, -1.5, 0.0), (0.0, -1.5, 0.0), (1.0, -1.5, 0.0),
                  (-1.0, 1.5, 0.0), (0.0, 1.5, 0.0), (1.0, 1.5, 0.0))
WALL_FACINGS = ((1, 0),) * 3 + ((-1, 0),) * 3 + ((0, 1),) * 3 + ((0, -1),) * 3

# ------------------------------------------------------------------------------------------------
# The robot (minitaur.py) and its motors (motor.py)
# ------------------------------------------------------------------------------------------------

INIT_POSITION = (0.0, 0.0, 0.2)
INIT_ORIENTATION = (0.0, 0.0, 0.0, 1.0)
KNEE_ANGLE = -2.1834  # _ResetPoseForLeg
KNEE_CONSTRAINT_POINT_RIGHT = (0.0, 0.005, 0.2)
KNEE_CONSTRAINT_POINT_LEFT = (0.0, 0.01, 0.2)
LEGS = ("front_left", "back_left", "front_right", "back_right")
MOTOR_NAMES = tuple(f"motor_{leg}{side}_joint" for leg in LEGS for side in "LR")
MOTOR_DIRECTION = (-1.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0)
LEG_LINK_ID = (2, 3, 5, 6, 8, 9, 11, 12, 15, 16, 18, 19, 21, 22, 24, 25)  # upper and lower legs
MOTOR_LINK_ID = (1, 4, 7, 10, 14, 17, 20, 23)
FOOT_LINK_ID = (3, 6, 9, 12, 16, 19, 22, 25)  # the lower legs
OVERHEAT_SHUTDOWN_TORQUE = 2.45  # a motor above it for more than 1 s (500 pybullet steps) is switched off
OVERHEAT_SHUTDOWN_STEPS = 1.0 / TIME_STEP
MOTOR_KP, MOTOR_KD = 1.0, 0.02  # MinitaurBulletEnv(motor_kp=1.0, motor_kd=0.02)
MOTOR_VOLTAGE = 16.0
MOTOR_RESISTANCE = 0.186
MOTOR_TORQUE_CONSTANT = 0.0954
OBSERVED_TORQUE_LIMIT = 5.7
VOLTAGE_CLIPPING = 50.0
CURRENT_TABLE = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)  # current (A) -> torque (Nm), saturating
TORQUE_TABLE = (0.0, 1.0, 1.9, 2.45, 3.0, 3.25, 3.5)

# pybullet's MinitaurEnvRandomizer, applied at every reset (EARL's env_randomizer default)
BASE_MASS_ERROR = (-0.2, 0.2)  # relative to the URDF's
LEG_MASS_ERROR = (-0.2, 0.2)
BATTERY_VOLTAGE = (14.8, 16.8)
MOTOR_VISCOUS_DAMPING = (0.0, 0.01)
FOOT_FRICTION = (0.8, 1.5)

HALF_PI = math.pi / 2

# ------------------------------------------------------------------------------------------------
# Observation layout (minitaur.py GetObservation + the goal appended by the goal-conditioned env)
# ------------------------------------------------------------------------------------------------
#   [0:8] motor angles, [8:16] motor velocities, [16:24] observed motor torques (all x MOTOR_DIRECTION, in MOTOR_NAMES
#   order), [24:28] base orientation quaternion (x, y, z, w), [28:30] base xy  | [30:32] goal xy
BASE_XY = (28, 29)

#: the reset state without the randomizer (nominal masses, 16 V, no viscous damping, the URDF's foot friction), as
#: EARL's own code computes it with pybullet 3.2.7 and ``deterministicOverlappingPairs=1`` (bitwise the simulator's
#: here; EARL's code with pybullet's default pair order gives it within 3.3e-3, velocities). EARL's
#: ``get_initial_states()`` returns one randomized reset instead (``num_initial_state_samples: 1``)
INITIAL_STATE = np.array([
    1.4920487584837083, 1.4790623660662168, 1.4862810693588193, 1.4747323200626368,
    1.4960381745568072, 1.500347660984298, 1.4946977513230852, 1.4959483460069065,
    1.0468924057890376, 1.0801054752500183, 1.06299322194636, 1.0945282462818127,
    0.9935772850174234, 0.9620036576895331, 1.0016569891297984, 0.9809936963856216,
    0.4809045357828659, 0.5825677800180252, 0.5261089657620209, 0.6161656980739934,
    0.45437480993646384, 0.42393165190644533, 0.46457666041813916, 0.4574741198046847,
    -0.0021555451274944673, 0.0008689910068461711, -0.00027728357382053815, 0.9999972607930748,
    -0.00012472990655374976, -0.000577134325034223,
])


def minitaur_reward(obs):
    """EARL's dense reward of observations (``GoalConditionedMinitaurBulletEnv.compute_reward``, equal to its step
    reward as the shake and drift weights are 0): ``-2 (|x - gx| + |y - gy|) - 0.005 |torques . velocities| dt``,
    dt = 0.002 s. numpy or torch, any batch shape."""
    distance = abs(obs[..., 28] - obs[..., 30]) + abs(obs[..., 29] - obs[..., 31])
    energy = abs((obs[..., 16:24] * obs[..., 8:16]).sum(-1)) * TIME_STEP
    return -DISTANCE_WEIGHT * distance - ENERGY_WEIGHT * energy


MINITAUR_SPEC = EnvSpec(
    name="minitaur", gym_id="earl/Minitaur-v0", state_dim=30, act_dim=8, success_idx=BASE_XY,
    success_threshold=SUCCESS_DISTANCE, train_horizon=100_000, eval_horizon=1000,
    initial_states=INITIAL_STATE[None], goal_states=GOALS, goal_idx=BASE_XY, reward_fn=minitaur_reward,
)

#: the catalogue entry (registered in ``harness.envs.ENVS``): no demonstrations (EARL's ``has_demos()`` is False for
#: minitaur), no scripted experts; RISC's budget of 5M steps
MINITAUR = EnvInfo(spec=MINITAUR_SPEC, label="Minitaur", env_class="harness.envs.minitaur:MinitaurEnv",
                   default_steps=5_000_000, bench_steps=1_000, demos=False, requires=("pybullet", "minitaur", "3.11"),
                   published_metric="deployed_return")
