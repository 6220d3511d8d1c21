"""EARL's minitaur (``minitaur``, ``earl/Minitaur-v0``; harness/envs/minitaur.py) checked before any training, and
dhand_lightbulb listed as unavailable.

Reference numbers marked "EARL's code" were produced by ``scripts/minitaur_earl_compare.py``: EARL's unmodified
``minitaur_gym_env.py`` / ``minitaur.py`` / ``motor.py`` run on the pybullet installed here (3.2.7). With
``deterministicOverlappingPairs=1`` on EARL's client (the setting our env needs for exact checkpoints) our env agrees
with it bit for bit: reset state, 1000 steps of float64 actions with and without the randomizer, returns. The tests
that simulate skip without pybullet (``pip install 'earl-harness[minitaur]'``, Python <= 3.11); the ones about its
absence run everywhere. Numbers worth reading are printed (``-s``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import pickle
import random

import gymnasium as gym
import numpy as np
import pytest

from harness.cli import main
from harness.data import DataNotFoundError, asset_path, find_data_dir
from harness.envs import ENVS, UNAVAILABLE_ENVS, EnvUnavailableError, check_env
from harness.envs.minitaur_task import (
    EARL_DEFAULT_GOALS,
    GOALS,
    INITIAL_STATE,
    KNEE_ANGLE,
    MINITAUR,
    MINITAUR_SPEC,
    MOTOR_DIRECTION,
    WALL_POSITIONS,
    minitaur_reward,
)


def _has_pybullet() -> bool:
    return importlib.util.find_spec("pybullet") is not None


def _has_walls() -> bool:
    try:
        asset_path("minitaur", "wall_tile.urdf")
        return True
    except DataNotFoundError:
        return False


needs_pybullet = pytest.mark.skipif(not _has_pybullet(), reason="pybullet is not installed (pip install "
                                    "'earl-harness[minitaur]', Python <= 3.11)")
needs_sim = [needs_pybullet, pytest.mark.skipif(not _has_walls(), reason="EARL's wall_tile.urdf (assets/minitaur of "
                                                "the EARL data directory) not found")]

#: EARL's code, pybullet's default contact-pair order, no randomizer: the reset state (our INITIAL_STATE is the same
#: with deterministicOverlappingPairs=1, bitwise ours)
EARL_DEFAULT_PAIRS_RESET = np.array([
    1.4921882851926274, 1.4789271033865863, 1.4862540104046591, 1.4746404563135431, 1.4959923210163835,
    1.5003442097217636, 1.4946713778208276, 1.4958402375856965, 1.0501221522621371, 1.0801084244608659,
    1.0663496355371118, 1.0943587809260047, 0.9956035411855173, 0.962486262838667, 1.001677592676776,
    0.9839904897223144, 0.47928237547356445, 0.58371208955893394, 0.52571009080600517, 0.61695410447033672,
    0.45444738007399771, 0.42391213180303089, 0.46479927253152581, 0.45789504049008939, -2.1500387145346055e-03,
    8.6321781225034673e-04, -2.7864899361966191e-04, 0.99999727726792986, -1.373787199185697e-04,
    -5.7409599989183659e-04])
#: EARL's code: the 12 wall tiles' base orientations (xyzw) in WALL_POSITIONS order, 3 per side (-x, +x, -y, +y)
EARL_WALL_QUATS = ([(0.0, 0.0, 0.0, 1.0)] * 3 + [(0.0, 0.0, 1.0, 6.123233995736766e-17)] * 3
                   + [(0.0, 0.0, 0.7071067811865475, 0.7071067811865476)] * 3
                   + [(0.0, 0.0, -0.7071067811865475, 0.7071067811865476)] * 3)
#: the published RISC minitaur curves (source risc_paper, metric deployed_return): the first evaluation (step 10k,
#: before RISC's 10k-step replay warm-up ends, so an untrained policy) of risc, per seed: -737.8 .. -560.2, mean -692
PUBLISHED_FIRST_EVAL = (-737.791, -560.163)


# -- the catalogue, and what happens without pybullet (no simulation) -------------------------------------------------
def test_spec_is_earls():
    s = MINITAUR_SPEC
    assert ENVS["minitaur"] is MINITAUR and s.gym_id == "earl/Minitaur-v0"
    assert (s.state_dim, s.goal_dim, s.obs_dim, s.act_dim) == (30, 2, 32, 8)
    assert (s.train_horizon, s.eval_horizon) == (100_000, 1000)  # EARL's deployment_eval_config['minitaur']
    assert s.success_idx == s.goal_idx == (28, 29) and s.success_threshold == 0.1
    assert np.array_equal(s.goal_states, [[0.4, 0], [0.2, 0], [-0.2, 0], [-0.4, 0]])  # RISC's fork of EARL
    assert len(EARL_DEFAULT_GOALS) == 12 and s.initial_states.shape == (1, 30)
    assert MINITAUR.demos is False and MINITAUR.experts is None  # EARL's has_demos(): False
    obs = np.zeros((2, 32), np.float32)
    obs[:, 28:30] = [0.35, 0.02]
    obs[:, 30:32] = [0.4, 0.0]
    obs[1, 8:16], obs[1, 16:24] = 2.0, 1.5  # velocities, torques: energy |8 x 3.0| x 0.002
    assert np.allclose(s.compute_reward(obs), [-2 * 0.07, -2 * 0.07 - 0.005 * 24.0 * 0.002])
    assert s.is_success(obs).all() and not s.is_success(s.with_goal(obs, [0.2, 0.0])).any()
    assert np.allclose(s.goal_distance(obs), np.hypot(0.05, 0.02))


def _without_pybullet(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name.split(".")[0] == "pybullet" else real(name, *a))


def test_without_pybullet_one_line_exit_2(monkeypatch, capsys, tmp_path):
    _without_pybullet(monkeypatch)
    assert main(["run", "algo=naive", "env=minitaur", "steps=300", f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("harness: error:"), err
    assert "pybullet" in err and "not installed" in err and "pip install 'earl-harness[minitaur]'" in err, err
    assert "Python <= 3.11" in err and not (tmp_path / "r").exists()
    with pytest.raises(EnvUnavailableError, match=r"needs pybullet") as e:
        gym.make("earl/Minitaur-v0")
    assert "\n" not in str(e.value)
    assert main(["list"]) == 0  # still listed, with the reason
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.split()[:1] == ["minitaur"])
    assert "needs pybullet" in line
    # on a Python newer than pybullet's wheels the line says so
    old = dataclasses.replace(MINITAUR, requires=("pybullet", "minitaur", "3.10"))
    assert "not available for Python 3." in old.unavailable() and "Python <= 3.10" in old.unavailable()


def test_dhand_lightbulb_listed_and_refused(capsys, tmp_path):
    assert UNAVAILABLE_ENVS == {"dhand_lightbulb": "not available: EARL never released it"}
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    envs = out.split("envs:")[1].split("suites:")[0]
    assert "dhand_lightbulb" in envs and "not available: EARL never released it" in envs
    assert main(["run", "algo=naive", "env=dhand_lightbulb", f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "harness: error: env dhand_lightbulb: not available: EARL never released it"
    with pytest.raises(EnvUnavailableError):
        check_env("dhand_lightbulb")
    assert "dhand_lightbulb" not in ENVS  # no spec: nothing derives tables from it


# -- the simulation ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env():
    if not (_has_pybullet() and _has_walls()):
        pytest.skip("pybullet or EARL's wall_tile.urdf not available")
    from harness.envs.minitaur import MinitaurEnv

    e = MinitaurEnv()
    yield e
    e.close()


def sim(f):
    for m in needs_sim:
        f = m(f)
    return f


@sim
def test_reset_is_earls_initial_state():
    """EARL's pose before settling (base at (0, 0, 0.2) level, motors +-pi/2, knees +-2.1834 x motor direction, zero
    velocities), then the settled reset state: bitwise EARL's code (same contact-pair order), 3.4e-3 from EARL's code
    with pybullet's default order."""
    from harness.envs.minitaur import MinitaurEnv

    e = MinitaurEnv(randomize=False)
    p, r = e._p, e._robot
    p.restoreState(e._fresh)
    pos, orn = p.getBasePositionAndOrientation(r)
    assert np.allclose(pos, (0, 0, 0.2)) and np.allclose(orn, (0, 0, 0, 1))
    for i, leg in enumerate(("front_left", "back_left", "front_right", "back_right")):
        for k, side in enumerate("LR"):
            d = MOTOR_DIRECTION[2 * i + k]
            motor = p.getJointState(r, e._joints[f"motor_{leg}{side}_joint"])
            knee = p.getJointState(r, e._joints[f"knee_{leg}{side}_link"])
            assert np.isclose(motor[0], d * np.pi / 2) and np.isclose(knee[0], d * KNEE_ANGLE)
            assert motor[1] == knee[1] == 0.0
    obs, info = e.reset(seed=0)
    assert obs.shape == (32,) and obs.dtype == np.float32 and not info["success"]
    assert np.allclose(e._obs64[:30], INITIAL_STATE, rtol=0, atol=1e-12), np.abs(e._obs64[:30] - INITIAL_STATE).max()
    assert np.abs(e._obs64[:30] - EARL_DEFAULT_PAIRS_RESET).max() < 5e-3
    assert any(np.array_equal(obs[30:], g) for g in GOALS.astype(np.float32))
    # settled near EARL's pose: motors near pi/2 (x direction in the observation: all positive), level base at origin
    assert np.all(np.abs(obs[0:8] - np.pi / 2) < 0.1) and np.all(np.abs(obs[28:30]) < 1e-3) and obs[27] > 0.9999
    e.close()


