"""Oracle RL: episodic SAC with a reset to rho0 every episode (docs/algorithms.md section 5, [MC] oracle.py).

A reference upper bound, not an autonomous-RL method. The train env is reset at the end of every episode: the
algorithm asks the protocol loop for it through ``observe``'s return value (each such reset counts as an
intervention), so the train env behaves as an instance of the eval env: episodes of H_E steps (200 / 300 / 200), s0 ~
rho0, the env's own goal (tabletop re-draws it at each reset). An episode ends on success (terminal, early) or at H_E
(truncated, no bootstrap in [MC]). Buffer <- forward demos. Uniform random actions in [-1, 1] during the
``seed_steps`` (10,000) seed phase, no updates; then one update per step.

Implemented as :class:`algorithms.naive.Naive` with ``episodic = True`` (the env is reset instead of a pseudo-episode
cut), ``episode_steps = 0`` (= H_E of the env) and ``random_seed_actions = True``.
"""

from __future__ import annotations

from dataclasses import dataclass

from algorithms.naive import Naive, NaiveConfig


@dataclass
class OracleConfig(NaiveConfig):
    episode_steps: int = 0  # 0 = the env's eval horizon H_E
    random_seed_actions: bool = True


class Oracle(Naive):
    """Episodic SAC: a reset every H_E steps and on success."""

    label = "oracle RL (episodic)"
    Config = OracleConfig
    episodic = True
