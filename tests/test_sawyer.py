"""Acceptance tests of the EARL Sawyer door / peg envs (harness/envs/sawyer.py) and their experts.

Numbers worth reading are printed (run with ``-s``): reset errors against EARL's published initial
states, open-loop demo replay success and timing, expert success rates, step rates.
"""

from __future__ import annotations

import math
import os
import pickle

import numpy as np
import pytest

from harness.data import DataNotFoundError, find_data_dir, load_demos

try:
    find_data_dir("assets/metaworld_earl")
    find_data_dir("demos/sawyer_peg/forward.npz")
except DataNotFoundError as e:  # pragma: no cover
    pytest.skip(f"EARL data not available: {e}", allow_module_level=True)

from harness.envs import sawyer_experts as X  # noqa: E402
from harness.envs.bench_sawyer import our_step_rate, raw_metaworld_step_rate  # noqa: E402
from harness.envs.sawyer import (  # noqa: E402
    DOOR_SPEC,
    PEG_SPEC,
    SawyerDoorEnv,
    SawyerPegEnv,
)

ENVS = {"sawyer_door": SawyerDoorEnv, "sawyer_peg": SawyerPegEnv}
EXPERTS = {
    "sawyer_door": (X.door_forward, X.door_backward),
    "sawyer_peg": (X.peg_forward, X.peg_backward),
}


@pytest.fixture(scope="module")
def door():
    env = SawyerDoorEnv()
    yield env
    env.close()


@pytest.fixture(scope="module")
def peg():
    env = SawyerPegEnv()
    yield env
    env.close()


def _env(name, door, peg):
    return door if name == "sawyer_door" else peg


# ------------------------------------------------------------------------------------------------
# specs and constants
# ------------------------------------------------------------------------------------------------

def test_specs():
    assert (DOOR_SPEC.gym_id, PEG_SPEC.gym_id) == ("earl/SawyerDoor-v0", "earl/SawyerPeg-v0")
    for s in (DOOR_SPEC, PEG_SPEC):
        assert (s.state_dim, s.act_dim, s.obs_dim, s.success_idx) == (7, 4, 14, (4, 5, 6))
    assert (DOOR_SPEC.success_threshold, DOOR_SPEC.train_horizon, DOOR_SPEC.eval_horizon) == (0.02, 200_000, 300)
    assert (PEG_SPEC.success_threshold, PEG_SPEC.train_horizon, PEG_SPEC.eval_horizon) == (0.05, 100_000, 200)
    assert DOOR_SPEC.initial_states.shape == (1, 7) and PEG_SPEC.initial_states.shape == (15, 7)
    np.testing.assert_array_equal(PEG_SPEC.goal_states, [[0.0, 0.6, 0.2, 1.0, -0.27, 0.6, 0.13]])
    np.testing.assert_allclose(DOOR_SPEC.goal_states[0, 4:], [0.29072163, 0.74286009, 0.10003595])
    np.testing.assert_array_equal(PEG_SPEC.initial_states[:, :4], np.tile([0.00615235, 0.6001898, 0.19430117, 1.0], (15, 1)))
    assert np.all(PEG_SPEC.initial_states[:, 6] == 0.02)


def test_envs_subclass_metaworld_and_earlenv():
    from metaworld.envs.sawyer_door_close_v3 import SawyerDoorCloseEnvV3
    from metaworld.envs.sawyer_peg_insertion_side_v3 import SawyerPegInsertionSideEnvV3

    from harness.envs.base import EarlEnv

    assert issubclass(SawyerDoorEnv, EarlEnv) and issubclass(SawyerDoorEnv, SawyerDoorCloseEnvV3)
    assert issubclass(SawyerPegEnv, EarlEnv) and issubclass(SawyerPegEnv, SawyerPegInsertionSideEnvV3)
    assert SawyerDoorEnv.spec_ is DOOR_SPEC and SawyerPegEnv.spec_ is PEG_SPEC


