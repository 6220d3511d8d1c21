"""``harness bench``: throughput measurements (never timed tests).

``bench env`` times env steps/s per env, median over several runs: the bare EARL env, the env
inside the protocol's train wrapper, and (Sawyer) raw metaworld 3 with the same physics.
"""

from __future__ import annotations

import statistics
import time
from typing import Callable

import numpy as np

from harness.envs import ENVS, env_info, make_env, make_train_env


def _rate(step: Callable[[np.ndarray], object], actions: np.ndarray) -> float:
    t = time.perf_counter()
    for a in actions:
        step(a)
    return len(actions) / (time.perf_counter() - t)


def env_rates(name: str, steps: int, repeats: int = 5, seed: int = 0) -> dict[str, float]:
    """Median steps/s of the bare env, the train-wrapped env and raw metaworld (envs built on Meta-World)."""
    rng = np.random.default_rng(seed)
    spec = make_env(name).spec_
    actions = rng.uniform(-1, 1, (steps, spec.act_dim)).astype(np.float32)
    envs = {"env": make_env(name), "train_wrapped": make_train_env(name)}
    rates: dict[str, list[float]] = {k: [] for k in envs}
    for e in envs.values():
        e.reset(seed=seed)
        _rate(e.step, actions[: max(len(actions) // 10, 1)])  # warm-up
    for _ in range(repeats):  # interleaved, so drift of the machine hits both alike
        for label, e in envs.items():
            rates[label].append(_rate(e.step, actions))
    out = {k: statistics.median(v) for k, v in rates.items()}
    if env_info(name).metaworld_class:
        from harness.envs.bench_sawyer import raw_metaworld_step_rate

        out["raw_metaworld"] = statistics.median(raw_metaworld_step_rate(name, steps) for _ in range(repeats))
    return out


def bench_env(envs: list[str] | None = None, steps: int | None = None, repeats: int = 5, log=print) -> dict:
    envs = envs or list(ENVS)
    results = {}
    log(f"{'env':<24}{'env steps/s':>14}{'wrapped':>12}{'overhead':>10}{'raw metaworld':>16}{'wrapped/raw':>13}")
    for name in envs:
        n = steps or env_info(name).bench_steps
        r = env_rates(name, n, repeats)
        results[name] = r
        over = r["env"] / r["train_wrapped"] - 1.0
        raw = r.get("raw_metaworld")
        raw_s = f"{raw:>16,.0f}{r['train_wrapped'] / raw:>12.2f}x" if raw else f"{'-':>16}{'-':>13}"
        log(f"{name:<24}{r['env']:>14,.0f}{r['train_wrapped']:>12,.0f}{over:>+10.1%}{raw_s}")
    return results
