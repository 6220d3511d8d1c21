"""Is our sawyer_peg / sawyer_door (MuJoCo 3, Meta-World 3) easier than EARL's original (mujoco-py, MuJoCo 2)?

The same seeded initial states and the same action (or noise) sequences are run on

- ``earl``: EARL's env logic (``earl_benchmark/envs/sawyer_peg.py`` / ``sawyer_door.py`` on the Meta-World master of
  2021, ``metaworld/envs/mujoco/sawyer_xyz/sawyer_xyz_env.py`` as of 48f6f688, unchanged to 2022-06) re-implemented
  here directly on the ``mujoco`` python bindings and EARL's own model XML. Run it on MuJoCo 2.2.1, the newest
  release whose weld equality still has mujoco-py 2.1's 7-number ``eq_data`` (relpose, no ``torquescale``; 2.2.2
  added ``torquescale``). Its wheels stop at CPython 3.10, so it needs a Python 3.10 venv. Run on MuJoCo >= 2.2.2 the
  same code uses Meta-World 3's weld data (relquat (-1, 0, 0, 0), torquescale 5) and is reported as ``earl@mj3``: a
  control that isolates our env code from the engine.
- ``ours``: ``harness.envs.sawyer.SawyerPegEnv`` / ``SawyerDoorEnv`` (MuJoCo 3, Meta-World 3) in the project venv.

What EARL's logic is, here: reset = ``mj_resetData``; 50 x (mocap at ``hand_init_pos``, mocap quat (1, 0, 1, 0),
ctrl (-1, 1), 5 x ``mj_step``); then the object (peg: box body at goal - (0.03, 0, 0.13), peg free joint xyz =
drawn position, its settled orientation kept, qvel zeroed; door: door body at (0.1, 0.95, 0.1) (float32), hinge at
-pi/3 + U(0, pi/20)) and ``mj_forward``. Step = mocap += clip(a[:3], -1, 1) * 0.01, clipped to the hand box
(-0.5, 0.40, 0.05)-(0.5, 1, 0.5); ctrl = (a3, -a3) (the actuators' ctrlrange clamps); 5 x ``mj_step``; the
observation is read right after the last ``mj_step`` as mujoco-py did (positions one substep stale), the reset's
after ``mj_forward`` (fresh). Observation = hand body xyz, ||rightEndEffector - leftEndEffector|| / 0.1 clipped to
[0, 1] (Meta-World 2021; Meta-World 3 uses the claw bodies, which give the same number in this model), peg-head
site / handle geom xyz, goal (7).

Randomness: numpy Generators only (``np.random.default_rng([seed, ...])``); the global ``np.random`` is not used.
Initial states are drawn here and imposed on both engines (ours: ``env.reset()`` then Meta-World's
``_set_obj_xyz`` with the drawn peg xyz / hinge angle, which is what our reset does with its own draw).

Statistics (sections of the JSON and of the Markdown report):

- ``reset``: the reset state (hand, opening, object; hand tilt against the mocap quaternion; peg tilt) against
  EARL's published initial states;
- ``expert``: the scripted forward experts (``harness/envs/sawyer_experts.py``, loaded by file path, numpy only)
  with Gaussian action noise, closed loop: success at any step, median first-success step, success at the last step;
- ``explore``: uniform random actions (i.i.d. and held for 10 steps) and the expert at high noise: how often the
  object moves / is lifted / reaches the goal, and how far it moves;
- ``demos``: open-loop replay of EARL's forward demos from their initial states: success and per-step position
  error against the demos' recorded ``next_observations``;
- ``staleness`` (``earl`` engine only): how far EARL's observation (read after ``mj_step``) is from the state's own.

Validation of the ``earl`` engine: on MuJoCo 2.2.1 its resets give EARL's published initial states to the last
printed digit (peg hand (0.00615235, 0.6001898, 0.19430117), door hand and handle), and it replays 8 of EARL's 10
forward peg demos to within float32 rounding of their recorded ``next_observations`` (the other 2 diverge after a
contact, by at most 1.1 mm). Door demos match until the first hand-door contact (box-cylinder), then drift by
1-2 mm (median): that contact differs between MuJoCo 2.2.x and the engine EARL recorded with.

Usage (each run takes 2-3 minutes of one core; nothing is written but ``--out``)::

    # once: a Python 3.10 venv with MuJoCo 2.2.1 (not the project venv; on this workplace's machines
    # /root/.pyenv/versions/3.10.13/bin/python3.10 is a Python 3.10)
    python3.10 -m venv /root/mj2venv && /root/mj2venv/bin/pip install mujoco==2.2.1 "numpy<2"

    /root/mj2venv/bin/python scripts/earl_engine_compare.py run --engine earl --out /tmp/earl_mj2.json.gz
    .venv/bin/python scripts/earl_engine_compare.py run --engine ours --out /tmp/ours_mj3.json.gz
    .venv/bin/python scripts/earl_engine_compare.py run --engine earl --out /tmp/earl_mj3.json.gz   # optional control
    .venv/bin/python scripts/earl_engine_compare.py compare /tmp/earl_mj2.json.gz /tmp/ours_mj3.json.gz [/tmp/earl_mj3.json.gz]

``compare`` (either venv) prints Markdown tables; the first file is the reference for the paired (discordant-episode)
counts. ``--out`` ending in ``.gz`` writes gzipped JSON. The shipped results of stop 51 are in
``docs/earl_env_comparison/`` (``docs/earl_env_comparison.md`` reads them)::

    .venv/bin/python scripts/earl_engine_compare.py compare docs/earl_env_comparison/{earl_mj2,ours_mj3,earl_mj3}.json.gz
The EARL data directory (``assets/metaworld_earl``, ``demos/``) is found as the harness finds it:
``--data-dir``, ``HARNESS_DATA_DIR``, ``<project>/.cache/earl``, ``<project>/../shared/earl``.
"""

