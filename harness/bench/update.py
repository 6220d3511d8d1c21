"""``harness bench update algo=medal env=sawyer_door [members=1] [update=default] [threads=1] [repeats=5] [n=50]``.

One SAC update of the algorithm's own agent (its obs and action sizes, batch size and networks) against its **matmul
ceiling**: the same matrix products (every ``member_matmul`` of one update on the default path, with its shapes and
strides) replayed back to back on preallocated tensors, which is as fast as the update could be if everything but the products were free. Prints both
times, the ratio reached (ceiling / update time), and, for the eager modes, where the update's time goes: products (as
timed inside the update, against their back-to-back time), optimizer steps (Adam), the target's Polyak step, noise
sampling, and the rest (elementwise chains, layer norm, reductions, indexing, allocation).

Times are medians over ``repeats`` rounds of ``n`` updates, update and ceiling interleaved so that drift of the machine
hits both alike. The agent's other work (MEDAL's discriminator every 10 steps, replay sampling) is not included:
``harness bench train`` measures the whole step.
"""

from __future__ import annotations

import contextlib
import platform
import statistics
import time
from pathlib import Path

import torch

import algorithms.core.manual as manual_mod
import algorithms.core.nets as nets_mod
import algorithms.core.sac as sac_mod
from algorithms.api import DemoSet
from algorithms.core.nets import member_matmul
from algorithms.core.optim import MemberAdam
from algorithms.core.sac import SAC
from harness.bench.train import training_words
from harness.envs import get_spec, load_env_demos
from harness.registry import ALGORITHMS
from harness.suites import resolve_algo_config
from harness.words import UsageError, optional_integer


def cpu_name() -> str:
    """The CPU's model name and its widest vector extension (AVX-512 or AVX2), as /proc/cpuinfo says."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine()
    name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "?")
    flags = next((ln for ln in info.splitlines() if ln.startswith("flags")), "")
    simd = "AVX-512" if " avx512f" in flags else "AVX2" if " avx2" in flags else "no AVX2"
    return f"{name} ({simd})"


def _like(a):
    """A tensor of ``a``'s shape, strides and dtype with random values (non-tensors as they are)."""
    if not isinstance(a, torch.Tensor):
        return a
    span = 1 + sum((n - 1) * s for n, s in zip(a.shape, a.stride()))  # strides may be 0 (an expanded tensor)
    base = torch.empty(span, dtype=a.dtype, device=a.device)
    return (base.normal_() if base.is_floating_point() else base.zero_()).as_strided(a.shape, a.stride())


