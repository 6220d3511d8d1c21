"""How ``harness run`` lays a suite onto a machine: seeds per process (``members``), processes (``workers``), env
worker processes per process (``env_workers``) and, on a GPU node, the GPU of each process.

Every member of a group is the run it would be alone (``algorithms.core.nets``) to float rounding (batched products
may round differently with E: 1e-8 to 5e-7 in the weights after 400 MEDAL steps, ``tests/test_split_group.py``), so
the packing changes speed, never results beyond rounding; the same packing repeats a run bit for bit. Values given
on the command line (``members=``, ``workers=``, ``env_workers=``) always win; a suite's or cell's own ``members``
wins over the automatic choice.

* CPU: one process per core. A group holds the suite's ``members`` (product suites: 1; cell suites: the cell's
  seeds, but one for a method that updates only each seed's acting controller, ``Algorithm.phase_split_updates``:
  members in different phases would run every controller's update, docs/performance.md); envs step in the group's
  process (on a CPU the update dominates a step; ``harness bench train`` measures it). A group with a checkpoint
  keeps its seeds (:func:`seed_groups`).
* GPU: the member dimension is what makes a GPU pay (one kernel launch serves E seeds), so a group holds all seeds of
  its (algorithm, env, config), up to :data:`GPU_MAX_MEMBERS`. Processes share the GPUs round-robin (``device=cuda``
  on a multi-GPU node uses every GPU; ``cuda:K`` pins one), as many per GPU as fit its memory and the node's cores
  (each process needs a core for its Python loop). Cores left over step the member envs in worker processes
  (:mod:`harness.env_pool`) when a group is large enough for it to pay.

The machine is the one ``harness run`` starts on. With ``backend=ray ray_address=...`` the cluster is elsewhere: Ray
places the groups by their resources (1/``per_device`` of a GPU each), and ``members=`` sizes them.
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

GPU_MAX_MEMBERS = 128  # seeds per process on a GPU; larger groups are split evenly
CUDA_PROCESS_BYTES = 1 << 30  # a CUDA context with torch's kernels and allocator slack, per process
ENV_WORKERS_MIN_MEMBERS = 4  # smaller groups step their envs in-process: a pipe round trip costs more than the step
GiB = 1 << 30


@dataclass(frozen=True)
class Machine:
    """What a node offers: usable cores, host memory, and its GPUs (count, memory of the smallest, name)."""

    cores: int
    memory: int  # host bytes
    gpus: int = 0
    gpu_memory: int = 0  # bytes, smallest GPU
    gpu_name: str = ""

    @classmethod
    def detect(cls) -> "Machine":
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cores = os.cpu_count() or 1
        memory = 0
        try:
            with open("/proc/meminfo") as f:
                memory = int(f.readline().split()[1]) * 1024
        except (OSError, ValueError, IndexError):
            pass
        import torch

        gpus = torch.cuda.device_count() if torch.cuda.is_available() else 0
        props = [torch.cuda.get_device_properties(i) for i in range(gpus)]
        return cls(cores, memory, gpus, min((p.total_memory for p in props), default=0),
                   props[0].name if props else "")

    def describe(self) -> str:
        gpus = f"{self.gpus} x {self.gpu_name or 'GPU'} ({self.gpu_memory / GiB:.0f} GiB), " if self.gpus else ""
        return f"{gpus}{self.cores} core(s), {self.memory / GiB:.0f} GiB RAM"


@dataclass(frozen=True)
class Work:
    """What packing needs to know of one (algorithm, env, config) of a suite."""

    seeds: int
    steps: int
    obs_dim: int
    act_dim: int
    members: int | None = None  # the suite's or cell's own value, if it gives one
    cpu_members: int = 1  # what a CPU run uses when nothing is given


@dataclass(frozen=True)
class Packing:
    members: tuple[int, ...]  # seeds per group, for each Work
    workers: int  # processes at once
    env_workers: int  # env worker processes per process (0: envs step in the process)
    devices: tuple[str, ...]  # groups take these devices round-robin
    per_device: int  # processes at once per device (GPU: what fits; CPU: workers)
    reasons: tuple[str, ...]  # how each value was chosen, for --dry-run

    def device_of(self, group_index: int) -> str:
        return self.devices[group_index % len(self.devices)]


def member_bytes(w: Work) -> int:
    """Device memory of one member's buffers at the end of its run, an upper bound: every step stored once in a
    transition buffer (obs, action, reward, 3 flags, an index) plus once as a state (MEDAL's negatives, VaPRL's
    relabelled copies), with the doubling growth of ``MemberStorage`` (up to 2x)."""
    transition = 4 * (w.obs_dim + w.act_dim + 1) + 3 + 8
    return int(2 * w.steps * (transition + 4 * w.obs_dim))


def split(seeds: int, most: int) -> int:
    """Members per group when ``seeds`` seeds are split into equal groups of at most ``most``."""
    return math.ceil(seeds / math.ceil(seeds / most))


def pack(work: Sequence[Work], device: str, machine: Machine, members: int | None = None,
         workers: int | None = None, env_workers: int | None = None) -> Packing:
    gpu = device.startswith("cuda")
    why = []
    if members is not None:
        per = [members] * len(work)
        why.append(f"members={members} (given)")
    elif gpu:
        per = [w.members or split(w.seeds, GPU_MAX_MEMBERS) for w in work]
        why.append(f"members: all seeds of a cell per process (at most {GPU_MAX_MEMBERS})")
    else:
        per = [w.members or w.cpu_members for w in work]
    per = [min(p, w.seeds) for p, w in zip(per, work)]
    groups = sum(math.ceil(w.seeds / p) for p, w in zip(per, work))
    cores = max(machine.cores, 1)

    if gpu and device == "cuda" and machine.gpus > 1:
        devices = tuple(f"cuda:{i}" for i in range(machine.gpus))
    else:
        devices = (device,)
    if gpu:
        # any `fit` groups at once fit one GPU: the largest `fit` together stay within its memory
        sizes = sorted((CUDA_PROCESS_BYTES + member_bytes(w) * p for w, p in zip(work, per)
                        for _ in range(math.ceil(w.seeds / p))), reverse=True)
        fit = sum(1 for total in itertools.accumulate(sizes) if total <= machine.gpu_memory) or 1
        per_device = max(1, min(fit, math.ceil(cores / len(devices))))
        auto_workers = min(groups, cores, per_device * len(devices))
        if machine.gpu_memory:
            why.append(f"{per_device} process(es) per GPU (its memory holds any {fit} groups at once, largest "
                       f"~{sizes[0] / GiB:.1f} GiB; {cores} cores)")
    else:
        auto_workers = min(groups, cores)
    if workers is not None:
        why.append(f"workers={workers} (given)")
    n_workers = max(1, min(workers if workers is not None else auto_workers, max(groups, 1)))
    if not gpu:
        per_device = n_workers

    if env_workers is not None:
        n_env = env_workers
        if env_workers:
            why.append(f"env_workers={env_workers} (given)")
    else:
        spare = (cores - n_workers) // n_workers
        biggest_group = max(per, default=1)
        n_env = min(biggest_group, spare) if gpu and spare >= 2 and biggest_group >= ENV_WORKERS_MIN_MEMBERS else 0
        if n_env:
            why.append(f"env_workers={n_env} per process ({cores} cores, {n_workers} processes)")
    return Packing(tuple(per), n_workers, n_env, devices, per_device, tuple(why))


def seed_groups(seeds: list[int], members: int, checkpoints: Path, done: set[int] = frozenset()) -> list[tuple[int, ...]]:
    """The groups (one process each) of a method's ``seeds``: a group with a checkpoint in ``checkpoints`` (its
    ``seeds=a-b`` directories) stays as it trained, whatever ``members`` says now, so its runs resume rather than
    start again; the other seeds go ``members`` to a group, in order. A selection that holds only some seeds of such
    a group, unfinished (not in ``done``), is refused: alone they would start again from step 0."""
    from harness.results import CHECKPOINT_FILE
    from harness.suites import ConfigError

    kept: list[tuple[int, ...]] = []
    taken: set[int] = set()
    for d in sorted(checkpoints.glob("seeds=*")) if checkpoints.is_dir() else []:
        try:
            g = tuple(int(x) for x in d.name.removeprefix("seeds=").split("-"))
        except ValueError:
            continue
        if not (d / CHECKPOINT_FILE).exists() or taken & set(g):
            continue
        if set(g) <= set(seeds):
            kept.append(g)
            taken |= set(g)
        elif cut := sorted(set(g) & set(seeds) - set(done)):
            raise ConfigError(f"seed(s) {', '.join(map(str, cut))} train in the group {d.name} (its checkpoint is in "
                              f"{checkpoints}): select all its seeds (seeds={','.join(map(str, g))}), or split the "
                              "group first (scripts/split_group.py)")
    rest = [s for s in seeds if s not in taken]
    return sorted(kept + [tuple(rest[i : i + members]) for i in range(0, len(rest), members)],
                  key=lambda g: seeds.index(g[0]))