def test_earl_door_model(door):
    """EARL's light door (hinge range [-1.4, 0]), not Meta-World 3's; expert constants match it."""
    m = door.model
    np.testing.assert_allclose(m.jnt_range[m.joint("doorjoint").id], [-1.4, 0.0])
    assert "metaworld_earl" in door.model_name
    np.testing.assert_allclose(door._hinge_xy, X.DOOR_HINGE_XY, atol=1e-12)
    assert abs(door._handle_phase0 - X.DOOR_HANDLE_PHASE0) < 1e-12
    for ang in (-1.3, -math.pi / 3, -0.4, 0.0):
        door._set_obj_xyz(np.array(ang))
        assert abs(X.door_angle(door.data.geom("handle").xpos[:2]) - ang) < 1e-9
        assert abs(door.handle_to_angle(door.data.geom("handle").xpos) - ang) < 1e-9


# ------------------------------------------------------------------------------------------------
# resets vs EARL's published initial states
# ------------------------------------------------------------------------------------------------

def test_door_reset_matches_earl_initial_state():
    """EARL's listed door state is the noise-0 sample of -pi/3 + U(0, pi/20)."""
    s0 = DOOR_SPEC.initial_states[0]
    env = SawyerDoorEnv(angle_noise=False)
    obs, info = env.reset(seed=0)
    handle_err = np.abs(obs[4:7] - s0[4:7]).max()
    hand_err = np.abs(obs[0:3] - s0[0:3]).max()
    print(f"\n[door reset, angle -pi/3] handle err {handle_err:.2e}, hand err {hand_err * 1e3:.2f} mm, "
          f"gripper {obs[3]:.4f}")
    assert handle_err < 1e-6 and hand_err < 5e-3 and obs[3] == 1.0
    np.testing.assert_allclose(obs[7:], DOOR_SPEC.goal_states[0], atol=1e-7)
    assert not info["success"]
    env.close()


def test_door_random_reset_distribution(door):
    lo, hi = -math.pi / 3, -math.pi / 3 + math.pi / 20
    angles = []
    for seed in range(30):
        obs, _ = door.reset(seed=seed)
        angles.append(door.door_angle())
        assert lo - 1e-12 <= angles[-1] <= hi + 1e-12
        assert abs(door.handle_to_angle(obs[4:7]) - angles[-1]) < 1e-6
        assert np.abs(obs[:3] - DOOR_SPEC.initial_states[0, :3]).max() < 5e-3
    assert np.ptp(angles) > 0.5 * (hi - lo)  # spread over the noise range


def test_peg_reset_to_earl_initial_states(peg):
    errs, hand_errs = [], []
    for s in PEG_SPEC.initial_states:
        obs, _ = peg.reset(options={"state": np.concatenate([s, PEG_SPEC.goal_states[0]])})
        errs.append(np.abs(obs[4:7] - s[4:7]).max())
        hand_errs.append(np.abs(obs[:3] - s[:3]).max())
        np.testing.assert_allclose(obs[7:], PEG_SPEC.goal_states[0], atol=1e-7)
    print(f"\n[peg reset to the 15 EARL states] max head err {max(errs):.2e}, max hand err {max(hand_errs):.2e}")
    assert max(errs) < 1e-6 and max(hand_errs) < 5e-3


def test_peg_random_reset_distribution(peg):
    """Random resets draw the peg body from U([0,.2]x[.5,.7]x{.02}) (head = body - (0.1, 0, 0)),
    the distribution EARL's 15 listed states were sampled from; hand as EARL's within 5 mm."""
    lo, hi = np.array([-0.1, 0.5, 0.02]), np.array([0.1, 0.7, 0.02])
    s = PEG_SPEC.initial_states
    assert np.all(s[:, 4:7] >= lo - 1e-6) and np.all(s[:, 4:7] <= hi + 1e-6)
    heads, hand_errs = [], []
    for seed in range(40):
        obs, _ = peg.reset(seed=seed)
        heads.append(obs[4:7])
        hand_errs.append(np.abs(obs[:3] - s[0, :3]).max())
    heads = np.array(heads)
    print(f"\n[peg random reset] hand err vs EARL {max(hand_errs) * 1e3:.2f} mm, head z err "
          f"{np.abs(heads[:, 2] - 0.02).max():.1e}")
    assert np.all(heads >= lo - 1e-6) and np.all(heads <= hi + 1e-6)
    assert np.abs(heads[:, 2] - 0.02).max() < 1e-6
    assert np.ptp(heads[:, 0]) > 0.1 and np.ptp(heads[:, 1]) > 0.1
    assert max(hand_errs) < 5e-3


