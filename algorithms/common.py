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

from algorithms.api import AlgoConfig
from algorithms.core.sac import SACConfig


@dataclass
class SACAlgoConfig(SACConfig, AlgoConfig):
    """SAC hyperparameters (ALGORITHMS.md 3.3) plus what every SAC-based algorithm needs."""

    seed_steps: int = 10_000  # steps without any update (num_seed_frames)
    buffer_capacity: int = 10_000_000  # upper bound; storage grows on demand

    def sac(self) -> SACConfig:
        return SACConfig(**{f.name: getattr(self, f.name) for f in fields(SACConfig)})


def member_rngs(seeds: list[int], stream: int) -> list[np.random.Generator]:
    """One numpy Generator per member for host-side choices (goals, switching)."""
    return [np.random.default_rng([s, stream]) for s in seeds]


def rng_states(rngs: list[np.random.Generator]) -> list[dict]:
    return [r.bit_generator.state for r in rngs]


def load_rng_states(rngs: list[np.random.Generator], states: list[dict]) -> None:
    for r, st in zip(rngs, states):
        r.bit_generator.state = st


def with_goal(obs: np.ndarray, goal: np.ndarray, state_dim: int) -> np.ndarray:
    """``obs`` (E, obs_dim) with its goal half replaced by ``goal`` (E, state_dim); a new array."""
    out = obs.copy()
    out[:, state_dim:] = goal
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