from __future__ import annotations

import argparse
import gzip
import importlib.util
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# ---- EARL's constants (earl_benchmark/envs/sawyer_peg.py:18-50, sawyer_door.py:13-16) -----------------------------
PEG_HAND_PUBLISHED = np.array([0.00615235, 0.6001898, 0.19430117, 1.0])
PEG_HEADS_PUBLISHED = np.array(
    [
        [0.00313463, 0.68326396],
        [-0.04035005, 0.67949003],
        [0.02531051, 0.6074387],
        [0.05957219, 0.6271171],
        [-0.07566337, 0.62575287],
        [-0.01177235, 0.55206996],
        [0.02779735, 0.54707706],
        [0.01835314, 0.5329686],
        [0.02690855, 0.6263067],
        [0.01766127, 0.59630984],
        [0.0560186, 0.6634998],
        [-0.03950658, 0.6323736],
        [-0.03216827, 0.5247563],
        [0.01265727, 0.69466716],
        [0.05076993, 0.6025737],
    ]
)
PEG_GOAL = np.array([0.0, 0.6, 0.2, 1.0, -0.3 + 0.03, 0.6, 0.0 + 0.13])
PEG_OBJ_LOW, PEG_OBJ_HIGH = np.array([0.0, 0.5, 0.02]), np.array([0.2, 0.7, 0.02])
PEG_HEAD_OFFSET = np.array([-0.1, 0.0, 0.0])  # pegHead site in the peg body frame (the XML)
DOOR_INITIAL_PUBLISHED = np.array([0.00591636, 0.39968333, 0.19493164, 1.0, 0.01007495, 0.47104556, 0.10003595])
DOOR_GOAL = np.array([0.29072163, 0.74286009, 0.10003595, 1.0, 0.29072163, 0.74286009, 0.10003595])
TASKS = {
    "peg": {
        "xml": "sawyer_peg_insertion_side.xml",
        "hand_init": np.array([0.0, 0.6, 0.2]),
        "goal": PEG_GOAL,
        "threshold": 0.05,
        "horizon": 200,
        "published": np.concatenate([PEG_HAND_PUBLISHED, [np.nan] * 3]),
    },
    "door": {
        "xml": "sawyer_door_pull.xml",
        "hand_init": np.array([0, 0.4, 0.2], dtype=np.float32).astype(np.float64),
        "goal": DOOR_GOAL,
        "threshold": 0.02,
        "horizon": 300,
        "published": DOOR_INITIAL_PUBLISHED,
    },
}
HAND_LOW, HAND_HIGH = np.array([-0.5, 0.40, 0.05]), np.array([0.5, 1.0, 0.5])  # both tasks' hand_low / hand_high
DOOR_BODY_POS = np.array([0.1, 0.95, 0.1], dtype=np.float32).astype(np.float64)
DOOR_ANGLE0, DOOR_ANGLE_NOISE = -np.pi / 3, np.pi / 20
MOCAP_QUAT = np.array([1.0, 0.0, 1.0, 0.0])
SETTLE_STEPS, FRAME_SKIP, ACTION_SCALE = 50, 5, 0.01


def data_dir(explicit: str | None) -> Path:
    cands = (
        [Path(explicit)]
        if explicit
        else (
            [Path(os.environ["HARNESS_DATA_DIR"])]
            if os.environ.get("HARNESS_DATA_DIR")
            else [Path(os.environ.get("HARNESS_CACHE_DIR", ROOT / ".cache" / "earl")), ROOT.parent / "shared" / "earl"]
        )
    )
    for c in cands:
        if (c.expanduser() / "assets" / "metaworld_earl").exists():
            return c.expanduser()
    sys.exit(f"EARL data (assets/metaworld_earl) not found in {[str(c) for c in cands]}; use --data-dir")


