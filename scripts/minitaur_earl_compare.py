"""EARL's own minitaur code against ours (``harness.envs.minitaur.MinitaurEnv``): resets, steps, returns.

Runs EARL's unmodified ``envs/minitaur_gym_env.py``, ``minitaur.py`` and ``motor.py`` (read from an EARL checkout,
``--earl DIR``, or from a git mirror of it, ``--git-dir DIR``, at HEAD) on the pybullet installed here, with stand-ins
for what today's environment lacks: a ``gym`` module (``Env``, ``spaces``, ``utils.seeding``), ``pkg_resources``
(``parse_version``) and the ``pybullet_envs`` package namespace, so that pybullet's ``minitaur_env_randomizer.py`` loads
without that package's ``__init__`` (which registers gym envs). Nothing of EARL's is copied into the project.

Prints, for the tests' reference constants (``tests/test_minitaur.py``) and the env's docstring:

1. EARL's reset state without the randomizer, with pybullet's default contact-pair order and with
   ``deterministicOverlappingPairs=1`` (the setting our env uses), and ours;
2. 1000 steps of the same float64 actions on both, with ``deterministicOverlappingPairs=1`` on EARL's client: the
   largest difference of any observation entry and the two returns (equal: the simulations are the same);
3. the same with the randomizer: our env draws its parameters, EARL's env gets them through a randomizer stand-in;
4. EARL's 12 default goals and RISC's 4: the 1000-step return of zero actions from the reset, per goal (ours).

Usage::

    .venv/bin/python scripts/minitaur_earl_compare.py --git-dir /path/to/earl_benchmark.git
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
FILES = ("minitaur_gym_env.py", "minitaur.py", "motor.py", "minitaur_assets/wall_tile.urdf")


def earl_sources(args) -> Path:
    """A directory holding EARL's ``earl_benchmark/envs`` files (the checkout itself, or extracted from the mirror)."""
    if args.earl:
        return Path(args.earl)
    out = Path(tempfile.mkdtemp(prefix="earl_minitaur_"))
    for f in FILES:
        dest = out / "earl_benchmark" / "envs" / f
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_bytes(subprocess.run(["git", "-C", args.git_dir, "show", f"HEAD:earl_benchmark/envs/{f}"],
                                        check=True, capture_output=True).stdout)
    return out


def load_earl(root: Path, deterministic_pairs: bool):
    """EARL's ``minitaur_gym_env`` module, imported with the stand-ins; its bullet client optionally with
    ``deterministicOverlappingPairs=1``."""
    import gymnasium
    import pybullet
    import pybullet_data
    from packaging.version import parse

    gym = types.ModuleType("gym")
    gym.__version__ = "0.23.1"
    gym.Env = type("Env", (), {})
    gym.spaces = gymnasium.spaces
    seeding = types.ModuleType("gym.utils.seeding")
    seeding.np_random = lambda seed=None: (np.random.RandomState(seed), seed)
    gym.utils = types.SimpleNamespace(seeding=seeding)
    pkg = types.ModuleType("pkg_resources")
    pkg.parse_version = parse
    sys.modules.update({"gym": gym, "gym.spaces": gymnasium.spaces, "gym.utils": gym.utils,
                        "gym.utils.seeding": seeding, "pkg_resources": pkg})
    site = Path(pybullet_data.__file__).parent.parent
    packages = (("pybullet_envs", site / "pybullet_envs"), ("pybullet_envs.bullet", site / "pybullet_envs" / "bullet"),
                ("earl_benchmark", root / "earl_benchmark"), ("earl_benchmark.envs", root / "earl_benchmark" / "envs"))
    for name, where in packages:
        m = types.ModuleType(name)
        m.__path__ = [str(where)]
        sys.modules[name] = m
    for name in [n for n in sys.modules if n.startswith("earl_benchmark.envs.")]:
        del sys.modules[name]
    import earl_benchmark.envs.minitaur_gym_env as M

    base = M.bc.BulletClient

    class Client(base):
        def __init__(self, *a, **k):
            super().__init__(connection_mode=pybullet.DIRECT)

        def setPhysicsEngineParameter(self, **kw):
            if deterministic_pairs:
                kw["deterministicOverlappingPairs"] = 1
            return pybullet.setPhysicsEngineParameter(physicsClientId=self._client, **kw)

    M.bc = types.SimpleNamespace(BulletClient=Client)
    return M


