"""Can a checkpoint's policy close sawyer_door from the deployed start pose, or only with the hand at the handle?

    python scripts/start_pose_probe.py RUN_DIR [episodes=10] [step=N]

RUN_DIR is one cell's directory of a results tree (e.g. ~/runs/reproduction/sawyer_door/vaprl). For each checkpointed
seed the probe runs the protocol's deployed evaluation (``harness.protocol.evaluate``: the deterministic policy, success
at any step of the eval horizon) from two starts: the env's own reset (rho0: door open, hand raised away from it), and
each such reset's door angle with the hand and gripper where the forward demos hold the handle before the door moves
(hand within 0.08 of the handle point, which the finger geometry keeps 0.06 away at the closest; handle within 0.02 of
where it starts). A policy that succeeds only from the second start has learned to close the door from the handle
pose its training phases begin in, not from the pose deployment begins in (docs/reproduction.md, "`vaprl` on
sawyer_door"). ``step=N`` probes the checkpoints kept at step N (a run with ``keep_every``) instead of the latest.
Read-only: nothing in RUN_DIR changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import yaml

from algorithms.api import DemoSet
from harness.data import load_demos
from harness.envs import get_spec, make_eval_env
from harness.protocol import evaluate, load_checkpoint
from harness.registry import ALGORITHMS
from harness.results import CHECKPOINT_FILE, kept_checkpoint_path


def handle_pose(env_name: str) -> np.ndarray:
    """Mean hand xyz + gripper of the forward-demo states that hold the handle before the door has moved."""
    obs = load_demos(env_name, "forward").observations
    near = (np.linalg.norm(obs[:, 0:3] - obs[:, 4:7], axis=1) < 0.08) & (
        np.linalg.norm(obs[:, 4:7] - obs[0, 4:7], axis=1) < 0.02)
    if not near.any():
        raise SystemExit("error: no forward-demo state holds the handle before the door moves")
    return obs[near][:, 0:4].mean(axis=0)


class HandAtHandle(gym.Wrapper):
    """Each reset draws s0 ~ rho0 as the env does, then moves the hand and gripper to ``pose`` (door angle kept)."""

    def __init__(self, env: gym.Env, pose: np.ndarray):
        super().__init__(env)
        self.pose = pose

    def reset(self, *, seed=None, options=None):
        start, _ = self.env.reset(seed=seed, options=options)
        held = start.copy()
        held[0:4] = self.pose
        return self.env.reset(options={"state": held})


def main(argv: list[str]) -> int:
    run_dir = Path(argv[0]) if argv else None
    opts = dict(a.split("=", 1) for a in argv[1:] if "=" in a)
    try:
        episodes, at = int(opts.get("episodes", 10)), int(opts["step"]) if "step" in opts else None
    except ValueError:
        print("error: episodes and step must be whole numbers", file=sys.stderr)
        return 2
    name = CHECKPOINT_FILE if at is None else kept_checkpoint_path(Path(CHECKPOINT_FILE), at).name
    ckpts = sorted(run_dir.glob(f"checkpoints/seeds=*/{name}")) if run_dir else []
    if not ckpts:
        kept = sorted({p.name for p in run_dir.glob("checkpoints/seeds=*/checkpoint-*.pt")}) if run_dir else []
        print(f"error: give a cell directory with checkpoints/seeds=*/{name} (got {run_dir}"
              + (f"; it keeps {', '.join(kept)})" if kept else ")"), file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    for ckpt in ckpts:
        seeds = [int(x) for x in ckpt.parent.name.removeprefix("seeds=").split("-")]
        meta = yaml.safe_load((run_dir / f"seed={seeds[0]}" / "run.yaml").read_text())
        env_name, cls = meta["env"], ALGORITHMS[meta.get("algo_class", meta["algo"])]
        demos = DemoSet(load_demos(env_name, "forward"), load_demos(env_name, "reverse"))
        algo = cls(get_spec(env_name), demos, cls.Config.from_dict(meta["config"]), seeds, torch.device("cpu"))
        state = load_checkpoint(ckpt)
        algo.load_state_dict(state["algo"])
        pose, step = handle_pose(env_name), state["step"]
        starts = {"rho0": [make_eval_env(env_name) for _ in seeds],
                  "hand at handle": [HandAtHandle(make_eval_env(env_name), pose) for _ in seeds]}
        rates = {name: evaluate(algo, envs, seeds, step, episodes)[0] for name, envs in starts.items()}
        for member, seed in enumerate(seeds):
            print(f"{env_name}/{meta['algo']} seed {seed} at step {step:,}, deployed success over {episodes} "
                  "episodes: " + ", ".join(f"from {name} {rate[member]:.2f}" for name, rate in rates.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