def test_reset_options_state_and_goal(door, peg):
    g = DOOR_SPEC.initial_states[0]
    obs, _ = door.reset(seed=3, options={"goal": g})
    np.testing.assert_allclose(obs[7:], g, atol=1e-7)
    # a mid-way door state with a partly closed gripper
    target = np.array([0.15, 0.5, 0.15, 0.6, 0, 0, 0.1, *DOOR_SPEC.goal_states[0]])
    door._set_obj_xyz(np.array(-0.5))
    target[4:7] = door.data.geom("handle").xpos
    obs, _ = door.reset(options={"state": target})
    assert np.abs(obs[4:7] - target[4:7]).max() < 1e-6
    assert np.abs(obs[:3] - target[:3]).max() < 1e-4
    assert abs(obs[3] - 0.6) < 1e-4
    np.testing.assert_allclose(obs[7:], target[7:], atol=1e-7)
    obs, _ = peg.reset(options={"state": target, "goal": PEG_SPEC.goal_states[0]})
    np.testing.assert_allclose(obs[7:], PEG_SPEC.goal_states[0], atol=1e-7)


# ------------------------------------------------------------------------------------------------
# EARL's forward demos replayed open loop
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name,need", [("sawyer_door", 5), ("sawyer_peg", 8)])
def test_forward_demo_replay(name, need, door, peg):
    env = _env(name, door, peg)
    rows = []
    for tr in load_demos(name, "forward").trajectories():
        env.reset(options={"state": tr["observations"][0]})
        first = None
        for k, a in enumerate(tr["actions"]):
            obs, r, term, trunc, info = env.step(a)
            assert r == float(info["success"]) and not term and not trunc
            if info["success"] and first is None:
                first = k + 1
        rows.append((len(tr["actions"]), first))
    ok = [(n, f) for n, f in rows if f is not None]
    diffs = [f - n for n, f in ok]
    print(f"\n[{name} forward replay] {len(ok)}/{len(rows)} reach success; (demo length, first success step): "
          f"{rows}; first success - demo length: mean {np.mean(diffs):+.1f}, range [{min(diffs)}, {max(diffs)}]")
    assert len(ok) >= need


# ------------------------------------------------------------------------------------------------
# scripted experts
# ------------------------------------------------------------------------------------------------

def _expert_episodes(env, n=20):
    """Forward from reset(seed) with the task goal; backward from the forward-success state with the
    goal half set to the state the env started from (success = spec.is_success on [s, s0])."""
    spec = env.spec_
    fwd, bwd = EXPERTS[spec.name]
    H = spec.eval_horizon
    res = []
    for seed in range(n):
        obs, _ = env.reset(seed=seed)
        s0 = obs[:7].copy()
        f_step = None
        for k in range(H):
            obs, r, *_ = env.step(fwd(obs))
            if r > 0:
                f_step = k + 1
                break
        b_step = None
        if f_step is not None:
            for k in range(H):
                ob = spec.with_goal(obs, s0)
                obs, *_ = env.step(bwd(ob))
                if spec.is_success(spec.with_goal(obs, s0)):
                    b_step = k + 1
                    break
        res.append((f_step, b_step))
    return res


@pytest.fixture(scope="module")
def expert_results(door, peg):
    return {"sawyer_door": _expert_episodes(door), "sawyer_peg": _expert_episodes(peg)}


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
@pytest.mark.parametrize("direction", ["forward", "backward"])
def test_expert_success(name, direction, expert_results):
    res = expert_results[name]
    i = 0 if direction == "forward" else 1
    steps = [r[i] for r in res if r[i] is not None]
    print(f"\n[{name} {direction} expert] {len(steps)}/{len(res)} success, steps to success "
          f"median {np.median(steps) if steps else float('nan'):.0f}, max {max(steps) if steps else None}")
    assert len(steps) >= 18


def test_experts_are_pure_and_deterministic(peg):
    obs, _ = peg.reset(seed=0)
    for fn in (X.door_forward, X.door_backward, X.peg_forward, X.peg_backward):
        o = obs.copy()
        a1, a2 = fn(o), fn(o)
        np.testing.assert_array_equal(a1, a2)
        np.testing.assert_array_equal(o, obs)  # input untouched
        assert a1.shape == (4,) and np.all(np.abs(a1) <= 1)