@sim
def test_pen_walls_where_earl_puts_them(env):
    p = env._p
    assert len(env._walls) == 12 and [p.getBodyInfo(w)[1] for w in env._walls] == [b"wall"] * 12
    for w, pos, quat in zip(env._walls, WALL_POSITIONS, EARL_WALL_QUATS):
        got_pos, got_quat = p.getBasePositionAndOrientation(w)
        assert np.allclose(got_pos, pos) and np.allclose(got_quat, quat, atol=1e-12)
    # the tiles' inner faces close a 3 m x 3 m pen around the origin, 0.5 m high from z = 0.25 (EARL's tile: a
    # 0.1 x 1 x 0.5 box, its centre 0.05 behind and 0.5 above the tile's origin)
    lo = np.array([p.getAABB(w)[0] for w in env._walls])
    hi = np.array([p.getAABB(w)[1] for w in env._walls])
    assert np.allclose(hi[0:3, 0], -1.5, atol=0.03) and np.allclose(lo[3:6, 0], 1.5, atol=0.03)
    assert np.allclose(hi[6:9, 1], -1.5, atol=0.03) and np.allclose(lo[9:12, 1], 1.5, atol=0.03)
    assert np.allclose(lo[:, 2], 0.25, atol=0.03) and np.allclose(hi[:, 2], 0.75, atol=0.03)


