"""Tabletop: EARL-exact kinematics, demo replay, seeding, wrappers, experts."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from harness.data import load_demos
from harness.envs import make_env, make_eval_env, make_train_env, register_gym
from harness.envs.experts import get_expert, rollout
from harness.envs.tabletop import GOAL_STATES, TABLETOP_SPEC

from .conftest import requires_data


@requires_data
@pytest.mark.parametrize("direction", ["forward", "reverse"])
def test_demo_replay_is_exact(direction):
    """All 12+12 EARL demos replay open loop to < 1e-5 and succeed exactly at their last step."""
    env = make_env("tabletop_manipulation")
    trajs = load_demos("tabletop_manipulation", direction).trajectories()
    assert len(trajs) == 12
    for tr in trajs:
        obs, _ = env.reset(options={"state": tr["observations"][0]})
        np.testing.assert_array_equal(obs, tr["observations"][0])
        succ = []
        for a, nxt in zip(tr["actions"], tr["next_observations"]):
            obs, r, term, trunc, info = env.step(a)
            assert np.abs(obs - nxt).max() < 1e-5
            assert not term and not trunc
            assert r == float(info["success"])
            succ.append(info["success"])
        assert succ.index(True) == len(succ) - 1


def test_reset_and_goals():
    env = make_env("tabletop_manipulation")
    seen = set()
    for s in range(40):
        obs, _ = env.reset(seed=s)
        np.testing.assert_array_equal(obs[:6], [0, 0, 2.5, 0, -1, -1])
        assert any(np.array_equal(obs[6:], g) for g in GOAL_STATES)
        seen.add(tuple(obs[6:]))
    assert len(seen) == 4  # all four task goals are drawn
    g = GOAL_STATES[2]
    obs, _ = env.reset(options={"goal": g})
    np.testing.assert_array_equal(obs[6:], g)


def test_grasp_semantics():
    env = make_env("tabletop_manipulation")
    # mug 0.39 away: grasped; the mug then moves with the gripper
    env.reset(options={"state": np.array([2.11, 0, 2.5, 0, -1, -1, *GOAL_STATES[0]], np.float32)})
    obs, *_ = env.step(np.array([1.0, 0.0, 1.0], np.float32))
    assert obs[4] == 0 and obs[5] == 0
    np.testing.assert_allclose(obs[:4], [2.31, 0, 2.7, 0], atol=1e-6)
    obs, *_ = env.step(np.array([1.0, 0.0, 0.5], np.float32))  # mug clipped at 2.8
    np.testing.assert_allclose(obs[:4], [2.51, 0, 2.8, 0], atol=1e-6)
    obs, *_ = env.step(np.array([-1.0, 0.0, -1.0], np.float32))  # release: mug stays
    np.testing.assert_allclose(obs[:6], [2.31, 0, 2.8, 0, -1, -1], atol=1e-6)
    # mug 0.41 away: not grasped; actions outside [-1, 1] are clipped
    env.reset(options={"state": np.array([2.09, 0, 2.5, 0, -1, -1, *GOAL_STATES[0]], np.float32)})
    obs, *_ = env.step(np.array([5.0, 0.0, 1.0], np.float32))
    np.testing.assert_allclose(obs[:6], [2.29, 0, 2.5, 0, -1, -1], atol=1e-6)


def test_success_predicate_and_reward():
    spec = TABLETOP_SPEC
    o = np.zeros(12, np.float32)
    o[6:12] = [0, 0, 0.19, 0, -1, -1]
    assert spec.is_success(o) and spec.compute_reward(o) == 1.0
    o[8] = 0.21
    assert not spec.is_success(o) and spec.compute_reward(o) == 0.0
    o[4:6] = 5.0  # the attached flag is not part of the predicate
    o[8] = 0.1
    assert spec.is_success(o)
    batch = np.stack([o, o])
    batch[1, 0] = 1.0
    np.testing.assert_array_equal(spec.is_success(batch), [True, False])


def test_same_seed_same_trajectory_and_check_env():
    actions = np.random.default_rng(1).uniform(-1, 1, (300, 3)).astype(np.float32)

    def traj(env):
        obs = [env.reset(seed=7)[0]]
        obs += [env.step(a)[0] for a in actions]
        return np.stack(obs)

    a, b = traj(make_env("tabletop_manipulation")), traj(make_env("tabletop_manipulation"))
    assert a.tobytes() == b.tobytes()
    check_env(make_env("tabletop_manipulation"), skip_render_check=True)


def test_gym_ids_register_on_import_in_both_forms():
    """As gymnasium packages do: ``import harness.envs`` registers the ids, and ``module:id`` imports the module;
    checked in fresh interpreters (this one has registered long ago); ``register_gym()`` stays an idempotent alias."""
    import subprocess
    import sys

    for code in ("import gymnasium as gym, harness.envs; e = gym.make('earl/SawyerDoor-v0')",
                 "import gymnasium as gym; e = gym.make('harness.envs:earl/TabletopManipulation-v0')"):
        out = subprocess.run([sys.executable, "-c", code + "; print(e.spec.max_episode_steps, e.reset(seed=0)[0].shape)"],
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split()[0] in ("300", "200")
    register_gym()
    register_gym()


def test_gym_registration_and_horizons():
    env = gym.make("earl/TabletopManipulation-v0")
    assert env.spec.max_episode_steps == 200
    env.reset(seed=0)
    for t in range(200):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        assert not term
    assert trunc  # H_E is a truncation, never a termination
    ev = make_eval_env("tabletop_manipulation")
    assert ev._max_episode_steps == 200


def test_persistent_state_wrapper_counts():
    env = make_train_env("tabletop_manipulation", horizon=5)
    env.reset(seed=0)
    assert env.interventions == 0
    for t in range(1, 6):
        _, _, term, trunc, info = env.step(np.zeros(3, np.float32))
        assert not term and trunc == (t == 5) and info["steps_since_reset"] == t
    env.reset()
    assert env.interventions == 1 and env.total_steps == 5 and env.steps_since_reset == 0
    assert make_train_env("tabletop_manipulation").horizon == 200_000


def test_sim_state_round_trip():
    env = make_env("tabletop_manipulation")
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    for a in rng.uniform(-1, 1, (50, 3)).astype(np.float32):
        env.step(a)
    st = env.get_sim_state()
    tail = rng.uniform(-1, 1, (50, 3)).astype(np.float32)
    ref = [env.step(a)[0] for a in tail] + [env.reset()[0]]
    env2 = make_env("tabletop_manipulation")
    env2.reset(seed=99)
    env2.set_sim_state(st)
    got = [env2.step(a)[0] for a in tail] + [env2.reset()[0]]  # RNG state restored too
    assert np.array_equal(np.stack(ref), np.stack(got))


@pytest.mark.parametrize("direction", ["forward", "reverse"])
def test_scripted_expert_success_rate(direction):
    env = make_env("tabletop_manipulation")
    spec = env.spec_
    ok = 0
    for s in range(20):
        obs, _ = env.reset(seed=s)
        goal = None
        if direction == "reverse":
            done = rollout(env, get_expert(spec.name, "forward"), obs, spec.eval_horizon)
            assert done is not None
            obs, goal = done["next_observations"][-1], spec.initial_states[0]
        ok += rollout(env, get_expert(spec.name, direction), obs, spec.eval_horizon, goal=goal) is not None
    assert ok >= 18


def test_render_rgb_array():
    env = make_env("tabletop_manipulation", render_mode="rgb_array", width=64, height=64)
    env.reset(seed=0)
    try:
        img = env.render()
    except RuntimeError as e:
        pytest.skip(str(e))
    assert img.shape == (64, 64, 3) and img.std() > 0