def quiet_earl_env(M, **kw):
    devnull = os.open(os.devnull, os.O_WRONLY)
    saved = os.dup(1)
    sys.stdout.flush()
    os.dup2(devnull, 1)
    try:
        return M.GoalConditionedMinitaurBulletEnv(**kw)
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class Randomizer:
    """Stands in for pybullet's ``MinitaurEnvRandomizer`` in EARL's env: applies our env's draws through EARL's
    ``Minitaur`` setters (None: nothing, as ``env_randomizer=None``)."""

    def __init__(self, params):
        self.params = params

    def randomize_env(self, env):
        p, r = self.params, env.minitaur
        if p is None:
            return
        r.SetBaseMass(p["base_mass"])
        r.SetLegMasses(p["leg_masses"])
        r.SetBatteryVoltage(p["voltage"])
        r.SetMotorViscousDamping(p["damping"])
        r.SetFootFriction(p["foot_friction"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--earl", help="an earl_benchmark checkout (holding earl_benchmark/envs)")
    src.add_argument("--git-dir", help="a git mirror of earl_benchmark (read at HEAD)")
    args = ap.parse_args()
    root = earl_sources(args)
    from harness.envs.minitaur import MinitaurEnv
    from harness.envs.minitaur_task import EARL_DEFAULT_GOALS, GOALS

    np.set_printoptions(precision=17, linewidth=160)
    ours = MinitaurEnv(randomize=False)
    ours.reset(seed=0, options={"goal": GOALS[3]})
    for det in (False, True):
        M = load_earl(root, det)
        e = quiet_earl_env(M, goal_locations=GOALS.tolist(), env_randomizer=None)
        o = np.array(e.reset())
        print(f"1. EARL reset state, deterministicOverlappingPairs={int(det)}:\n{o[:30]!r}")
        print(f"   ours - EARL: max |diff| {np.abs(ours._obs64[:30] - o[:30]).max():.3g}")
    print(f"   ours:\n{ours._obs64[:30]!r}")

    M = load_earl(root, True)  # EARL's code with our contact-pair order: the same simulation, bit for bit
    actions = np.random.default_rng(1).uniform(-1, 1, (1000, 8))
    for randomize in (False, True):
        m = MinitaurEnv(randomize=randomize)
        m.reset(seed=7)
        params = m._params

        e = quiet_earl_env(M, goal_locations=[m._goal.tolist()], env_randomizer=Randomizer(params))
        o = np.array(e.reset())
        diffs, ret_e, ret_m = [np.abs(o - m._obs64).max()], 0.0, 0.0
        for a in actions:
            oe, re, _, _ = e.step(a)
            _, rm, _, _, _ = m.step(a)
            diffs.append(np.abs(np.array(oe) - m._obs64).max())
            ret_e, ret_m = ret_e + re, ret_m + rm
        print(f"{2 + randomize}. 1000 float64 random steps, randomize={randomize} {params or ''}: max |obs diff| "
              f"{max(diffs):.3g}, returns EARL {ret_e:.6f} ours {ret_m:.6f}")

    z = np.zeros(8, np.float32)
    for name, goals in (("RISC's 4", GOALS), ("EARL's 12", EARL_DEFAULT_GOALS)):
        rets = []
        for k, g in enumerate(goals):
            m.reset(seed=k, options={"goal": g})
            rets.append(sum(m.step(z)[1] for _ in range(1000)))
        print(f"4. zero actions, {name} goals (ours, randomized, seed = goal index): mean {np.mean(rets):.1f}, "
              f"per goal {np.round(rets, 1).tolist()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