def load_experts():
    """harness/envs/sawyer_experts.py by file path (numpy only: runs in the MuJoCo 2 venv without the project)."""
    spec = importlib.util.spec_from_file_location("_sawyer_experts", ROOT / "harness" / "envs" / "sawyer_experts.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def quat_angle_deg(q1, q2) -> float:
    q1, q2 = np.asarray(q1, float) / np.linalg.norm(q1), np.asarray(q2, float) / np.linalg.norm(q2)
    return float(np.degrees(2 * math.acos(min(1.0, abs(float(np.dot(q1, q2)))))))


# ------------------------------------------------------------------------------------------------------------------
# engines: reset(obj) -> obs, step(a) -> obs, plus a few probes (hand quat, peg quat)
# ------------------------------------------------------------------------------------------------------------------


class EarlSawyer:
    """EARL's SawyerPegV2 / SawyerDoorV2 logic on the ``mujoco`` bindings (see the module docstring)."""

    def __init__(self, task: str, assets: Path):
        import mujoco

        self.mj, self.task, self.cfg = mujoco, task, TASKS[task]
        self.m = mujoco.MjModel.from_xml_path(str(assets / "sawyer_xyz" / self.cfg["xml"]))
        self.d = mujoco.MjData(self.m)
        m, name = self.m, mujoco.mj_name2id
        self.weld_semantics = (
            "mujoco-py 2.1 (7-number eq_data)"
            if m.eq_data.shape[1] == 7
            else "MuJoCo >= 2.2.2 (Meta-World 3's relquat (-1,0,0,0), torquescale 5)"
        )
        for i in range(m.neq):  # Meta-World 2021 reset_mocap_welds (sawyer_xyz_env.py:70-78)
            if m.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
                m.eq_data[i] = [0, 0, 0, 1, 0, 0, 0] if m.eq_data.shape[1] == 7 else [0, 0, 0, 0, 0, 0, -1, 0, 0, 0, 5]
        mujoco.mj_forward(m, self.d)
        B, S, G, J = (
            mujoco.mjtObj.mjOBJ_BODY,
            mujoco.mjtObj.mjOBJ_SITE,
            mujoco.mjtObj.mjOBJ_GEOM,
            mujoco.mjtObj.mjOBJ_JOINT,
        )
        self.hand = name(m, B, "hand")
        self.ree, self.lee = name(m, S, "rightEndEffector"), name(m, S, "leftEndEffector")
        self.goal = self.cfg["goal"].copy()
        if task == "peg":
            self.obj_site = name(m, S, "pegHead")
            self.box = name(m, B, "box")
            self.peg_body = name(m, B, "peg")
        else:
            self.handle = name(m, G, "handle")
            self.door_body = name(m, B, "door")
            self.door_jnt = name(m, J, "doorjoint")
            self.door_adr = int(m.jnt_qposadr[self.door_jnt])  # Meta-World 2021 uses the qpos address for qvel too
        self.first_reset_obs = self.reset(self.default_obj()).tolist()  # EARL moves box/door after the 1st settling
        if task == "door":
            self._hinge_setup()

    def default_obj(self):
        return np.array([0.0, 0.6, 0.02]) if self.task == "peg" else DOOR_ANGLE0

    def _hinge_setup(self):
        d2 = self.mj.MjData(self.m)
        self.mj.mj_kinematics(self.m, d2)
        self.hinge_xy = d2.xanchor[self.door_jnt][:2].copy()
        r0 = d2.geom_xpos[self.handle][:2] - self.hinge_xy
        self.phase0 = math.atan2(r0[1], r0[0])

    def handle_to_angle(self, p) -> float:
        r = np.asarray(p[:2], float) - self.hinge_xy
        return float((math.atan2(r[1], r[0]) - self.phase0 + math.pi) % (2 * math.pi) - math.pi)

    def _substeps(self, n):
        for _ in range(n):
            self.mj.mj_step(self.m, self.d)

    def obs(self) -> np.ndarray:
        d = self.d
        opening = float(np.clip(np.linalg.norm(d.site_xpos[self.ree] - d.site_xpos[self.lee]) / 0.1, 0.0, 1.0))
        obj = d.site_xpos[self.obj_site] if self.task == "peg" else d.geom_xpos[self.handle]
        return np.concatenate([d.xpos[self.hand], [opening], obj, self.goal])

    def reset(self, obj) -> np.ndarray:
        m, d = self.m, self.d
        self.mj.mj_resetData(m, d)
        for _ in range(SETTLE_STEPS):  # Meta-World 2021 _reset_hand (sawyer_xyz_env.py:461-466)
            d.mocap_pos[0] = self.cfg["hand_init"]
            d.mocap_quat[0] = MOCAP_QUAT
            d.ctrl[0], d.ctrl[1] = -1.0, 1.0
            self._substeps(FRAME_SKIP)
        if self.task == "peg":  # sawyer_peg.py:194-217; _set_obj_xyz (sawyer_xyz_env.py:190-195)
            m.body_pos[self.box] = PEG_GOAL[4:] - np.array([0.03, 0.0, 0.13])
            d.qpos[9:12] = obj
            d.qvel[9:15] = 0.0
        else:  # sawyer_door.py:111-125; SawyerDoorEnvV2._set_obj_xyz (sawyer_door_v2.py:83-88)
            m.body_pos[self.door_body] = DOOR_BODY_POS
            d.qpos[self.door_adr] = obj
            d.qvel[self.door_adr] = 0.0
        self.mj.mj_forward(m, d)  # MujocoEnv.set_state -> sim.forward()
        return self.obs()

    def step(self, a) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        d = self.d
        pos = np.clip(d.mocap_pos[0] + np.clip(a[:3], -1, 1) * ACTION_SCALE, HAND_LOW, HAND_HIGH)
        d.mocap_pos[0] = pos
        d.mocap_quat[0] = MOCAP_QUAT
        d.ctrl[0], d.ctrl[1] = a[3], -a[3]
        self._substeps(FRAME_SKIP)
        return self.obs()  # no mj_forward: mujoco-py's observation after sim.step()

    def fresh_obs(self) -> np.ndarray:
        """The observation of the current state (``mj_kinematics``; the next ``mj_step`` recomputes it anyway)."""
        self.mj.mj_kinematics(self.m, self.d)
        return self.obs()

    def hand_quat(self):
        return self.d.xquat[self.hand].copy()

    def peg_quat(self):
        return self.d.xquat[self.peg_body].copy()

    def mocap_pos(self):
        return self.d.mocap_pos[0].copy()


class OursSawyer:
    """Our gymnasium env (harness.envs.sawyer) with the initial object imposed after its reset."""

    def __init__(self, task: str, assets: Path):
        os.environ.setdefault("HARNESS_DATA_DIR", str(assets.parent.parent))
        from harness.envs.sawyer import SawyerDoorEnv, SawyerPegEnv

        self.task, self.cfg = task, TASKS[task]
        self.env = SawyerPegEnv() if task == "peg" else SawyerDoorEnv()
        self.m, self.d = self.env.model, self.env.data
        self.weld_semantics = "MuJoCo 3 (Meta-World 3's relquat (-1,0,0,0), torquescale 5)"
        self.first_reset_obs = self.reset(self.default_obj()).tolist()  # (ours places box/door in __init__)
        if task == "door":
            self.handle_to_angle = self.env.handle_to_angle
        import mujoco

        self.hand = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_BODY, "hand")
        self.peg_body = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_BODY, "peg") if task == "peg" else None

    def default_obj(self):
        return np.array([0.0, 0.6, 0.02]) if self.task == "peg" else DOOR_ANGLE0

    def reset(self, obj) -> np.ndarray:
        self.env.reset(seed=0)
        self.env._set_obj_xyz(np.asarray(obj, dtype=np.float64))  # what our _object_random_reset does with its draw
        return self.env._make_obs().astype(np.float64)

    def step(self, a) -> np.ndarray:
        return self.env.step(np.asarray(a, dtype=np.float64))[0].astype(np.float64)

    def hand_quat(self):
        return self.d.xquat[self.hand].copy()

    def peg_quat(self):
        return self.d.xquat[self.peg_body].copy()

    def mocap_pos(self):
        return self.d.mocap_pos[0].copy()