def _episode(env, seed, policy):
    """A 1000-step (H_E) episode from reset(seed); the float64 observations and the env's rewards."""
    env.reset(seed=seed)
    rng = np.random.default_rng(1000 + seed)
    obs, rewards = [], []
    for _ in range(MINITAUR_SPEC.eval_horizon):
        a = np.zeros(8, np.float32) if policy == "zero" else rng.uniform(-1, 1, 8).astype(np.float32)
        rewards.append(env.step(a)[1])
        obs.append(env._obs64.copy())
    return np.array(obs), np.array(rewards)


def _returns(obs, goals):
    """The 1000-step return of the same trajectory for each goal (the goal does not act on the dynamics)."""
    out = []
    for g in goals:
        o = obs.copy()
        o[:, 30:32] = g
        out.append(minitaur_reward(o).sum())
    return np.array(out)


@sim
def test_do_nothing_returns_against_the_published_level(env):
    """Zero and uniform random actions for an evaluation episode (H_E = 1000), 2 reset seeds each: the return per
    goal (computed from the trajectory, EARL's reward of the observation: the env's own rewards match it) averaged
    over RISC's 4 goals lies in the range of the published RISC runs' first evaluation (an untrained policy);
    averaged over EARL's 12 default goals it is ~400 lower, outside it."""
    zero, rand, zero12 = [], [], []
    for seed in (0, 1):
        for policy, out in (("zero", zero), ("random", rand)):
            obs, rewards = _episode(env, seed, policy)
            assert np.allclose(rewards, minitaur_reward(obs), rtol=0, atol=1e-12)  # the env's reward is EARL's
            out.append(_returns(obs, GOALS))
            if policy == "zero":
                zero12.append(_returns(obs, EARL_DEFAULT_GOALS))
                assert np.abs(obs[-1, 28:30]).max() < 0.15  # zero actions stay near the origin
    zero, rand, zero12 = np.mean(zero, axis=0), np.mean(rand, axis=0), np.mean(zero12, axis=0)
    print(f"\nzero actions, RISC's 4 goals: {np.round(zero, 1)} mean {zero.mean():.1f}")
    print(f"random actions, RISC's 4 goals: {np.round(rand, 1)} mean {rand.mean():.1f}")
    print(f"zero actions, EARL's 12 goals: mean {zero12.mean():.1f}")
    lo, hi = PUBLISHED_FIRST_EVAL
    for r in (zero.mean(), rand.mean()):
        assert 1.15 * lo < r < 0.85 * hi, r
    assert zero12.mean() < 1.15 * lo  # EARL's 12 goals: about -1000, below every published first evaluation
    # standing near the origin, a goal |gx| away costs about 2 |gx| per step
    assert np.allclose(zero, -2000 * np.abs(GOALS[:, 0]), rtol=0.2)


