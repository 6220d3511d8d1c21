"""EARL's kitchen on MuJoCo 2 against ours (``harness.envs.kitchen.KitchenEnv``, MuJoCo 3): resets and returns.

``run --engine earl`` re-implements EARL's kitchen logic (``earl_benchmark/envs/kitchen.py`` on adept_envs'
``KitchenV0`` / ``Robot_VelAct``, see ``harness/envs/kitchen.py``) directly on the ``mujoco`` bindings, procedurally
and in EARL's own call order (four separate noise draws per observation, 10 x 40 single ``mj_step`` calls at reset),
on EARL's scene files. On MuJoCo 2.2.1 (mujoco-py 2.1's weld data; the newest 2.x with wheels) it loads the scene
file as it is, unpatched; on MuJoCo 3 it applies the kettle patch (the kettle asset's top-level default class wrapped
in a plain ``<default>``) through an in-memory copy and, unless ``--mj3-weld``, gives the weld MuJoCo 2's
regularisation as our env does (``harness.envs.kitchen.mujoco2_weld``: before MuJoCo 3.0 all 6 weld rows used the
bodies' translational inverse weight). ``run --engine ours`` runs the project's env. Both seed numpy Generators the
same way and draw in the same order, so on the same engine they agree bit for bit, and across engines the difference
is MuJoCo's. Measured: ours (MuJoCo 3.3) against EARL's logic on MuJoCo 2.2.1: resets equal to 1e-15 rad, zero-action
returns equal, random-action returns within 0.01; with ``--mj3-weld`` the arm settles up to 0.26 rad elsewhere.

Per initial pair i (0-5, EARL's ``all_pairs`` order; reset seed i): the reset observation and true qpos, the return of
a 400-step (H_E) episode of zero actions and of uniform random actions (``default_rng(1000 + i)``), the final object
qpos. Usage (MuJoCo 2.2.1 needs Python <= 3.10; on this workplace ``/root/mj2venv`` has it)::

    /root/mj2venv/bin/python scripts/kitchen_engine_compare.py run --engine earl --out /tmp/kitchen_earl_mj2.json
    .venv/bin/python scripts/kitchen_engine_compare.py run --engine ours --out /tmp/kitchen_ours_mj3.json
    .venv/bin/python scripts/kitchen_engine_compare.py run --engine earl --out /tmp/kitchen_earl_mj3.json   # control
    .venv/bin/python scripts/kitchen_engine_compare.py compare /tmp/kitchen_earl_mj2.json /tmp/kitchen_ours_mj3.json

The kitchen assets are found as the harness finds them (``HARNESS_DATA_DIR``, else ``../shared/earl`` beside the
checkout) or given with ``--assets DIR`` (the ``assets/kitchen`` directory).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENE = "adept_envs/adept_envs/franka/assets/franka_kitchen_jntpos_act_ab.xml"
H_E = 400

# EARL's constants (kitchen.py, kitchen_multitask_v0.py, franka_config.xml), written out again so that this file runs
# without the project (Python 3.10, numpy < 2)
COMPONENTS = [("burner0", [9, 10], "knob1_site"), ("burner1", [11, 12], "knob2_site"),
              ("burner2", [13, 14], "knob3_site"), ("burner3", [15, 16], "knob4_site"),
              ("light_switch", [17, 18], "light_site"), ("slide_cabinet", [19], "slide_site"),
              ("hinge_cabinet", [20, 21], "hinge_site2"), ("microwave", [22], "microhandle_site")]
GOAL = np.array([-4.1336253e-01, -1.6970085e+00, 1.4286385e+00, -2.5005307e+00, 6.2198675e-01, 1.2632011e+00,
                 8.8903642e-01, 4.3514766e-02, 7.9217982e-03, -5.1586074e-04, 4.8548312e-04, -5.4527864e-06,
                 6.3510129e-06, 6.0837720e-05, -3.3861103e-05, 6.6394619e-05, -1.9801613e-05, -1.2477605e-04,
                 3.8065159e-04, -1.5148541e-04, -9.2229841e-04, 7.2293887e-03, 6.9650509e-03])
OPENED = {"microwave": ([22], [-0.7]), "light_switch": ([17, 18], [-0.69, -0.05]), "slide_cabinet": ([19], [0.37]),
          "hinge_cabinet": ([20, 21], [0.0, 1.45])}
PAIRS = [("microwave", "hinge_cabinet"), ("microwave", "slide_cabinet"), ("microwave", "light_switch"),
         ("light_switch", "slide_cabinet"), ("light_switch", "hinge_cabinet"), ("slide_cabinet", "hinge_cabinet")]
INIT_QPOS = np.array([1.48388023e-01, -1.76848573e+00, 1.84390296e+00, -2.47685760e+00, 2.60252026e-01,
                      7.12533105e-01, 1.59515394e+00, 4.79267505e-02, 3.71350919e-02])
PNOISE = np.array([0.1] * 9 + [0.005] * 2 + [0.0005] * 6 + [0.005] * 3 + [0.1] * 3)
VNOISE = np.array([0.1] * 9 + [0.005] * 11 + [0.1] * 3)
PBOUND = np.array([[-2.9, 2.9], [-1.8, 1.8], [-2.9, 2.9], [-3.1, 0.0], [-2.9, 2.9], [0.0, 3.8], [-2.9, 2.9],
                   [0.0, 0.04], [0.0, 0.04]])


def initial_state(i: int) -> np.ndarray:
    s = GOAL.copy()
    for name in PAIRS[i]:
        idx, val = OPENED[name]
        s[idx] = val
    return s


def assets_dir(given: str | None) -> Path:
    if given:
        return Path(given)
    base = Path(os.environ["HARNESS_DATA_DIR"]) if os.environ.get("HARNESS_DATA_DIR") else ROOT.parent / "shared" / "earl"
    return base / "assets" / "kitchen"


def load_earl_model(assets: Path, mj3_weld: bool = False):
    import mujoco

    path = assets / SCENE
    if int(mujoco.__version__.split(".")[0]) < 3:
        return mujoco.MjModel.from_xml_path(str(path))  # EARL's files as they are

    def expand(el, base):
        i = 0
        while i < len(el):
            c = el[i]
            if c.tag != "include":
                expand(c, base)
                i += 1
                continue
            inc = os.path.normpath(os.path.join(base, c.get("file")))
            kids = list(ET.parse(inc).getroot())
            if inc.endswith("kettle_asset.xml"):
                for j, k in enumerate(kids):
                    if k.tag == "default" and k.get("class"):
                        outer = ET.Element("default")
                        outer.append(k)
                        kids[j] = outer
            for k in kids:
                expand(k, os.path.dirname(inc))
            el[i:i + 1] = kids
            i += len(kids)

    root = ET.parse(path).getroot()
    expand(root, str(path.parent))
    for comp in root.iter("compiler"):
        for key in ("meshdir", "texturedir"):
            if comp.get(key):
                comp.set(key, os.path.normpath(os.path.join(str(path.parent), comp.get(key))))
    m = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    if not mj3_weld:  # MuJoCo 2's mj_diagApprox: every weld row with the translational inverse weight
        for i in np.flatnonzero(m.eq_type == mujoco.mjtEq.mjEQ_WELD):
            for b in (m.eq_obj1id[i], m.eq_obj2id[i]):
                m.body_invweight0[b, 1] = m.body_invweight0[b, 0]
    return m


class EarlKitchen:
    """EARL's kitchen logic, procedurally (mujoco-py's sim.step() = mj_step; sim.forward() = mj_forward)."""

    def __init__(self, assets: Path, mj3_weld: bool = False):
        import mujoco

        self.mj = mujoco
        self.m = load_earl_model(assets, mj3_weld)
        self.d = mujoco.MjData(self.m)
        self.cache = None
        self.goal = GOAL.copy()
        self.sites = {name: mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_SITE, site) for name, _, site in COMPONENTS}

    def get_obs(self, ratio: float) -> np.ndarray:  # franka_robot.Robot.get_obs + KitchenV0._get_obs
        d, r = self.d, self.rng
        qp, qv = d.qpos[:9].copy(), d.qvel[:9].copy()
        qp_obj, qv_obj = d.qpos[-14:].copy(), d.qvel[-14:].copy()
        qp += ratio * PNOISE[:9] * r.uniform(low=-1.0, high=1.0, size=9)
        qv += ratio * VNOISE[:9] * r.uniform(low=-1.0, high=1.0, size=9)
        qp_obj += ratio * PNOISE[-14:] * r.uniform(low=-1.0, high=1.0, size=14)
        qv_obj += ratio * VNOISE[-14:] * r.uniform(low=-1.0, high=1.0, size=14)
        self.cache = qp
        return np.concatenate([qp, qp_obj, self.goal])

    def robot_step(self, a: np.ndarray) -> None:  # Robot_VelAct.step
        dur = 40 * self.m.opt.timestep
        pos = self.cache[:9] + np.clip(a, -10, 10) * dur
        pos = np.clip(pos, PBOUND[:, 0], PBOUND[:, 1])
        for i in range(self.m.nu):
            self.d.ctrl[i] = pos[i]
        for _ in range(int(dur / self.m.opt.timestep)):
            self.mj.mj_step(self.m, self.d)

    def reset(self, seed: int, index: int) -> np.ndarray:
        mj, m, d = self.mj, self.m, self.d
        self.rng = np.random.default_rng(seed)
        self.rng.integers(1)  # the harness's env draws its (single) goal first
        mj.mj_resetData(m, d)
        d.qpos[:9] = INIT_QPOS
        d.qvel[:9] = 0.0
        d.qpos[-14:] = initial_state(index)[9:]
        d.qvel[-14:] = 0.0
        mj.mj_forward(m, d)
        for _ in range(5):
            self.get_obs(1.0)
        for _ in range(10):
            d.mocap_pos[:] = np.array([-0.440, 0.1, 2.226])
        for _ in range(10):
            self.robot_step(np.zeros(9))
        return self.get_obs(0.1)

    def step(self, a: np.ndarray) -> tuple[np.ndarray, float]:
        a = np.clip(a, -1.0, 1.0)
        a = np.zeros(9) + a * 2.0 * np.ones(9)
        new = np.clip(self.d.mocap_pos.copy() + a[:3] * np.array([0.01, 0.01, 0.01]), [-0.7, -0.1, 1.8], [0.4, 0.5, 2.6])
        self.d.mocap_pos[:] = new.copy()
        self.robot_step(a)
        obs = self.get_obs(0.1)
        return obs, self.reward(obs)

    def reward(self, obs: np.ndarray) -> float:  # Kitchen._get_reward_n_score
        r = -10 * np.linalg.norm(obs[9:23] - obs[9 + 23:23 + 23])
        reaching = False
        for name, idx, _ in COMPONENTS:
            idx = np.array(idx)
            if np.linalg.norm(obs[idx] - obs[idx + 23]) < len(idx) * 0.01:
                r += 1
            elif not reaching:
                reaching = True
                r += -0.5 * np.linalg.norm(self.d.mocap_pos[0] - self.d.site_xpos[self.sites[name]])
        return float(r)

    def qpos(self) -> np.ndarray:
        return self.d.qpos.copy()


class Ours:
    def __init__(self, assets: Path):
        sys.path.insert(0, str(ROOT))
        if os.environ.get("HARNESS_DATA_DIR") is None:
            os.environ["HARNESS_DATA_DIR"] = str(assets.parent.parent)
        from harness.envs.kitchen import KitchenEnv

        self.env = KitchenEnv()

    def reset(self, seed: int, index: int) -> np.ndarray:
        return self.env.reset(seed=seed, options={"initial_index": index})[0].astype(np.float64)

    def step(self, a):
        o, r, *_ = self.env.step(a)
        return o.astype(np.float64), r

    def qpos(self):
        return self.env.data.qpos.copy()


def run(engine: str, assets: Path, mj3_weld: bool = False) -> dict:
    import mujoco

    env = EarlKitchen(assets, mj3_weld) if engine == "earl" else Ours(assets)
    out = {"engine": engine + ("-mj3weld" if mj3_weld else ""), "mujoco": mujoco.__version__, "pairs": []}
    for i in range(len(PAIRS)):
        row = {"pair": "+".join(PAIRS[i])}
        for policy in ("zero", "random"):
            obs = env.reset(seed=i, index=i)
            if policy == "zero":
                row["reset_obs"], row["reset_qpos"] = obs.astype(np.float32).tolist(), env.qpos().tolist()
            acts = np.zeros((H_E, 9)) if policy == "zero" else np.random.default_rng(1000 + i).uniform(-1, 1, (H_E, 9))
            ret, success = 0.0, False
            for a in acts:
                obs, r = env.step(a)
                ret += r
                success |= bool(np.linalg.norm(obs[9:23] - obs[32:46]) <= 0.3)
            row[f"{policy}_return"], row[f"{policy}_success"] = ret, success
            row[f"{policy}_final_qpos"] = env.qpos().tolist()
        out["pairs"].append(row)
        print(f"{row['pair']:<28} zero {row['zero_return']:10.2f}   random {row['random_return']:10.2f}", flush=True)
    for k in ("zero", "random"):
        out[f"{k}_mean"] = float(np.mean([p[f"{k}_return"] for p in out["pairs"]]))
    print(f"{'mean':<28} zero {out['zero_mean']:10.2f}   random {out['random_mean']:10.2f}")
    return out


def compare(a: dict, b: dict) -> None:
    print(f"| pair | reset arm max abs diff (rad) | reset objects max diff | zero return {a['engine']}@{a['mujoco']} "
          f"| {b['engine']}@{b['mujoco']} | random return | | final objects max diff (zero / random) |")
    print("|---|---|---|---|---|---|---|---|")
    for p, q in zip(a["pairs"], b["pairs"]):
        arm = np.abs(np.subtract(p["reset_qpos"][:9], q["reset_qpos"][:9])).max()
        obj = np.abs(np.subtract(p["reset_qpos"][9:], q["reset_qpos"][9:])).max()
        fz = np.abs(np.subtract(p["zero_final_qpos"][9:], q["zero_final_qpos"][9:])).max()
        fr = np.abs(np.subtract(p["random_final_qpos"][9:], q["random_final_qpos"][9:])).max()
        print(f"| {p['pair']} | {arm:.2e} | {obj:.2e} | {p['zero_return']:.2f} | {q['zero_return']:.2f} | "
              f"{p['random_return']:.2f} | {q['random_return']:.2f} | {fz:.2e} / {fr:.2e} |")
    print(f"| mean | | | {a['zero_mean']:.2f} | {b['zero_mean']:.2f} | {a['random_mean']:.2f} | {b['random_mean']:.2f} | |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--engine", choices=("earl", "ours"), required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--assets")
    r.add_argument("--mj3-weld", action="store_true", help="earl engine on MuJoCo 3: keep MuJoCo 3's weld rows")
    c = sub.add_parser("compare")
    c.add_argument("files", nargs=2)
    args = ap.parse_args()
    if args.cmd == "run":
        Path(args.out).write_text(json.dumps(run(args.engine, assets_dir(args.assets), args.mj3_weld)))
    else:
        a, b = (json.loads(Path(f).read_text()) for f in args.files)
        compare(a, b)


if __name__ == "__main__":
    main()
