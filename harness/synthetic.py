"""Synthetic results, written through the harness's own writer (``harness.results.RunResults`` and
``write_status``): :func:`write_run` for one run, :func:`write_big` for a large set (the dashboard's
load-time benchmark, ``harness bench app``). The tests' fixture with known values
(``tests/fixtures_results.py``) builds on these.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from harness.results import RunResults, run_dir, write_status


def metric_rows(ident: dict, meta: dict, steps: Iterable[int], fn: Callable[[int], dict]) -> list[dict]:
    """Long-format rows: ``fn(step) -> {metric: value}`` at each step."""
    rows = []
    for step in steps:
        for metric, value in fn(step).items():
            rows.append({**ident, "step": int(step), "metric": metric, "value": float(value), **meta})
    return rows


def write_run(root: Path, suite: str, env: str, algo: str, seed: int, steps, fn, status: dict,
              eval_every: int = 10_000) -> Path:
    """One run: ``fn(step) -> {metric: value}`` at each step, written once through RunResults."""
    d = run_dir(root, suite, env, algo, seed)
    r = RunResults(d, {"suite": suite, "env": env, "algo": algo, "seed": seed},
                   {"config_hash": "fixture", "git_sha": "0" * 7, "demo_source": "earl", "device": "cpu", "members": 3})
    r.rows = metric_rows(r.ident, r.meta, steps, fn)
    r.flush()
    (d / "run.yaml").write_text(f"suite: {suite}\nenv: {env}\nalgo: {algo}\nseed: {seed}\neval_every: {eval_every}\n")
    write_status(d, **status)
    return d


def write_big(root: str | Path, runs: int = 100, evals: int = 300) -> Path:
    """``runs`` runs x ``evals`` evaluations (all six metrics), suite ``big`` over 4 envs x 5 algorithms
    (seed = run // 20), every run done."""
    root = Path(root)
    envs = ("tabletop_manipulation", "sawyer_door", "sawyer_peg", "kitchen")
    algos = ("naive", "fbrl", "r3l", "vaprl", "medal")
    rng = np.random.default_rng(0)
    steps = [i * 10_000 for i in range(evals)]
    for k in range(runs):
        env, algo, seed = envs[k % 4], algos[(k // 4) % 5], k // 20
        noise = rng.random(evals)

        def fn(step, noise=noise):
            i = step // 10_000
            s = min(1.0, step / (evals * 10_000) + 0.1 * noise[i])
            return {"deployed_success": s, "deployed_return": s, "continuing_reward": step * s,
                    "interventions": 0, "steps_per_s": 100.0, "wall_s": step / 100}

        write_run(root, "big", env, algo, seed, steps, fn,
                  {"state": "done", "step": steps[-1], "total": steps[-1], "steps_per_s": 100.0, "eta_s": 0.0,
                   "last_success": 1.0})
    return root
