"""Where would VaPRL's curriculum put its subgoal? A read-only probe of a VaPRL run's checkpoint.

    python scripts/vaprl_curriculum_probe.py RUN_DIR [lambdas=0.5,1,2,5,20]

RUN_DIR is one cell's directory of a results tree (e.g. ~/runs/reproduction/tabletop_manipulation/vaprl): its
``seed=*/run.yaml`` give the resolved config and its ``checkpoints/seeds=*/checkpoint.pt`` the state. For every task
goal g* and seed the probe evaluates, with the run's own critic and candidates, V(c, g*) and V(s_now, c) for every
candidate c (s_now: the state the member was in at the checkpoint), then prints which candidate the Lagrangian rule
argmin_c ||c - mean(rho0)|| - lambda V(c) picks at the checkpoint's lambda and at larger ones, with and without
``use_minimum``: its distance to rho0 and to g* (the success norm). docs/reproduction.md uses it to show whether the
curriculum could lead at all: a useful subgoal lies near g* and still far from rho0.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
import yaml

from algorithms.api import DemoSet
from harness.data import load_demos
from harness.envs import get_spec
from harness.registry import ALGORITHMS


def groups(run_dir: Path):
    """Yield (algo, seeds, step) for every checkpointed group of seeds in the cell (one process each)."""
    for ckpt in sorted(run_dir.glob("checkpoints/seeds=*/checkpoint.pt")):
        seeds = [int(s) for s in ckpt.parent.name.removeprefix("seeds=").split("-")]
        meta = yaml.safe_load((run_dir / f"seed={seeds[0]}" / "run.yaml").read_text())
        cls = ALGORITHMS["vaprl"]  # every VaPRL variant is this class; the resolved config fixes every behaviour
        demos = DemoSet(load_demos(meta["env"], "forward"), load_demos(meta["env"], "reverse"))
        algo = cls(get_spec(meta["env"]), demos, cls.Config.from_dict(meta["config"]), seeds, torch.device("cpu"))
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        algo.load_state_dict(state["algo"])
        yield algo, seeds, state["step"]


def probe(algo, seeds: list[int], step: int, lambdas: list[float]) -> None:
    task, sd, E = algo.task, algo.task.state_dim, len(seeds)
    idx, mask = list(task.success_idx), np.ones(E, dtype=bool)
    print(f"step {step:,}; lambda per seed {np.round(algo.lagrange.value, 3).tolist()}; {len(algo.candidates)} "
          "demo-state candidates; each cell: lambda: L2 to rho0 / distance to g* of the pick")
    obs = np.empty((E, len(algo.candidates), task.obs_dim), dtype=np.float32)
    for gi, goal in enumerate(task.goal_states):
        obs[:, :, :sd], obs[:, :, sd:] = algo.candidates, goal
        v_goal = algo._values(obs, mask)  # V(c, g*)
        obs[:, :, :sd], obs[:, :, sd:] = algo.phase_obs[:, None, :sd], algo.candidates
        v_reach = algo._values(obs, mask)  # V(s_now, c)
        to_goal = np.linalg.norm(algo.candidates[:, idx] - goal[idx], axis=1)
        near = to_goal <= task.success_threshold
        for i, seed in enumerate(seeds):
            v = v_goal[i]
            at_rho0, at_goal = v[np.argmin(algo.l2_distance)], v[near].mean() if near.any() else np.nan
            print(f"g*{gi} seed {seed}: V(c,g*) {v.min():.1f}..{v.max():.1f}, at rho0 {at_rho0:.1f}, "
                  f"mean at the {near.sum()} candidates within success of g* {at_goal:.1f}")
            lams = [float(algo.lagrange.value[i]), *lambdas]
            for name, value in (("min(V(s,c), V(c,g*))", np.minimum(v, v_reach[i])), ("V(c,g*)", v)):
                picks = [int(np.argmin(algo.l2_distance - lam * value)) for lam in lams]
                print(f"    {name:22s} " + "  ".join(f"{lam:.3g}: {algo.l2_distance[k]:.1f}/{to_goal[k]:.1f}"
                                                    for lam, k in zip(lams, picks)))


def main(argv: list[str]) -> int:
    run_dir = Path(argv[0]) if argv else None
    if run_dir is None or not any(run_dir.glob("checkpoints/seeds=*/checkpoint.pt")):
        print(f"error: give a VaPRL cell directory with checkpoints/seeds=*/checkpoint.pt (got {run_dir}); usage: "
              + __doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    opts = dict(a.split("=", 1) for a in argv[1:] if "=" in a)
    try:
        lambdas = [float(x) for x in opts.get("lambdas", "0.5,1,2,5,20").split(",")]
    except ValueError:
        print(f"error: lambdas must be comma-separated numbers (got {opts['lambdas']!r})", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    for algo, seeds, step in groups(run_dir):
        probe(algo, seeds, step, lambdas)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
