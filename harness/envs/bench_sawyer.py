"""Step-rate baselines: raw Meta-World 3 Sawyer envs, for comparison with ``harness.envs.sawyer``.

``raw_metaworld_step_rate("sawyer_door" | "sawyer_peg", n)`` times ``n`` steps of Meta-World 3's own
``SawyerDoorCloseEnvV3`` / ``SawyerPegInsertionSideEnvV3`` (Meta-World 3's model, its ``step`` with
its reward / ``evaluate_state``, observation clipping and ``_partially_observable`` left at its
default) under random actions from a seeded ``numpy.random.Generator``. Resets are excluded from the
timing. The global ``np.random`` is not used: the env's reset vector is drawn from its own seeded
``np_random`` (``seeded_rand_vec``). ``max_path_length`` is lifted so that the run is one episode.
``our_step_rate`` times our EARL envs the same way.
"""

from __future__ import annotations

import time

import numpy as np

from harness.envs import ENVS, make_env

#: env -> (module, class) of the raw Meta-World 3 env it builds on (each env's ``EnvInfo.metaworld_class``)
RAW_CLASSES = {name: tuple(e.metaworld_class.split(":")) for name, e in ENVS.items() if e.metaworld_class}


def _raw_env(name: str, seed: int):
    import importlib

    if name not in RAW_CLASSES:
        raise ValueError(f"unknown sawyer env {name!r}; known: {', '.join(RAW_CLASSES)}")
    mod, cls = RAW_CLASSES[name]
    env = getattr(importlib.import_module(mod), cls)()
    env._set_task_called = True  # no Task object needed for timing
    env._freeze_rand_vec = False
    env.seeded_rand_vec = True  # draw the reset vector from env.np_random, not the global RNG
    env.seed(seed)
    env.max_path_length = 1 << 62
    return env


def _time_steps(env, n_steps: int, seed: int) -> float:
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, size=(n_steps, 4)).astype(np.float32)
    step = env.step
    t0 = time.perf_counter()
    for a in actions:
        step(a)
    return n_steps / (time.perf_counter() - t0)


def raw_metaworld_step_rate(name: str, n_steps: int = 2000, seed: int = 0) -> float:
    """Steps per second of raw Meta-World 3 (``name``: ``sawyer_door`` or ``sawyer_peg``)."""
    env = _raw_env(name, seed)
    env.reset()
    try:
        return _time_steps(env, n_steps, seed)
    finally:
        env.close()


def our_step_rate(name: str, n_steps: int = 2000, seed: int = 0) -> float:
    """Steps per second of our EARL env (``harness.envs.sawyer``), same protocol."""
    env = make_env(name)
    env.reset(seed=seed)
    try:
        return _time_steps(env, n_steps, seed)
    finally:
        env.close()


if __name__ == "__main__":  # python -m harness.envs.bench_sawyer
    for nm in RAW_CLASSES:
        raw, ours = raw_metaworld_step_rate(nm, 3000), our_step_rate(nm, 3000)
        print(f"{nm}: raw metaworld {raw:.0f} steps/s, ours {ours:.0f} steps/s ({ours / raw:.2f}x)")
