"""Pieces every SAC-based algorithm composes: its config base, goal bookkeeping, timers.

Kept deliberately small: the SAC math lives in ``algorithms.core.sac``, the buffers in
``algorithms.core.buffer``; this module only holds what the algorithm files would otherwise
repeat.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, fields

import numpy as np
import torch

from algorithms.api import AlgoConfig, setting
from algorithms.core.sac import SACConfig


@dataclass
class SACAlgoConfig(SACConfig, AlgoConfig):
    """SAC hyperparameters (docs/algorithms.md 3.3) plus what every SAC-based algorithm needs."""

    seed_steps: int = setting(10_000, "first env steps without any update (num_seed_frames)", ge=0, le=10**9)
    buffer_capacity: int = setting(10_000_000, "replay capacity per buffer (storage grows on demand)", ge=1, le=10**9)

    def validate(self) -> None:
        super().validate()
        if self.log_std_min >= self.log_std_max:
            raise ValueError(f"log_std_min={self.log_std_min} must be below log_std_max={self.log_std_max}")

    def sac(self) -> SACConfig:
        return SACConfig(**{f.name: getattr(self, f.name) for f in fields(SACConfig)})


def member_rngs(seeds: list[int], stream: int) -> list[np.random.Generator]:
    """One numpy Generator per member for host-side choices (goals, switching); ``stream``: an id from
    ``core.nets.Stream``."""
    return [np.random.default_rng([s, stream]) for s in seeds]


def rng_states(rngs: list[np.random.Generator]) -> list[dict]:
    return [r.bit_generator.state for r in rngs]


def load_rng_states(rngs: list[np.random.Generator], states: list[dict]) -> None:
    for r, st in zip(rngs, states):
        r.bit_generator.state = st


def with_goal(obs: np.ndarray, goal: np.ndarray, state_dim: int) -> np.ndarray:
    """``obs`` (E, obs_dim) with its goal half replaced by ``goal`` (E, goal_dim); a new array."""
    out = obs.copy()
    out[:, state_dim:] = goal
    return out


def to_host(*tensors: torch.Tensor | None) -> list[np.ndarray | None]:
    """Host copies of device tensors that share a leading member dim E (None passes through), fetched in ONE
    device->host transfer: on a GPU each transfer is a synchronisation, and a training step needs one (its actions)."""
    present = [t for t in tensors if t is not None]
    if not present:
        return [None] * len(tensors)
    if len(present) == 1:
        host = [present[0].cpu().numpy()]
    else:
        flat = torch.cat([t.reshape(t.shape[0], -1).to(torch.float32) for t in present], 1).cpu().numpy()
        ends = np.cumsum([t[0].numel() for t in present])
        host = [part.reshape(t.shape) for part, t in zip(np.split(flat, ends[:-1], axis=1), present)]
    it = iter(host)
    return [None if t is None else next(it) for t in tensors]


class TrainLog:
    """Per-member means of training diagnostics since the last :meth:`pop` (what each update returns: losses,
    temperature, Q, rewards; and host-side counts such as phase outcomes). Device values are summed on the device and
    counts kept on the host, so logging costs no host-device sync per step; :meth:`pop` syncs once per log period.
    Members outside an update's ``mask`` add nothing (a member that did not update reports NaN). One ``add`` stacks
    its K values into one (K, E) tensor: three small tensor ops per update, whatever K is."""

    def __init__(self, num_members: int, device):
        self.E, self.device = num_members, torch.device(device)
        self._groups: dict[str, tuple[list[str], torch.Tensor | np.ndarray, np.ndarray]] = {}

    def add(self, prefix: str, values: dict[str, torch.Tensor], mask=None) -> None:
        """Device values (E,) of one update, e.g. ``SAC.update``'s metrics, under ``prefix``."""
        m = np.ones(self.E, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        v = torch.stack([x.detach().to(torch.float32) for x in values.values()])
        if mask is not None:
            v = torch.where(torch.as_tensor(m, device=self.device), v, torch.zeros((), device=self.device))
        self._accumulate(prefix, list(values), v, m)

    def add_host(self, prefix: str, values: dict[str, np.ndarray], mask=None) -> None:
        """Host values (E,) under ``prefix`` (members outside ``mask`` add nothing)."""
        m = np.ones(self.E, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        v = np.where(m, np.stack([np.asarray(x, dtype=np.float64) for x in values.values()]), 0.0)
        self._accumulate(prefix + "\0host", list(values), v, m)

    def _accumulate(self, group: str, keys: list[str], v, m: np.ndarray) -> None:
        if group in self._groups and self._groups[group][0] == keys:
            _, total, count = self._groups[group]
            total += v  # in place: a device tensor or a host array
            count += m
        elif group in self._groups:  # another key set under the same prefix: keep both apart
            self._accumulate(group + "\0" + ",".join(keys), keys, v, m)
        else:
            self._groups[group] = (keys, v.clone() if isinstance(v, torch.Tensor) else v.copy(), m.astype(np.float64))

    def pop(self) -> dict[str, np.ndarray]:
        """The means (E,) since the last call (NaN where a member added nothing); starts a new period."""
        out = {}
        for group, (keys, total, count) in self._groups.items():
            prefix = group.split("\0")[0]
            total = total.cpu().numpy().astype(np.float64) if isinstance(total, torch.Tensor) else total
            means = np.where(count > 0, total / np.maximum(count, 1), np.nan)
            out.update({prefix + k: means[j] for j, k in enumerate(keys)})
        self._groups = {}
        return out


class Timers:
    """Accumulated wall time per named section, only when ``enabled`` (``harness bench train``).

    On CUDA each section synchronises so the split is real; disabled, it costs one branch."""

    def __init__(self, device: torch.device, enabled: bool = False):
        self.enabled = enabled
        self.cuda = torch.device(device).type == "cuda"
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, name: str):
        if not self.enabled:
            yield
            return
        if self.cuda:
            torch.cuda.synchronize()
        t = time.perf_counter()
        yield
        if self.cuda:
            torch.cuda.synchronize()
        self.seconds[name] += time.perf_counter() - t