class _PhaseTimer:
    """Wall time of the update's parts, by wrapping the functions that do them (the CPU runs every kernel before the
    call returns, so a wrapper's time is the part's time): products (``member_matmul``), Adam, Polyak, noise."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.enabled = False

    def wrap(self, label, fn):
        def timed(*args, **kwargs):
            if not self.enabled:
                return fn(*args, **kwargs)
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[label] = self.seconds.get(label, 0.0) + time.perf_counter() - t
        return timed

    @contextlib.contextmanager
    def installed(self):
        patches = [(manual_mod, "member_matmul", "products"), (nets_mod, "member_matmul", "products"),
                   (MemberAdam, "step", "optimizer"), (MemberAdam, "step_masked", "optimizer"),
                   (sac_mod, "polyak_update", "target"), (sac_mod, "polyak_update_masked", "target"),
                   (sac_mod, "member_randn", "sampling")]
        saved = [(obj, name, getattr(obj, name)) for obj, name, _ in patches]
        try:
            for obj, name, label in patches:
                setattr(obj, name, self.wrap(label, getattr(obj, name)))
            yield self
        finally:
            for obj, name, fn in saved:
                setattr(obj, name, fn)


def _record_products(agent: SAC, batch: dict) -> list[tuple]:
    """The arguments of every product (``member_matmul``) of one update on the default path, as tensors of the same
    shapes and strides."""
    calls = []

    def record(*args):
        calls.append(tuple(_like(a) for a in args))
        return member_matmul(*args)

    saved = manual_mod.member_matmul, nets_mod.member_matmul
    manual_mod.member_matmul = nets_mod.member_matmul = record
    try:
        agent.update(batch)
    finally:
        manual_mod.member_matmul, nets_mod.member_matmul = saved
    return calls


def _random_batch(agent: SAC, batch_size: int, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    E, O, A = agent.num_members, agent.obs_dim, agent.act_dim
    return {"obs": torch.randn(E, batch_size, O, generator=g), "next_obs": torch.randn(E, batch_size, O, generator=g),
            "action": torch.rand(E, batch_size, A, generator=g) * 2 - 1, "reward": torch.rand(E, batch_size, generator=g),
            "terminal": torch.zeros(E, batch_size, dtype=torch.bool), "truncated": torch.zeros(E, batch_size, dtype=torch.bool)}


def _per_call(fn, n: int) -> float:
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n


def measure_update(agent: SAC, update: str = "default", repeats: int = 5, n: int = 50) -> dict:
    """Times of one update of ``agent`` (on the default path, switched to ``update`` here) and of its products back
    to back, and (eager manual paths: default, static) the split inside the update; see the module docstring."""
    batch = _random_batch(agent, agent.cfg.batch_size)
    calls = _record_products(agent, batch)
    agent.use_update(update)
    for _ in range(3):  # warm-up (and the compile of update=compiled)
        agent.update(batch)

    def ceiling():
        for args in calls:
            member_matmul(*args)

    update_s, ceiling_s = [], []
    for _ in range(repeats):  # interleaved
        update_s.append(_per_call(lambda: agent.update(batch), n))
        ceiling_s.append(_per_call(ceiling, n))
    t_update, t_ceiling = statistics.median(update_s), statistics.median(ceiling_s)
    split = {}
    if update in ("default", "static"):  # the others' products are not member_matmul calls at run time
        timer = _PhaseTimer()
        with timer.installed():
            timer.enabled = True
            t = time.perf_counter()
            for _ in range(n):
                agent.update(batch)
            total = time.perf_counter() - t
        split = {k: v / n for k, v in timer.seconds.items()}
        split["other"] = max(total / n - sum(split.values()), 0.0)
    flops = sum(2 * a.shape[0] * a.shape[1] * a.shape[2] * w.shape[2] for a, w, *_ in calls)  # (E, n, k) @ (E, k, m)
    return {"cpu": cpu_name(), "threads": torch.get_num_threads(), "update_ms": t_update * 1e3,
            "ceiling_ms": t_ceiling * 1e3, "products": len(calls), "gflop": flops / 1e9, "ratio": t_ceiling / t_update,
            "split_ms": {k: v * 1e3 for k, v in split.items()}}


def bench_update(algo: str, env: str, members: int = 1, update: str = "default", repeats: int = 5, n: int = 50,
                 log=print) -> dict:
    cls = ALGORITHMS[algo]
    cfg = resolve_algo_config(cls.Config, algo, env, {})
    demos = DemoSet(load_env_demos(env, "forward"), load_env_demos(env, "reverse"))
    algorithm = cls(get_spec(env), demos, cfg, list(range(members)), torch.device("cpu"))
    agents = [a for a in vars(algorithm).values() if isinstance(a, SAC)]
    if not agents:
        raise UsageError(f"{algo} has no SAC agent to bench")
    agent = agents[0]
    r = measure_update(agent, update, repeats, n)
    log(f"bench update: algo={algo} env={env} members={members} batch={agent.cfg.batch_size} obs={agent.obs_dim} "
        f"act={agent.act_dim} update={update} threads={r['threads']} cpu={r['cpu']} torch={torch.__version__}")
    log(f"  one update       {r['update_ms']:7.2f} ms  ({1e3 / r['update_ms']:6.1f} updates/s)")
    log(f"  matmul ceiling   {r['ceiling_ms']:7.2f} ms  ({1e3 / r['ceiling_ms']:6.1f} updates/s; "
        f"{r['products']} products back to back: {r['gflop']:.2f} GFLOP, {r['gflop'] / r['ceiling_ms'] * 1e3:.0f} GFLOP/s)")
    log(f"  ratio reached    {r['ratio']:7.2f}")
    split = r["split_ms"]
    if split:
        total = sum(split.values())
        log("  inside the update (timed wrappers, one pass of n updates):")
        for k in ("products", "optimizer", "target", "sampling", "other"):
            v = split.get(k, 0.0)
            extra = (f"  = {v / r['ceiling_ms']:.2f}x their back-to-back time" if k == "products" else
                     "  (elementwise, layer norm, reductions, indexing, allocation)" if k == "other" else "")
            log(f"    {k:<10}{v:7.2f} ms  {v / total:4.0%}{extra}")
    return r


RECORD_HEADER = ("| date | commit | CPU | torch | threads | algo · env | members | update | allocator | update ms | "
                 "ceiling ms | ratio |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n")


def record_row(path: Path, r: dict, algo: str, env: str, members: int, update: str, allocator: str) -> None:
    """Append the measurement as a row of the Markdown table in ``path`` (made with its header if new): the machine,
    commit and date go with every number."""
    from datetime import datetime, timezone

    from harness.data import atomic_write_bytes
    from harness.provenance import git_sha

    old = path.read_text() if path.exists() else ""
    if RECORD_HEADER not in old:
        old += ("\n" if old and not old.endswith("\n") else "") + RECORD_HEADER
    sha = git_sha(ignore=path)
    row = (f"| {datetime.now(timezone.utc):%Y-%m-%d} | {sha[:8]}{'-dirty' if sha.endswith('-dirty') else ''} | {r['cpu']} | {torch.__version__} | "
           f"{r['threads']} | {algo} · {env} | {members} | {update} | {allocator} | {r['update_ms']:.2f} | "
           f"{r['ceiling_ms']:.2f} | {r['ratio']:.2f} |\n")
    atomic_write_bytes(path, (old + row).encode())


def bench_update_cli(ov: dict[str, str]) -> int:
    algo, env, update = training_words("update", ov)
    torch.set_num_threads(optional_integer("threads", ov.get("threads"), 1, 1))
    members = optional_integer("members", ov.get("members"), 1, 1)
    r = bench_update(algo, env, members, update, optional_integer("repeats", ov.get("repeats"), 5, 1),
                     optional_integer("n", ov.get("n"), 50, 1))
    if ov.get("record"):
        record_row(Path(ov["record"]), r, algo, env, members, update, ov.get("allocator", "keep"))
    return 0