def test_published_first_evaluations_are_those_numbers():
    try:
        find_data_dir("reference/published_curves.csv.gz")
    except DataNotFoundError:
        pytest.skip("published curves not found")
    from harness.results import load_published

    df = load_published()
    first = df[(df.env == "minitaur") & (df.algo == "risc") & (df.step == 10_000) & (df.metric == "deployed_return")]
    assert len(first) == 5 and np.isclose(first.value.min(), PUBLISHED_FIRST_EVAL[0])
    assert np.isclose(first.value.max(), PUBLISHED_FIRST_EVAL[1])


@sim
def test_success_at_the_goal(env):
    goal = GOALS[1]
    at = np.concatenate([INITIAL_STATE, goal]).astype(np.float32)
    at[28:30] = goal + [0.03, -0.02]
    obs, info = env.reset(seed=4, options={"state": at})
    assert info["success"] and np.array_equal(obs[30:], goal.astype(np.float32))
    assert np.allclose(obs[28:30], at[28:30], atol=1e-6)
    for _ in range(10):  # standing still there stays a success, with EARL's reward near 0
        obs, reward, terminated, truncated, info = env.step(np.zeros(8, np.float32))
        assert info["success"] and reward > -0.2 and not terminated and not truncated
    near = at.copy()
    near[28:30] = goal + [0.15, 0.0]
    assert not env.reset(seed=4, options={"state": near})[1]["success"]
    obs, info = env.reset(seed=4, options={"goal": [0.0, 0.0]})  # a goal at the reset position
    assert info["success"] and np.array_equal(obs[30:], [0, 0])


@sim
def test_seeded_and_no_global_rng(env):
    from harness.envs.minitaur import MinitaurEnv

    np_state, py_state = np.random.get_state()[1].copy(), random.getstate()
    other = MinitaurEnv()
    actions = np.random.default_rng(3).uniform(-1, 1, (50, 8)).astype(np.float32)
    a0, _ = env.reset(seed=11)
    b0, _ = other.reset(seed=11)
    assert np.array_equal(a0, b0) and env._params == other._params
    for a in actions:
        ra, rb = env.step(a), other.step(a)
        assert np.array_equal(ra[0], rb[0]) and ra[1] == rb[1]
    draws = {tuple(env.reset(seed=s)[0][30:]) + (env._params["base_mass"],) for s in range(8)}
    assert len(draws) == 8  # the goal and the randomizer follow the seed
    assert len({tuple(env.reset(seed=s)[0][30:]) for s in range(40)}) == 4
    assert np.array_equal(np.random.get_state()[1], np_state) and random.getstate() == py_state
    other.close()


