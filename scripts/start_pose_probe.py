"""Can a checkpoint's policy close sawyer_door from the deployed start pose, or only with the hand at the handle?

    python scripts/start_pose_probe.py RUN_DIR [episodes=10]

RUN_DIR is one cell's directory of a results tree (e.g. ~/runs/reproduction/sawyer_door/vaprl). For each checkpointed
seed the probe rolls the deterministic forward policy (``eval_act``) for the eval horizon from two starts per episode:
the env's own reset (rho0: door open, hand raised away from it), and the same door angle with the hand and gripper
where the forward demos hold the handle before the door moves (hand within 0.08 of the handle point, which the finger
geometry keeps 0.06 away at the closest; handle within 0.02 of where it starts). A policy that succeeds only from the
second start has learned to close the door from the handle pose its training phases begin in, not from the pose
deployment begins in (docs/reproduction.md, "`vaprl` on sawyer_door"). Read-only: nothing in RUN_DIR changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
import yaml

from algorithms.api import DemoSet
from harness.data import load_demos
from harness.envs import get_spec, make_env
from harness.registry import ALGORITHMS


def handle_pose(env_name: str) -> np.ndarray:
    """Mean hand xyz + gripper of the forward-demo states that hold the handle before the door has moved."""
    obs = load_demos(env_name, "forward").observations
    near = (np.linalg.norm(obs[:, 0:3] - obs[:, 4:7], axis=1) < 0.08) & (
        np.linalg.norm(obs[:, 4:7] - obs[0, 4:7], axis=1) < 0.02)
    if not near.any():
        raise SystemExit("error: no forward-demo state holds the handle before the door moves")
    return obs[near][:, 0:4].mean(axis=0)


def rollout(env, algo, member: int, start: dict, horizon: int) -> tuple[bool, bool]:
    """One deterministic episode of ``member``'s policy from ``start``: (success at the end, success at any step)."""
    obs, _ = env.reset(options=start)
    any_success, E = False, len(algo.seeds)
    for _ in range(horizon):
        action = algo.eval_act(np.repeat(obs[None].astype(np.float32), E, axis=0))[member]
        obs, _, _, _, info = env.step(action)
        any_success |= info["success"]
    return bool(info["success"]), any_success


def main(argv: list[str]) -> int:
    run_dir = Path(argv[0]) if argv else None
    ckpts = sorted(run_dir.glob("checkpoints/seeds=*/checkpoint.pt")) if run_dir else []
    if not ckpts:
        print(f"error: give a cell directory with checkpoints/seeds=*/checkpoint.pt (got {run_dir})", file=sys.stderr)
        return 2
    try:
        episodes = int(dict(a.split("=", 1) for a in argv[1:] if "=" in a).get("episodes", 10))
    except ValueError:
        print("error: episodes must be a whole number", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    for ckpt in ckpts:
        seeds = [int(x) for x in ckpt.parent.name.removeprefix("seeds=").split("-")]
        meta = yaml.safe_load((run_dir / f"seed={seeds[0]}" / "run.yaml").read_text())
        env_name, cls = meta["env"], ALGORITHMS[meta["algo"]]
        demos = DemoSet(load_demos(env_name, "forward"), load_demos(env_name, "reverse"))
        algo = cls(get_spec(env_name), demos, cls.Config.from_dict(meta["config"]), seeds, torch.device("cpu"))
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        algo.load_state_dict(state["algo"])
        env, pose, horizon = make_env(env_name), handle_pose(env_name), get_spec(env_name).eval_horizon
        for member, seed in enumerate(seeds):
            counts = {"rho0": np.zeros(2), "hand at handle": np.zeros(2)}
            for ep in range(episodes):
                start, _ = env.reset(seed=ep)
                held = start.copy()
                held[0:4] = pose
                counts["rho0"] += rollout(env, algo, member, {"state": start}, horizon)
                counts["hand at handle"] += rollout(env, algo, member, {"state": held}, horizon)
            print(f"{env_name}/{meta['algo']} seed {seed} at step {state['step']:,}, {episodes} episodes of {horizon}:")
            for name, (final, anytime) in counts.items():
                print(f"  from {name:15s} success at the end {final / episodes:.2f}, "
                      f"at any step {anytime / episodes:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