# ------------------------------------------------------------------------------------------------------------------
# experiments
# ------------------------------------------------------------------------------------------------------------------


def success(obs, thr) -> bool:
    return bool(np.linalg.norm(obs[4:7] - obs[11:14]) <= thr)


def info_success(obs, task) -> bool:
    """EARL's ``info["success"]`` from ``evaluate_state`` (not its reward): peg ``||(head - goal) * (1, 2, 2)|| <= 0.05``
    (sawyer_peg.py:169-171, 241-243), door ``||handle - goal|| <= 0.08`` (sawyer_door.py:129-133, 149)."""
    if task == "peg":
        return bool(np.linalg.norm((obs[4:7] - obs[11:14]) * np.array([1.0, 2.0, 2.0])) <= 0.05)
    return bool(np.linalg.norm(obs[4:7] - obs[11:14]) <= 0.08)


def draw_obj(task, rng):
    if task == "peg":  # sawyer_peg.py:210-213 (_get_state_rand_vec, uniform in the obj box; the box test never fires)
        return rng.uniform(PEG_OBJ_LOW, PEG_OBJ_HIGH)
    return DOOR_ANGLE0 + rng.uniform(0.0, DOOR_ANGLE_NOISE)  # sawyer_door.py:116-121


def rollout(eng, obj, expert, acts, thr):
    """One episode of ``len(acts)`` steps; action ``expert(obs) + acts[t]`` (``expert=None``: ``acts[t]``, open loop),
    clipped to [-1, 1]. Per-episode summary (object motion, success)."""
    o = eng.reset(obj)
    o0 = o.copy()
    first = first_info = None
    hand_path = 0.0
    max_disp = max_lift = 0.0
    in_goal = 0
    prev_hand = o[0:3].copy()
    mocap_gap = 0.0
    horizon = len(acts)
    for t in range(horizon):
        a = np.clip(acts[t] if expert is None else expert(o) + acts[t], -1.0, 1.0)
        o = eng.step(a)
        hand_path += float(np.linalg.norm(o[0:3] - prev_hand))
        prev_hand = o[0:3].copy()
        mocap_gap += float(np.linalg.norm(eng.mocap_pos() - o[0:3]))
        disp = float(np.linalg.norm(o[4:7] - o0[4:7]))
        max_disp = max(max_disp, disp)
        max_lift = max(max_lift, float(o[6] - o0[6]))
        s = success(o, thr)
        in_goal += s
        if s and first is None:
            first = t + 1
        if first_info is None and info_success(o, eng.task):
            first_info = t + 1
    return {
        "first": first,
        "first_info": first_info,
        "final": success(o, thr),
        "steps_in_goal": in_goal,
        "max_disp": max_disp,
        "max_lift": max_lift,
        "final_disp": float(np.linalg.norm(o[4:7] - o0[4:7])),
        "hand_step_mm": 1000 * hand_path / horizon,
        "mocap_gap_mm": 1000 * mocap_gap / horizon,
    }


