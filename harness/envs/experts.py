"""Scripted experts for the three EARL tasks, and scripted demonstration generation.

An expert is a deterministic function ``obs -> action`` that drives the state towards the goal
written in the observation's goal half. ``forward`` experts start from rho0 with a task goal;
``reverse`` (backward) experts start from a forward-success state with an initial state as goal.

``generate_demos`` rolls experts out into EARL's demo format (one trajectory per rollout, ending
at its first success), which ``harness data scripted`` writes with ``source=scripted`` for users
without EARL's demonstrations.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from algorithms.api import DEMO_FIELDS
from harness.envs.base import EarlEnv

Expert = Callable[[np.ndarray], np.ndarray]

_STEP = 0.2  # tabletop: largest displacement per action unit


def _toward(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Tabletop action (dx, dy) in [-1, 1] moving ``src`` to ``dst`` (exactly, once within reach)."""
    return np.clip((dst - src) / _STEP, -1.0, 1.0)


def tabletop_expert(obs: np.ndarray) -> np.ndarray:
    """Fetch the mug, carry it to the goal's mug position, release, return the gripper to the goal.

    Works for both directions, since the goal half says where mug and gripper must end."""
    fist, mug, held = obs[0:2], obs[2:4], obs[4] > -0.5
    goal_fist, goal_mug = obs[6:8], obs[8:10]
    mug_placed = np.linalg.norm(mug - goal_mug) < 1e-3
    if not mug_placed:
        if held:
            return np.array([*_toward(mug, goal_mug), 1.0], dtype=np.float32)
        if np.linalg.norm(fist - mug) < 0.3:  # within grasp radius: grasp, then move together
            return np.array([*_toward(mug, goal_mug), 1.0], dtype=np.float32)
        return np.array([*_toward(fist, mug), -1.0], dtype=np.float32)
    return np.array([*_toward(fist, goal_fist), -1.0], dtype=np.float32)


def get_expert(env: str, direction: str) -> Expert:
    """The scripted expert of ``env`` for ``direction`` (``forward`` or ``reverse``): its ``EnvInfo.experts``."""
    from harness.envs import ENVS

    if env not in ENVS:
        raise KeyError(f"no scripted expert for env={env!r} direction={direction!r}")
    return ENVS[env].expert(direction)


def rollout(
    env: EarlEnv, expert: Expert, obs: np.ndarray, max_steps: int, goal: np.ndarray | None = None
) -> dict[str, np.ndarray] | None:
    """Run ``expert`` from the env's current state ``obs`` until its first success (or give up).

    With ``goal``, the observations' goal half is replaced by ``goal`` (what the expert sees, what
    is recorded, and what success is judged against); the simulator is untouched. Returns the
    trajectory in EARL's demo layout, or None if it never succeeded."""
    spec = env.spec_
    traj: dict[str, list] = {k: [] for k in DEMO_FIELDS}
    if goal is not None:
        obs = spec.with_goal(obs, goal)
    for _ in range(max_steps):
        action = np.asarray(expert(obs), dtype=np.float32)
        nxt = env.step(action)[0]
        if goal is not None:
            nxt = spec.with_goal(nxt, goal)
        done = bool(spec.is_success(nxt))
        for k, v in zip(DEMO_FIELDS, (obs, action, float(done), done, nxt)):
            traj[k].append(v)
        obs = nxt
        if done:
            return {k: np.asarray(v) for k, v in traj.items()}
    return None


def generate_demos(env_name: str, direction: str, n: int, seed: int) -> dict[str, np.ndarray]:
    """``n`` successful scripted trajectories concatenated in EARL's demo layout.

    Forward: from a seeded reset (task goal). Reverse: run the forward expert to success first,
    then the reverse expert with an initial state (the one the episode started from) as goal."""
    from harness.envs import make_env

    env = make_env(env_name)
    spec = env.spec_
    fwd = get_expert(env_name, "forward")
    rev = get_expert(env_name, "reverse")
    out: list[dict[str, np.ndarray]] = []
    attempt = 0
    while len(out) < n:
        if attempt > 5 * n:
            raise RuntimeError(f"scripted {direction} expert for {env_name} keeps failing ({len(out)}/{n})")
        obs, _ = env.reset(seed=seed + attempt)
        attempt += 1
        start_state = obs[: spec.state_dim].copy()
        if direction == "forward":
            traj = rollout(env, fwd, obs, 4 * spec.eval_horizon)
        else:
            done = rollout(env, fwd, obs, 4 * spec.eval_horizon)
            if done is None:
                continue
            goal = spec.initial_states[0] if len(spec.initial_states) == 1 else start_state
            traj = rollout(env, rev, done["next_observations"][-1], 4 * spec.eval_horizon, goal=goal)
        if traj is not None:
            out.append(traj)
    return {k: np.concatenate([t[k] for t in out]) for k in out[0]}
