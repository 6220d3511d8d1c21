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
    envs = envs or [e for e, info in ENVS.items() if not info.unavailable()]  # all that can be built here
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


def matmul_rates(members: int = 2, batch: int = 256, hidden: int = 256, act_dim: int = 3, repeats: int = 5,
                 n: int = 200) -> list[dict]:
    """Median microseconds of the member-batched products of one SAC update, plain ``torch.bmm``/``baddbmm`` against
    :func:`algorithms.core.nets.member_matmul`, interleaved: (E, B, hidden) @ (E, hidden, out) for a critic head
    (out 1, two heads per member), the actor's output (out 2A) and a hidden layer (out = hidden), each with its weight
    gradient x^T d and input gradient d W^T."""
    import torch

    from algorithms.core.nets import member_matmul

    def t(x):
        return x.transpose(1, 2)

    cases = []
    for label, E, out in (("critic head", 2 * members, 1), ("actor output", members, 2 * act_dim),
                          ("hidden layer", members, hidden)):
        x, w = torch.randn(E, batch, hidden), torch.randn(E, hidden, out)
        b, d = torch.randn(E, 1, out), torch.randn(E, batch, out)
        cases += [(f"{label} forward", lambda x=x, w=w, b=b: torch.baddbmm(b, x, w),
                   lambda x=x, w=w, b=b: member_matmul(x, w, b)),
                  (f"{label} x^T d", lambda x=x, d=d: torch.bmm(t(x), d), lambda x=x, d=d: member_matmul(t(x), d)),
                  (f"{label} d W^T", lambda d=d, w=w: torch.bmm(d, t(w)), lambda d=d, w=w: member_matmul(d, t(w)))]
    rows = []
    for name, plain, ours in cases:
        torch.testing.assert_close(ours(), plain(), rtol=1e-4, atol=1e-3)
        times: dict[str, list[float]] = {"bmm": [], "member_matmul": []}
        for _ in range(repeats):  # interleaved, so drift of the machine hits both alike
            for key, f in (("bmm", plain), ("member_matmul", ours)):
                start = time.perf_counter()
                for _ in range(n):
                    f()
                times[key].append((time.perf_counter() - start) / n * 1e6)
        med = {k: statistics.median(v) for k, v in times.items()}
        rows.append({"product": name, **{f"{k}_us": v for k, v in med.items()},
                     "speedup": med["bmm"] / med["member_matmul"]})
    return rows


def bench_matmul(members: int = 2, repeats: int = 5, log=print) -> list[dict]:
    import torch

    rows = matmul_rates(members, repeats=repeats)
    log(f"bench matmul: members={members} batch=256 hidden=256 threads={torch.get_num_threads()} "
        f"(median of {repeats} interleaved rounds, microseconds per product)")
    log(f"  {'product':<28}{'bmm':>10}{'member_matmul':>16}{'speedup':>10}")
    for r in rows:
        log(f"  {r['product']:<28}{r['bmm_us']:>10.0f}{r['member_matmul_us']:>16.0f}{r['speedup']:>9.1f}x")
    return rows