def exp_reset(eng, task):
    cfg = TASKS[task]
    rows = []
    objs = (
        [np.array([h[0], h[1], 0.02]) - PEG_HEAD_OFFSET for h in PEG_HEADS_PUBLISHED]
        if task == "peg"
        else [DOOR_ANGLE0]
    )
    for obj in objs:
        o = eng.reset(obj)
        row = {
            "obs": o[:7].tolist(),
            "hand_tilt_deg": quat_angle_deg(eng.hand_quat(), MOCAP_QUAT),
            "hand_err_mm": (1000 * (o[0:3] - cfg["published"][0:3])).tolist(),
            "hand_mocap_gap_mm": 1000 * float(np.linalg.norm(eng.mocap_pos() - o[0:3])),
        }
        if task == "peg":
            row["head_err_mm"] = 1000 * float(np.linalg.norm(o[4:6] - (obj + PEG_HEAD_OFFSET)[:2]))
            row["head_z"] = float(o[6])
            row["peg_tilt_deg"] = quat_angle_deg(eng.peg_quat(), [1, 0, 0, 0])
        else:
            row["handle_err_mm"] = (1000 * (o[4:7] - cfg["published"][4:7])).tolist()
        rows.append(row)
    again = eng.reset(eng.default_obj())  # the first reset's object, on a later reset
    return {
        "states": rows,
        "first_reset_obs": eng.first_reset_obs,
        "first_vs_later_max_abs": float(np.max(np.abs(np.array(eng.first_reset_obs[:7]) - again[:7]))),
    }


def exp_expert(eng, task, experts, sigmas, n_ep, seed):
    cfg = TASKS[task]
    fn = experts.peg_forward if task == "peg" else experts.door_forward
    out = {}
    for si, sigma in enumerate(sigmas):
        eps = []
        for e in range(n_ep):
            rng = np.random.default_rng([seed, 1, e])  # the initial state: the same for every sigma
            obj = draw_obj(task, rng)
            noise = np.random.default_rng([seed, 2, si, e]).normal(0.0, 1.0, (cfg["horizon"], 4)) * sigma
            eps.append(rollout(eng, obj, fn, noise, cfg["threshold"]))
        out[str(sigma)] = eps
    return out