@sim
def test_reset_does_not_depend_on_history(env):
    from harness.envs.minitaur import MinitaurEnv

    actions = np.random.default_rng(5).uniform(-1, 1, (300, 8)).astype(np.float32)
    env.reset(seed=2)
    for a in actions[:200]:
        env.step(a)
    fresh = MinitaurEnv()
    assert np.array_equal(env.reset(seed=9)[0], fresh.reset(seed=9)[0])
    for a in actions[200:]:
        assert np.array_equal(env.step(a)[0], fresh.step(a)[0])
    fresh.close()


def _run(env, actions) -> list[tuple[bytes, float]]:
    """The observations (as bytes: compared bit for bit) and rewards of ``actions`` from the env's current state."""
    return [(o.tobytes(), r) for o, r, *_ in (env.step(a) for a in actions)]


@sim
def test_checkpoint_round_trip_is_exact(env):
    """``get_sim_state`` / ``set_sim_state`` (pybullet's saveBullet/restoreState of the world, the randomizer's draws,
    the motor model's state, goal, RNG) and pickling continue bit for bit: in the same env, in another env, and after
    the robot came to rest (pybullet's sleeping)."""
    from harness.envs.minitaur import MinitaurEnv

    actions = np.random.default_rng(6).uniform(-1, 1, (400, 8)).astype(np.float32)
    env.reset(seed=21)
    for a in actions[:150]:
        env.step(a)
    st = env.get_sim_state()
    pickle.dumps(st)
    ref = _run(env, actions[150:300])
    after = env.reset()[0]  # the RNG state is part of the checkpoint too
    env.set_sim_state(st)
    assert _run(env, actions[150:300]) == ref
    assert np.array_equal(env.reset()[0], after)
    other = MinitaurEnv()
    other.reset(seed=77)
    other.set_sim_state(st)
    assert _run(other, actions[150:300]) == ref
    clone = pickle.loads(pickle.dumps(other))
    assert _run(clone, actions[300:]) == _run(other, actions[300:])
    # at rest
    other.reset(seed=3)
    for _ in range(1500):
        obs = other.step(np.zeros(8, np.float32))[0]
    assert np.abs(obs[8:16]).max() < 0.05
    st = other.get_sim_state()
    ref = _run(other, actions[:100])
    other.set_sim_state(st)
    assert _run(other, actions[:100]) == ref
    other.close()
    clone.close()


@sim
def test_gym_make_and_render():
    e = gym.make("earl/Minitaur-v0", render_mode="rgb_array")
    obs, _ = e.reset(seed=0)
    assert e.spec.max_episode_steps == 1000 and obs.shape == (32,) and e.action_space.shape == (8,)
    frame = e.render()
    assert frame.shape == (260, 480, 3) and frame.dtype == np.uint8 and frame.std() > 0
    e.close()


