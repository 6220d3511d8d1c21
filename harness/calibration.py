"""Measured training speed for ``harness run --dry-run``: what a plan will cost on this machine.

A calibration trains one group's algorithm (its own config, its members, the threads a worker gets) for a few hundred
steps past a short seed phase, as ``harness bench train`` does, and records steps/s per member, then times one
deployed-policy evaluation episode (seconds per evaluation step of all members: an evaluation of kitchen or minitaur,
400 or 1000 steps per episode, costs far more than one of the Sawyer tasks). Results are cached in
``<state>/calibration.json`` (``harness.data.state_dir``) per (machine, torch, device, threads, algorithm, env, members, config), so only the
first dry-run of a new kind of group pays for it (seconds per group). :func:`estimate` then packs the groups onto the
workers, longest first (the order a pool runs them in, give or take), and returns the time until the last finishes.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from harness.plan import RunSpec

WARMUP, MEASURE = 120, 120  # seed-phase steps (no updates), then timed steps with updates
#: groups of at most this many steps per seed are not measured: measuring one (WARMUP + MEASURE steps and an
#: evaluation episode, plus building the agent) takes about as long as running it
SHORT_STEPS = 2_000


def _cache_file() -> Path:
    from harness.data import state_dir

    return state_dir() / "calibration.json"


def machine() -> str:
    """CPU model (or GPU name) and torch version: speeds are only comparable on the same kind of machine."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu} | torch {torch.__version__}"


def key(group: RunSpec, threads: int) -> str:
    return "|".join([machine(), torch.device(group.device).type, f"threads={threads}", group.algo_class, group.env,
                     f"members={len(group.seeds)}", group.config_hash]
                    + ([f"env_workers={group.env_workers}"] if group.env_workers > 1 else [])
                    + ([f"update={group.update}"] if group.update != "default" else []))


def read_cache() -> dict[str, float]:
    """Steps/s per member by :func:`key` (entries written before the metadata existed are plain numbers)."""
    return {k: (v["steps_per_s"] if isinstance(v, dict) else v) for k, v in _read_entries().items()}


def eval_costs(groups: list[RunSpec], threads: int) -> list[float | None]:
    """Seconds per evaluation step (all members of the group at once) of each group, where measured."""
    entries = _read_entries()
    return [e.get("eval_s_per_step") if isinstance(e, dict) else None
            for e in (entries.get(key(g, threads)) for g in groups)]