# ------------------------------------------------------------------------------------------------
# determinism, gymnasium API, checkpointing
# ------------------------------------------------------------------------------------------------

def _rollout(env, seed, n=120):
    obs, _ = env.reset(seed=seed)
    acts = np.random.default_rng(1234).uniform(-1, 1, size=(n, 4)).astype(np.float32)
    out = [obs]
    for a in acts:
        out.append(env.step(a)[0])
    return np.array(out)


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_same_seed_same_trajectory(name, door, peg):
    env = _env(name, door, peg)
    t1 = _rollout(env, 7)
    t2 = _rollout(env, 7)
    fresh = ENVS[name]()
    t3 = _rollout(fresh, 7)
    fresh.close()
    assert t1.tobytes() == t2.tobytes() == t3.tobytes()
    assert _rollout(env, 8)[0].tobytes() != t1[0].tobytes() or name == "sawyer_door"


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_global_rng_untouched(name, door, peg):
    env = _env(name, door, peg)
    before = np.random.get_state()[1].copy()
    env.reset(seed=1)
    env.reset()
    for _ in range(5):
        env.step(env.action_space.sample())
    assert np.array_equal(np.random.get_state()[1], before)


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_check_env(name):
    from gymnasium.utils.env_checker import check_env

    env = ENVS[name]()
    check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_never_truncates_and_sparse_reward(name, door, peg):
    env = _env(name, door, peg)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(600):  # beyond Meta-World's 500-step limit
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 4))
        assert not term and not trunc
        assert r == float(env.spec_.compute_reward(obs)) == float(info["success"])
        assert obs.dtype == np.float32 and obs.shape == (14,)


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_sim_state_roundtrip(name, door, peg):
    env = _env(name, door, peg)
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    for _ in range(40):
        env.step(rng.uniform(-1, 1, 4))
    state = pickle.loads(pickle.dumps(env.get_sim_state()))
    acts = rng.uniform(-1, 1, (60, 4))
    ref = np.array([env.step(a)[0] for a in acts])
    ref_rng = env.np_random.random()
    env.set_sim_state(state)
    again = np.array([env.step(a)[0] for a in acts])
    assert ref.tobytes() == again.tobytes()
    assert env.np_random.random() == ref_rng
    fresh = ENVS[name]()
    fresh.reset(seed=99)
    fresh.set_sim_state(state)
    other = np.array([fresh.step(a)[0] for a in acts])
    fresh.close()
    assert ref.tobytes() == other.tobytes()


def test_render():
    env = SawyerDoorEnv(render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    if not os.environ.get("MUJOCO_GL"):
        try:
            img = env.render()
        except RuntimeError as e:
            assert "MUJOCO_GL" in str(e)
            env.close()
            pytest.skip(f"no GL backend: {e}")
    else:
        try:
            img = env.render()
        except RuntimeError as e:
            env.close()
            pytest.skip(f"GL backend {os.environ['MUJOCO_GL']} unusable: {e}")
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8 and img.std() > 0
    env.close()


def test_step_rate_vs_raw_metaworld():
    rows = []
    for name in ENVS:
        raw = raw_metaworld_step_rate(name, 1500)
        ours = our_step_rate(name, 1500)
        rows.append((name, raw, ours))
        print(f"\n[{name}] raw metaworld {raw:.0f} steps/s, ours {ours:.0f} steps/s, ratio {ours / raw:.2f}")
    for name, raw, ours in rows:
        assert ours >= raw / 1.15, f"{name}: ours {ours:.0f} vs raw {raw:.0f} steps/s"


@pytest.mark.parametrize("name", ["sawyer_door", "sawyer_peg"])
def test_env_pickles_with_its_state(name, door, peg):
    env = _env(name, door, peg)
    env.reset(seed=11)
    for _ in range(20):
        env.step(np.full(4, 0.3))
    clone = pickle.loads(pickle.dumps(env))
    acts = np.random.default_rng(2).uniform(-1, 1, (30, 4))
    a = np.array([env.step(x)[0] for x in acts])
    b = np.array([clone.step(x)[0] for x in acts])
    clone.close()
    assert a.tobytes() == b.tobytes()