def exp_explore(eng, task, experts, n_ep, seed):
    cfg = TASKS[task]
    fn = experts.peg_forward if task == "peg" else experts.door_forward
    H = cfg["horizon"]
    out = {}
    for pi, pol in enumerate(["uniform", "uniform_hold10", "expert+N(0,1)", "expert+N(0,2)"]):
        eps = []
        for e in range(n_ep):
            obj = draw_obj(task, np.random.default_rng([seed, 3, e]))
            r = np.random.default_rng([seed, 4, pi, e])
            if pol == "uniform":
                expert, acts = None, r.uniform(-1, 1, (H, 4))
            elif pol == "uniform_hold10":
                expert, acts = None, np.repeat(r.uniform(-1, 1, (H // 10 + 1, 4)), 10, axis=0)[:H]
            else:
                expert, acts = fn, r.normal(0.0, 1.0 if pol == "expert+N(0,1)" else 2.0, (H, 4))
            eps.append(rollout(eng, obj, expert, acts, cfg["threshold"]))
        out[pol] = eps
    return out


def exp_staleness(eng, task, experts, seed, n_ep=10):
    """EARL's step observation (read after ``mj_step``: one substep stale) against the current state's (ours)."""
    if not hasattr(eng, "fresh_obs"):
        return None
    cfg = TASKS[task]
    fn = experts.peg_forward if task == "peg" else experts.door_forward
    out = {}
    for pol in ("uniform", "expert"):
        hand, obj = [], []
        for e in range(n_ep):
            o = eng.reset(draw_obj(task, np.random.default_rng([seed, 5, e])))
            acts = np.random.default_rng([seed, 6, e]).uniform(-1, 1, (cfg["horizon"], 4))
            for t in range(cfg["horizon"]):
                o = eng.step(acts[t] if pol == "uniform" else np.clip(fn(o), -1, 1))
                f = eng.fresh_obs()
                hand.append(1000 * float(np.linalg.norm(o[0:3] - f[0:3])))
                obj.append(1000 * float(np.linalg.norm(o[4:7] - f[4:7])))
        out[pol] = {
            "hand_mean_mm": float(np.mean(hand)),
            "hand_max_mm": float(np.max(hand)),
            "obj_mean_mm": float(np.mean(obj)),
            "obj_max_mm": float(np.max(obj)),
        }
    return out


def exp_demos(eng, task, ddir: Path):
    cfg = TASKS[task]
    z = np.load(ddir / "demos" / f"sawyer_{task}" / "forward.npz")
    obs, act, nxt, term = z["observations"], z["actions"], z["next_observations"], z["terminals"][:, 0]
    ends = np.where(term)[0]
    starts = np.concatenate([[0], ends[:-1] + 1])
    rows = []
    for s, e in zip(starts, ends):
        o0 = obs[s]
        obj = (o0[4:7] - PEG_HEAD_OFFSET) if task == "peg" else eng.handle_to_angle(o0[4:7])
        o = eng.reset(obj)
        init_err = float(np.linalg.norm(o[:7] - o0[:7]))
        hand_err, obj_err, any_s = [], [], False
        for t in range(s, e + 1):
            o = eng.step(act[t])
            hand_err.append(float(np.linalg.norm(o[0:3] - nxt[t][0:3])))
            obj_err.append(float(np.linalg.norm(o[4:7] - nxt[t][4:7])))
            any_s |= success(o, cfg["threshold"])
        rows.append(
            {
                "len": int(e - s + 1),
                "init_err_mm": 1000 * init_err,
                "final": success(o, cfg["threshold"]),
                "any": bool(any_s),
                "final_goal_dist": float(np.linalg.norm(o[4:7] - o[11:14])),
                "demo_final_goal_dist": float(np.linalg.norm(nxt[e][4:7] - nxt[e][11:14])),
                "hand_err_mm": [1000 * x for x in hand_err],
                "obj_err_mm": [1000 * x for x in obj_err],
            }
        )
    return rows


def model_info(eng) -> dict:
    import mujoco

    o = eng.m.opt
    names = {
        "integrator": ["Euler", "RK4", "implicit", "implicitfast"],
        "cone": ["pyramidal", "elliptic"],
        "solver": ["PGS", "CG", "Newton"],
        "jacobian": ["dense", "sparse", "auto"],
    }
    info = {k: names[k][int(getattr(o, k))] for k in names}
    for k in ("timestep", "iterations", "tolerance", "noslip_iterations", "impratio", "disableflags", "enableflags"):
        info[k] = float(getattr(o, k)) if k in ("timestep", "tolerance", "impratio") else int(getattr(o, k))
    info["weld_eq_data"] = [float(x) for x in eng.m.eq_data[0]]
    info["weld_solref"] = [float(x) for x in eng.m.eq_solref[0]]
    info["weld_semantics"] = eng.weld_semantics
    info["mujoco"] = mujoco.__version__
    info["nq"], info["nv"], info["ngeom"] = int(eng.m.nq), int(eng.m.nv), int(eng.m.ngeom)
    return info


def run(args):
    ddir = data_dir(args.data_dir)
    assets = ddir / "assets" / "metaworld_earl"
    experts = load_experts()
    import mujoco

    engine = args.engine
    if engine == "earl":
        ver = tuple(int(x) for x in mujoco.__version__.split(".")[:3])
        label = "earl@mj2" if ver < (2, 2, 2) else "earl@mj3"
        mk = lambda task: EarlSawyer(task, assets)
    else:
        label = "ours"
        sys.path.insert(0, str(ROOT))
        mk = lambda task: OursSawyer(task, assets)
    n = args.episodes
    res = {
        "engine": label,
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "seed": args.seed,
        "episodes": n,
        "tasks": {},
    }
    t0 = time.time()
    for task in args.tasks:
        eng = mk(task)
        tt = time.time()
        r = {"model": model_info(eng), "reset": exp_reset(eng, task)}
        r["expert"] = exp_expert(
            eng, task, experts, [0.0, 0.3, 0.6, 1.0], n if task == "peg" else max(n // 2, 1), args.seed
        )
        r["explore"] = exp_explore(eng, task, experts, n, args.seed)
        r["demos"] = exp_demos(eng, task, ddir)
        r["staleness"] = exp_staleness(eng, task, experts, args.seed)
        r["wall_s"] = time.time() - tt
        res["tasks"][task] = r
        print(f"{label} {task}: {r['wall_s']:.0f}s", file=sys.stderr)
    res["wall_s"] = time.time() - t0
    data = json.dumps(res).encode()
    Path(args.out).write_bytes(gzip.compress(data, mtime=0) if args.out.endswith(".gz") else data)
    print(f"wrote {args.out} ({res['wall_s']:.0f}s)", file=sys.stderr)


# ------------------------------------------------------------------------------------------------------------------
# compare: Markdown tables
# ------------------------------------------------------------------------------------------------------------------


def _fmt(x, nd=2):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def _med(xs):
    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def _wilson(k, n, z=1.96):
    if n == 0:
        return (float("nan"),) * 2
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return c - h, c + h


def compare(args):
    runs = [json.loads(gzip.decompress(Path(f).read_bytes()) if f.endswith(".gz") else Path(f).read_bytes())
            for f in args.files]
    ref = runs[0]
    L = []
    p = L.append
    p("### Engines\n")
    p(
        "| run | python | mujoco | weld eq_data | weld semantics | integrator | cone | solver | iterations | tolerance "
        "| jacobian | timestep | wall s |"
    )
    p("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in runs:
        mi = r["tasks"]["peg"]["model"]
        p(
            f"| {r['engine']} | {r['python']} | {r['mujoco']} | {' '.join(f'{x:g}' for x in mi['weld_eq_data'])} | "
            f"{mi['weld_semantics']} | {mi['integrator']} | {mi['cone']} | {mi['solver']} | {mi['iterations']} | "
            f"{mi['tolerance']:g} | {mi['jacobian']} | {mi['timestep']:g} | {r['wall_s']:.0f} |"
        )
    for task in ("peg", "door"):
        if task not in ref["tasks"]:
            continue
        pub = TASKS[task]["published"]
        p(
            f"\n### {task}: reset state (EARL's published: hand {pub[:3].round(5).tolist()}, opening 1.0"
            + (f", handle {pub[4:7].round(5).tolist()})" if task == "door" else ")")
            + "\n"
        )
        p(
            "| run | hand xyz | hand - published (mm) | opening | hand tilt vs mocap (deg) | hand-mocap gap (mm) | "
            + ("peg head xy error (mm) / head z / peg tilt (deg) | " if task == "peg" else "handle - published (mm) | ")
            + "1st reset vs later (max abs) |"
        )
        p("|---|---|---|---|---|---|---|---|")
        for r in runs:
            rs = r["tasks"][task]["reset"]
            st = rs["states"]
            o = st[0]["obs"]
            spread = max(abs(a - b) for s in st for a, b in zip(s["obs"][:3], o[:3]))
            extra = (
                f"max {max(s['head_err_mm'] for s in st):.3f} / {min(s['head_z'] for s in st):.5f}-"
                f"{max(s['head_z'] for s in st):.5f} / max {max(s['peg_tilt_deg'] for s in st):.2f}"
                if task == "peg"
                else " ".join(f"{x:+.2f}" for x in st[0]["handle_err_mm"])
            )
            p(
                f"| {r['engine']} | {' '.join(f'{x:.5f}' for x in o[:3])} (spread {spread:.1e}) | "
                f"{' '.join(f'{x:+.2f}' for x in st[0]['hand_err_mm'])} | {o[3]:.4f} | {st[0]['hand_tilt_deg']:.2f} | "
                f"{st[0]['hand_mocap_gap_mm']:.2f} | {extra} | {rs['first_vs_later_max_abs']:.1e} |"
            )
        p(
            f"\n### {task}: scripted forward expert + N(0, sigma^2) action noise, closed loop "
            f"({TASKS[task]['horizon']}-step episodes, success = object within {TASKS[task]['threshold']} of the goal)\n"
        )
        p(
            "| sigma | run | success at any step (95% CI) | median first-success step | success at last step | "
            f"median steps in goal | discordant episodes vs {ref['engine']} (only ref / only this) | "
            "EARL info['success'] predicate: any step / median first step |"
        )
        p("|---|---|---|---|---|---|---|---|")
        for sigma in ref["tasks"][task]["expert"]:
            for r in runs:
                eps = r["tasks"][task]["expert"][sigma]
                rf = ref["tasks"][task]["expert"][sigma]
                k = sum(e["first"] is not None for e in eps)
                lo, hi = _wilson(k, len(eps))
                d1 = sum((a["first"] is not None) and (b["first"] is None) for a, b in zip(rf, eps))
                d2 = sum((a["first"] is None) and (b["first"] is not None) for a, b in zip(rf, eps))
                p(
                    f"| {sigma} | {r['engine']} | {k}/{len(eps)} ({lo:.2f}-{hi:.2f}) | "
                    f"{_fmt(_med([e['first'] for e in eps]), 0)} | {sum(e['final'] for e in eps)}/{len(eps)} | "
                    f"{_fmt(_med([e['steps_in_goal'] for e in eps]), 0)} | "
                    + ("-" if r is ref else f"{d1} / {d2}")
                    + " | "
                    + f"{sum(e['first_info'] is not None for e in eps)}/{len(eps)} / "
                    + f"{_fmt(_med([e['first_info'] for e in eps]), 0)} |"
                )
        p(f"\n### {task}: exploration ({TASKS[task]['horizon']}-step episodes from drawn initial states)\n")
        p(
            "| policy | run | object moved > 1 cm | lifted > 2 cm | any success | any EARL info['success'] | "
            "mean max displacement (cm) | mean final displacement (cm) | mean hand step (mm) | mean hand-mocap gap (mm) |"
        )
        p("|---|---|---|---|---|---|---|---|---|---|")
        for pol in ref["tasks"][task]["explore"]:
            for r in runs:
                eps = r["tasks"][task]["explore"][pol]
                n = len(eps)
                p(
                    f"| {pol} | {r['engine']} | {sum(e['max_disp'] > 0.01 for e in eps)}/{n} | "
                    f"{sum(e['max_lift'] > 0.02 for e in eps)}/{n} | {sum(e['first'] is not None for e in eps)}/{n} | "
                    f"{sum(e['first_info'] is not None for e in eps)}/{n} | "
                    f"{100 * np.mean([e['max_disp'] for e in eps]):.2f} | "
                    f"{100 * np.mean([e['final_disp'] for e in eps]):.2f} | "
                    f"{np.mean([e['hand_step_mm'] for e in eps]):.2f} | {np.mean([e['mocap_gap_mm'] for e in eps]):.2f} |"
                )
        p(f"\n### {task}: open-loop replay of EARL's forward demos (errors against the demos' next_observations)\n")
        p(
            "| run | success at last step | success at any step | initial-state error (mm, max) | hand error (mm) "
            "median / 90% / max | object error (mm) median / 90% / max | final goal distance per demo (m) |"
        )
        p("|---|---|---|---|---|---|---|")
        for r in runs:
            ds = r["tasks"][task]["demos"]
            he = np.concatenate([d["hand_err_mm"] for d in ds])
            oe = np.concatenate([d["obj_err_mm"] for d in ds])
            p(
                f"| {r['engine']} | {sum(d['final'] for d in ds)}/{len(ds)} | {sum(d['any'] for d in ds)}/{len(ds)} | "
                f"{max(d['init_err_mm'] for d in ds):.3f} | {np.median(he):.3f} / {np.percentile(he, 90):.3f} / "
                f"{he.max():.3f} | {np.median(oe):.3f} / {np.percentile(oe, 90):.3f} / {oe.max():.3f} | "
                + " ".join(f"{d['final_goal_dist']:.3f}" for d in ds)
                + " |"
            )
        p(
            "| (demo as recorded) | | | | | | | "
            + " ".join(f"{d['demo_final_goal_dist']:.3f}" for d in ref["tasks"][task]["demos"])
            + " |"
        )
        st = [(r["engine"], r["tasks"][task].get("staleness")) for r in runs if r["tasks"][task].get("staleness")]
        if st:
            p(
                f"\n### {task}: EARL's observation staleness (obs read after mj_step vs the state's own; ours is fresh)\n"
            )
            p("| run | policy | hand mean / max (mm) | object mean / max (mm) |")
            p("|---|---|---|---|")
            for name, sd in st:
                for pol, v in sd.items():
                    p(
                        f"| {name} | {pol} | {v['hand_mean_mm']:.3f} / {v['hand_max_mm']:.3f} | "
                        f"{v['obj_mean_mm']:.3f} / {v['obj_max_mm']:.3f} |"
                    )
    print("\n".join(L))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the statistics on one engine, write JSON")
    r.add_argument("--engine", choices=["earl", "ours"], required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--episodes", type=int, default=200, help="episodes per setting (door expert: half)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--tasks", nargs="+", default=["peg", "door"], choices=["peg", "door"])
    r.add_argument("--data-dir", default=None)
    c = sub.add_parser("compare", help="Markdown tables from run JSONs (the first is the reference)")
    c.add_argument("files", nargs="+")
    a = ap.parse_args()
    run(a) if a.cmd == "run" else compare(a)


if __name__ == "__main__":
    main()