def group_seconds(group: RunSpec, steps_left: int, rate: float, eval_s_per_step: float | None) -> float:
    """Seconds ``group`` needs for ``steps_left`` more steps per member at ``rate`` steps/s per member, with its
    evaluations (every ``eval_every`` steps, ``eval_episodes`` episodes of H_E steps) at their measured cost, or
    :data:`EVAL_SHARE` more where that was not measured. The measured rate is of updating steps: the first
    ``seed_steps`` of a run (random actions, no update) are left out of the training time."""
    from harness.envs import env_info

    random_left = max(min(steps_left, int(group.config.get("seed_steps", 0)) - (group.steps - steps_left)), 0)
    train = (steps_left - random_left) / rate
    if eval_s_per_step is None:
        return train * (1 + EVAL_SHARE)
    evals = -(-steps_left // group.eval_every)
    return train + evals * group.eval_episodes * env_info(group.env).spec.eval_horizon * eval_s_per_step


#: the share evaluations add to training time where their cost was not measured (a Sawyer task at EARL's schedule)
EVAL_SHARE = 0.03


def _read_entries() -> dict[str, dict | float]:
    try:
        d = json.loads(_cache_file().read_text())
        return d if isinstance(d, dict) else {}
    except (OSError, ValueError):
        return {}


def _load() -> float | None:
    """The 1-minute load average per core (None where the OS has none): how busy the machine was when measured."""
    try:
        return os.getloadavg()[0] / (os.cpu_count() or 1)
    except (OSError, AttributeError):
        return None


def when_measured(groups: list[RunSpec], threads: int) -> str:
    """When the speeds of ``groups`` were measured and how busy the machine was then, for the plan's last line:
    'on 2026-12-07 (load 1.0 per core)', or the span of dates; '' when no entry records it."""
    entries = _read_entries()
    meta = [e for e in (entries.get(key(g, threads)) for g in groups) if isinstance(e, dict) and "measured" in e]
    if not meta:
        return ""
    dates = sorted({e["measured"][:10] for e in meta})
    loads = [e["load"] for e in meta if e.get("load") is not None]
    when = dates[0] if len(dates) == 1 else f"{dates[0]} to {dates[-1]}"
    return f" on {when}" + (f" (load {max(loads):.1f} per core at most)" if loads else "")


def measure(group: RunSpec, threads: int) -> tuple[float, float]:
    """Steps/s per member of ``group`` on this machine with ``threads`` torch threads (no evaluation, no I/O), and the
    seconds per step of one evaluation episode (all members at once)."""
    from algorithms.api import DemoSet
    from algorithms.core.sac import set_update_mode
    from harness.env_pool import make_envs
    from harness.envs import get_spec, load_env_demos
    from harness.protocol import Interaction, evaluate
    from harness.registry import ALGORITHMS

    cls = ALGORITHMS[group.algo_class]
    cfg = cls.Config.from_dict({**group.config, **({"seed_steps": WARMUP} if "seed_steps" in cls.Config.keys() else {})})
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        demos = DemoSet(load_env_demos(group.env, "forward"), load_env_demos(group.env, "reverse"))
        algo = cls(get_spec(group.env), demos, cfg, list(group.seeds), torch.device(group.device))
        set_update_mode(algo, group.update)  # compiled at the first update, untimed
        inter = Interaction(group.env, list(group.seeds), group.env_workers)
        try:
            inter.start(algo)
            for _ in range(WARMUP + 10):
                inter.step(algo)
            t = time.perf_counter()
            for _ in range(MEASURE):
                inter.step(algo)
            rate = MEASURE / (time.perf_counter() - t)
        finally:
            inter.close()
        envs = make_envs(group.env, len(group.seeds), group.env_workers, "eval")
        try:
            t = time.perf_counter()
            evaluate(algo, envs, list(group.seeds), 0, 1)
            return rate, (time.perf_counter() - t) / envs.spec_.eval_horizon
        finally:
            envs.close()
    finally:
        torch.set_num_threads(old)


def rates(groups: list[RunSpec], threads: int, calibrate: bool | str, log=print) -> list[float | None]:
    """Steps/s per member of each group: cached, or measured now when ``calibrate`` (and cached with the date and the
    machine's load), else None. ``calibrate="refresh"`` measures every group again."""
    from datetime import datetime, timezone

    from harness.data import atomic_write_bytes

    entries, out, dirty, done = _read_entries(), [], False, set()
    for g in groups:
        k = key(g, threads)
        if calibrate and (k not in entries or calibrate == "refresh" and k not in done):
            load = _load()
            log(f"  calibrating {g.env}/{g.algo} (members={len(g.seeds)}, {threads} thread(s)"
                + (f", load {load:.1f} per core" if load is not None else "") + ") ...")
            rate, eval_s = measure(g, threads)
            entries[k] = {"steps_per_s": rate, "eval_s_per_step": eval_s, "measured": datetime.now(
                timezone.utc).isoformat(timespec="seconds"), "load": load}
            dirty = True
            done.add(k)
        e = entries.get(k)
        out.append(e["steps_per_s"] if isinstance(e, dict) else e)
    if dirty:
        try:
            atomic_write_bytes(_cache_file(), json.dumps(entries, indent=1, sort_keys=True).encode())
        except OSError:
            pass  # a read-only cache: measured again next time
    return out


def estimate(work: list[tuple[int, float]], workers: int) -> float:
    """Seconds until the last of ``work`` = [(steps left per member, steps/s per member)] finishes on ``workers``
    processes, longest first onto the least loaded worker."""
    load = [0.0] * max(workers, 1)
    for seconds in sorted((steps / rate for steps, rate in work if steps > 0), reverse=True):
        i = load.index(min(load))
        load[i] += seconds
    return max(load)


def worker_threads(workers: int, device: str = "cpu") -> int:
    """The torch threads each training process gets (:func:`harness.backends.process_threads`): one on a CPU."""
    return 1 if device.startswith("cpu") else max(1, (os.cpu_count() or 1) // workers)
