"""``harness bench train algo=medal env=sawyer_door members=E [steps=N] [device=cpu] [env_workers=N] [seed_steps=N]
[update=default|static|compiled] [denormals=keep|flush] [checkpoint=PATH]``.

Training throughput after the seed phase: the protocol's own step (act, update, env step, store, observe) with
updates on, timed over ``steps`` steps, three times (median). Prints steps/s per member and in
aggregate (E x per member), and where the time goes (env, act, update, discriminator, buffer,
other; with ``env_workers`` the env share is the wait for the workers). Evaluation is not included (it is a fixed ~3% of steps for EARL's schedule).

``checkpoint=`` times training from a run's saved state instead of a fresh one (a long run's networks, optimizer
state and replay buffer: what makes it slower or faster than a fresh run), with the run's algo, env, seeds and config
read from its ``run.yaml``, and prints the digest of the state after the timed steps: two commands that differ only in
``denormals=`` (or another setting that should not change results) and print the same digest trained alike.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import torch

from algorithms.api import DemoSet
from algorithms.core.sac import set_update_mode
from algorithms.update_modes import UPDATES
from harness.backends import use_allocator
from harness.catalogue import algorithm_name
from harness.command_keys import BENCH
from harness.envs import check_env, env_name, get_spec, load_env_demos
from harness.protocol import Interaction
from harness.registry import ALGORITHMS
from harness.runnable import check_runs_on
from harness.suites import resolve_algo_config
from harness.words import UsageError, did_you_mean, optional_integer


def bench_train(algo: str, env: str, members: int, steps: int, device: str, repeats: int = 3, seed_steps: int = 1000,
                log=print, env_workers: int = 0, update: str = "default") -> dict:
    cls = ALGORITHMS[algo]
    cfg = resolve_algo_config(cls.Config, algo, env, {"all": {"seed_steps": seed_steps}})
    check_runs_on(algo, cls, cfg, env)  # one line when algo cannot run on env (goals, demos, reward)
    demos = DemoSet(load_env_demos(env, "forward"), load_env_demos(env, "reverse"))
    seeds = list(range(members))
    agent = cls(get_spec(env), demos, cfg, seeds, torch.device(device))
    set_update_mode(agent, update)
    inter = Interaction(env, seeds, env_workers)
    try:
        return _measure(inter, agent, algo, env, members, steps, device, repeats, seed_steps, log, env_workers, update)
    finally:
        inter.close()


def bench_train_from(checkpoint: Path, steps: int, device: str, repeats: int = 3, log=print, env_workers: int = 0,
                     update: str | None = None) -> dict:
    """:func:`bench_train` from a run's checkpoint (see the module docstring); adds ``digest``, the state's after the
    timed steps."""
    from harness.planning import read_run_record
    from harness.protocol import CheckpointError, load_checkpoint
    from harness.provenance import state_digest
    from harness.results import RUN_FILE

    if not checkpoint.is_file():
        raise UsageError(f"checkpoint {checkpoint} not found (a run's <results>/<suite>/<env>/<algo>/checkpoints/"
                         "seeds=.../checkpoint.pt)")
    records = sorted(checkpoint.parent.parent.parent.glob(f"seed=*/{RUN_FILE}"))
    group = checkpoint.parent.name.removeprefix("seeds=")
    rec = next((r for r in map(read_run_record, records) if "-".join(map(str, r.get("group_seeds", []))) == group), None)
    if rec is None:
        raise UsageError(f"no {RUN_FILE} of the group {checkpoint.parent.name} beside {checkpoint} (the run's seed=K "
                         "directories): the bench reads the run's algo, env, seeds and config there")
    try:
        ck = load_checkpoint(checkpoint, device)
    except CheckpointError as e:
        raise UsageError(str(e)) from None
    cls = ALGORITHMS[rec.get("algo_class", rec["algo"])]
    seeds = list(rec["group_seeds"])
    agent = cls(get_spec(rec["env"]), DemoSet(load_env_demos(rec["env"], "forward"), load_env_demos(rec["env"], "reverse")),
                cls.Config.from_dict(rec["config"]), seeds, torch.device(device))
    update = update or rec.get("update", "default")
    set_update_mode(agent, update)
    inter = Interaction(rec["env"], seeds, env_workers)
    try:
        agent.load_state_dict(ck["algo"])
        inter.load_state_dict(ck["interaction"])
        log(f"bench train: from {checkpoint} at step {ck['step']:,}")
        r = _measure(inter, agent, rec["algo"], rec["env"], len(seeds), steps, device, repeats, None, log, env_workers,
                     update)
    finally:
        inter.close()
    r["digest"] = state_digest({"algo": agent.state_dict(), "interaction": inter.state_dict()})
    log(f"  state digest after the timed steps: {r['digest']}")
    return r


def _measure(inter, agent, algo, env, members, steps, device, repeats, seed_steps, log, env_workers, update) -> dict:
    """``seed_steps`` None: the envs and agent are already past the seed phase (a checkpoint's state); only the warm-up
    (and compile) steps run untimed."""
    if seed_steps is not None:
        inter.start(agent)
    for _ in range((seed_steps or 0) + 100):  # past the seed phase, updates on
        inter.step(agent)
    timers = getattr(agent, "timers", None)
    rates, splits = [], []
    for _ in range(repeats):
        if timers is not None:
            timers.enabled = True
            timers.seconds.clear()
        inter.timed, inter.env_seconds = True, 0.0
        t = time.perf_counter()
        for _ in range(steps):
            inter.step(agent)
        dt = time.perf_counter() - t
        rates.append(steps / dt)
        split = {"env": inter.env_seconds, **(dict(timers.seconds) if timers else {})}
        split["other"] = max(dt - sum(split.values()), 0.0)
        splits.append({k: v / dt for k, v in split.items()})
    rate = statistics.median(rates)
    share = {k: statistics.median(s.get(k, 0.0) for s in splits) for k in splits[0]}
    log(f"bench train: algo={algo} env={env} members={members} device={device} env_workers={env_workers} update={update} "
        f"steps={steps} x {repeats}")
    log(f"  steps/s per member: {rate:,.1f}   aggregate: {rate * members:,.1f}   (runs: "
        + ", ".join(f"{r:,.1f}" for r in rates) + ")")
    log("  time split: " + "  ".join(f"{k} {v:.0%}" for k, v in sorted(share.items(), key=lambda kv: -kv[1])))
    return {"steps_per_s": rate, "aggregate": rate * members, "split": share, "runs": rates}


def flush_denormals(on: bool = True) -> bool:
    """Read and write subnormal floats (|x| < 1.2e-38 in float32) as zero on this thread and the threads it starts
    (the CPU's FTZ and DAZ bits, as TensorFlow's and XLA's CPU kernels do); False where the CPU cannot. Only the
    benches' ``denormals=flush`` call it: training keeps torch's default (IEEE gradual underflow).

    A long run's Adam moments decay through the subnormal range wherever a gradient stays zero (35% of the forward
    critic's first moments at 1.92M steps of MEDAL on sawyer_peg), but flushing them sped a training step from that
    state up by 1.04x only and changed the weights in their last bits (subnormal products inside the matrix products
    flush too), so runs would no longer resume or repeat bit for bit across the change (docs/performance.md)."""
    import torch

    return bool(torch.set_flush_denormal(on))


#: ``denormals=`` of the benches: keep (IEEE gradual underflow, as training runs), flush (FTZ/DAZ, for comparison)
DENORMALS = ("keep", "flush")


def use_denormals(name: str) -> None:
    if name not in DENORMALS:
        raise UsageError(f"unknown denormals {name!r}; known: {', '.join(DENORMALS)}")
    flush_denormals(name == "flush")


def training_words(what: str, ov: dict[str, str]) -> tuple[str, str, str]:
    """The (algo, env, update) of ``harness bench <what>``'s words, each checked (one line naming a bad one), and the
    allocator set as the words say."""
    allowed = set(BENCH[what])
    unknown = set(ov) - allowed
    if unknown:
        raise UsageError(f"unknown key {sorted(unknown)[0]!r}; known keys: {', '.join(sorted(allowed))}")
    algo, env = algorithm_name(ov.get("algo", "medal")), env_name(ov.get("env", "sawyer_door"))
    if algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {algo!r}{did_you_mean(algo, ALGORITHMS)}; known: {', '.join(ALGORITHMS)}")
    check_env(env)  # unknown, never released or its simulator not installed: one line
    update = ov.get("update", "default")
    if update not in UPDATES:
        raise UsageError(f"unknown update {update!r}; known: {', '.join(UPDATES)}")
    use_allocator(ov.get("allocator", "keep"))
    use_denormals(ov.get("denormals", "keep"))
    return algo, env, update


def bench_train_cli(ov: dict[str, str]) -> int:
    algo, env, update = training_words("train", ov)
    if "threads" in ov:
        torch.set_num_threads(optional_integer("threads", ov["threads"], 1, 1))
    if ov.get("checkpoint"):
        bench_train_from(Path(ov["checkpoint"]).expanduser(), optional_integer("steps", ov.get("steps"), 1000, 1),
                         ov.get("device", "cpu"), optional_integer("repeats", ov.get("repeats"), 3, 1),
                         env_workers=optional_integer("env_workers", ov.get("env_workers"), 0, 0),
                         update=ov.get("update"))
        return 0
    bench_train(algo, env, optional_integer("members", ov.get("members"), 1, 1), optional_integer("steps", ov.get("steps"), 1000, 1),
                ov.get("device", "cpu"), optional_integer("repeats", ov.get("repeats"), 3, 1),
                env_workers=optional_integer("env_workers", ov.get("env_workers"), 0, 0),
                seed_steps=optional_integer("seed_steps", ov.get("seed_steps"), 1000, 1), update=update)
    return 0
