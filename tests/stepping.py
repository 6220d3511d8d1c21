"""One training step of an algorithm's hooks, in the protocol's order (``harness.protocol.Interaction.step``), with the
next observation given by the test instead of an env: for unit tests of an algorithm's controller and buffers.
``tests/test_protocol.py::test_tests_step_algorithms_in_the_loops_order`` checks the order against the loop's."""

from __future__ import annotations

import numpy as np

from algorithms.api import AFTER_ACT, AFTER_STORE, Algorithm


def take_step(algo: Algorithm, obs: np.ndarray, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
    """act on ``obs``, then ``next_obs`` arrives: update, store and observe where the loop calls them. Returns observe's
    (E,) bool, the members that want their env reset (the caller resets what it wants)."""
    algo.act(obs)
    if algo.update_at == AFTER_ACT:
        algo.update()
    algo.store(next_obs, hard_reset)
    if algo.update_at == AFTER_STORE:
        algo.update()
    return algo.observe(next_obs, hard_reset)