def test_algorithms_that_cannot_run_on_minitaur_are_refused_with_the_reason(capsys, tmp_path):
    """MEDAL and VaPRL need demonstrations (EARL ships none for minitaur), FBRL+VICE learns from 1[success]: one line
    each, naming what runs there; an algorithm that would write whole states into minitaur's xy goal is refused too."""
    from harness.registry import ALGORITHMS
    from harness.runnable import CannotRunThere, check_runs_on, why_not_on

    for algo, why in (("medal", "needs demonstrations"), ("vaprl", "needs demonstrations"),
                      ("fbrl_vice", "learns from 1[success]")):
        assert main(["run", f"algo={algo}", "env=minitaur", f"results={tmp_path / 'r'}", "--dry-run"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and why in err, err
        assert err.endswith("algorithms that run on env=minitaur: naive, oracle, fbrl, r3l, risc, risc_no_tab"), err
    naive = ALGORITHMS["naive"]
    whole_states = type("WholeStates", (naive,), {"state_goals": True})
    assert why_not_on(whole_states, naive.Config(), "minitaur").startswith("sets whole states as goals and "
                                                                             "env=minitaur's goal is 2 of its 30")
    assert why_not_on(whole_states, naive.Config(), "sawyer_door") is None
    with pytest.raises(CannotRunThere, match="^algo=w sets whole states as goals"):
        check_runs_on("w", whole_states, naive.Config(), "minitaur")


def _member_step(algo, spec, obs, next_obs):
    """One scripted step (no simulator): what the algorithm stores for ``next_obs``."""
    from tests.stepping import take_step

    take_step(algo, obs, next_obs, np.zeros(len(obs), dtype=bool))


def test_fbrl_r3l_and_risc_project_goals_and_learn_from_the_dense_reward():
    """FBRL's backward goal is the start position (base xy of EARL's initial state); RISC's backward goal is, as its
    released code computes it, a task goal fixed per run (or the start position with backward_goal=initial_state);
    every stored reward is EARL's dense reward of the stored observation, under the phase's goal."""
    import torch

    from algorithms.api import BACKWARD, DemoSet
    from algorithms.fbrl import FBRL, FBRLConfig
    from algorithms.r3l import R3L, R3LConfig
    from algorithms.risc import RISC, RISCConfig
    from harness.envs import get_spec, load_env_demos

    spec = get_spec("minitaur")
    demos = DemoSet(load_env_demos("minitaur", "forward"), load_env_demos("minitaur", "reverse"))
    start_xy = spec.initial_states[0, 28:30]
    assert np.array_equal(spec.goal_of(spec.initial_states), start_xy[None])
    rng = np.random.default_rng(0)

    def obs_at(goal):
        o = np.zeros((2, 32), np.float32)
        o[:, :30] = spec.initial_states[0] + rng.normal(0, 0.05, (2, 30))
        o[:, 30:] = goal
        return o

    small = dict(seed_steps=10**6, batch_size=8, buffer_capacity=1000)
    fb = FBRL(spec, demos, FBRLConfig(switch_every=2, **small), [0, 1], torch.device("cpu"))
    obs = obs_at(spec.goal_states[0])
    fb.on_reset(obs, np.ones(2, dtype=bool))
    for _ in range(2):  # two forward steps, then the switch to backward
        _member_step(fb, spec, obs, (obs := obs_at(spec.goal_states[0])))
    assert (fb.phase == BACKWARD).all() and np.allclose(fb.goal, start_xy)
    nxt = obs_at(spec.goal_states[0])
    _member_step(fb, spec, obs, nxt)
    batch = fb.bwd_buf.sample(4, mask=np.ones(2, dtype=bool))
    no = batch["next_obs"].numpy()
    assert np.allclose(no[..., 30:], start_xy)  # the backward controller's goal is the start xy
    assert np.allclose(batch["reward"].numpy(), spec.compute_reward(no).astype(np.float32))
    assert (batch["reward"].numpy() < 0).all()  # dense: minus the distance, not 1[success]

    r3l = R3L(spec, demos, R3LConfig(**small), [0], torch.device("cpu"))
    o = obs_at(spec.goal_states[1])[:1]
    r3l.on_reset(o, np.ones(1, dtype=bool))
    _member_step(r3l, spec, o, obs_at(spec.goal_states[1])[:1])
    b = r3l.fwd_buf.sample(2, mask=np.ones(1, dtype=bool))
    assert np.allclose(b["reward"].numpy(), spec.compute_reward(b["next_obs"].numpy()).astype(np.float32))

    cfg = dict(seed_steps=10**6, batch_size=8, buffer_capacity=10_000)
    risc = RISC(spec, demos, RISCConfig(**cfg), [0, 1, 2, 3], torch.device("cpu"))
    pools = np.concatenate(risc.backward_pools)
    assert pools.shape == (4, 2) and all((spec.goal_states == g).all(1).any() for g in pools)
    again = RISC(spec, demos, RISCConfig(**cfg), [0, 1, 2, 3], torch.device("cpu"))
    assert np.array_equal(np.concatenate(again.backward_pools), pools)  # drawn from each member's seed
    home = RISC(spec, demos, RISCConfig(backward_goal="initial_state", **cfg), [0], torch.device("cpu"))
    assert np.array_equal(home.backward_pools[0], start_xy[None])
    # a forward phase of one step, then the backward phase heads for the member's pool goal; both steps stored with
    # the dense reward under their own goal
    one = RISC(spec, demos, RISCConfig(phase_step_limit=1, **cfg), [0, 1], torch.device("cpu"))
    o = obs_at(spec.goal_states[0])
    one.on_reset(o, np.ones(2, dtype=bool))
    forward_goals = one.goal.copy()  # task goals drawn for the first phase
    _member_step(one, spec, o, (o := obs_at(spec.goal_states[0])))
    assert (one.direction == BACKWARD).all() and np.allclose(one.goal, np.concatenate(one.backward_pools))
    _member_step(one, spec, o, obs_at(spec.goal_states[0]))
    n = one.buffer.size
    for i in range(2):
        steps = ~one.buffer.data["first"][i, : n[i]].numpy()  # transitions, not segment starts
        obs = one.buffer.data["obs"][i, : n[i]].numpy()[steps][-2:]  # the forward step, then the backward one
        reward = one.buffer.data["reward"][i, : n[i]].numpy()[steps][-2:]
        assert np.allclose(obs[0, 30:], forward_goals[i]) and np.allclose(obs[1, 30:], one.backward_pools[i][0])
        assert np.allclose(reward, spec.compute_reward(obs).astype(np.float32)) and (reward < 0).all()
    # on an env whose goal is the whole state both choices are EARL's initial states
    door = get_spec("sawyer_door")
    for how in ("reset_observation", "initial_state"):
        r = RISC(door, DemoSet(load_env_demos("sawyer_door", "forward"), load_env_demos("sawyer_door", "reverse")),
                 RISCConfig(backward_goal=how, **cfg), [0], torch.device("cpu"))
        assert r.backward_pools[0] is door.initial_states


@sim
def test_naive_end_to_end_and_resume(tmp_path, capsys):
    """The brief's command, then the same stopped at 200 and resumed from its checkpoint (the envs' pybullet worlds
    included): the curves agree exactly."""
    from harness.results import load

    args = ["run", "algo=naive", "env=minitaur", "eval_every=100", "eval_episodes=1", "all.seed_steps=100",
            "all.batch_size=16"]
    assert main([*args, "steps=300", f"results={tmp_path / 'a'}"]) == 0, capsys.readouterr().err
    df = load(tmp_path / "a")
    ret = df[df.metric == "deployed_return"].sort_values("step")
    assert list(ret.step) == [0, 100, 200, 300] and (ret.value < 0).all() and (ret.value > -3000).all()
    cont = df[df.metric == "continuing_reward"].sort_values("step")
    assert cont.value.iloc[-1] < 0  # the train env's dense reward accumulates
    print("\nnaive on minitaur, deployed return:", ret.value.round(1).tolist())
    capsys.readouterr()
    for steps in (200, 300):
        assert main([*args, "checkpoint_every=100", f"steps={steps}", f"results={tmp_path / 'b'}"]) == 0
    out = capsys.readouterr()
    assert "resuming from the checkpoint at step 200" in out.out + out.err
    resumed = load(tmp_path / "b")
    curves = ("deployed_return", "deployed_success", "continuing_reward")
    key = ["step", "metric"]
    a = df[df.metric.isin(curves)].sort_values(key)[[*key, "value"]].reset_index(drop=True)
    b = resumed[resumed.metric.isin(curves)].sort_values(key)[[*key, "value"]].reset_index(drop=True)
    assert a.equals(b), (a, b)
