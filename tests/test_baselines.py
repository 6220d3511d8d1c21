"""Baselines (docs/algorithms.md 4-7, 10-13): the per-method rules, learned-reward pieces and member independence."""

import numpy as np
import pytest
import torch

from algorithms.api import BACKWARD, FORWARD, DemoSet
from algorithms.bc import BC, BCConfig
from algorithms.core.nets import Stream
from algorithms.fbrl import FBRL, FBRLConfig
from algorithms.fbrl_vice import FBRLVICE, FBRLVICEConfig
from algorithms.gail import GAILNaive, GAILNaiveConfig, gradient_penalty
from algorithms.naive import Naive, NaiveConfig
from algorithms.oracle import Oracle, OracleConfig
from algorithms.r3l import R3L, R3LConfig, RunningMeanStd
from harness.data import load_demos
from harness.envs import get_spec
from tests.stepping import take_step

from .conftest import requires_data, rollout_actions

pytestmark = requires_data
ENV = "tabletop_manipulation"
SPEC = get_spec(ENV)
AWAY = np.array([1.0, 1.0, 2.5, 0.0, -1, -1], dtype=np.float32)  # neither at a task goal nor at rho0



@pytest.fixture(scope="module")
def demos():
    return DemoSet(load_demos(ENV, "forward"), load_demos(ENV, "reverse"))


def _make(cls, cfg_cls, demos, seeds=(0,), **cfg):
    base = dict(seed_steps=10**9, batch_size=16)
    return cls(SPEC, demos, cfg_cls(**{**base, **cfg}), list(seeds), torch.device("cpu"))


def _obs(state, goal):
    return np.concatenate([state, goal]).astype(np.float32)[None]


def _step(m, obs, next_obs, hard=False):
    return take_step(m, obs, next_obs, np.array([hard]))


def _last(buf, field):
    return buf.data[field][0, buf.size[0] - 1].item()


def test_fbrl_backward_phase_ends_on_reaching_rho0(demos):
    m = _make(FBRL, FBRLConfig, demos, switch_every=5)
    assert int(m.bwd_buf.num_transitions[0]) == 1256  # backward demos, as stored
    o = _obs(AWAY, SPEC.goal_states[0])
    m.on_reset(o, np.ones(1, bool))
    for _ in range(5):
        _step(m, o, o)
    assert m.phase[0] == BACKWARD
    s0 = SPEC.initial_states[0]
    np.testing.assert_array_equal(m.goal[0], s0)  # backward goal: an EARL initial state
    _step(m, o, o)  # not at rho0: reward 0 on the initial-state goal, phase goes on
    assert m.phase[0] == BACKWARD and _last(m.bwd_buf, "reward") == 0.0
    np.testing.assert_array_equal(m.bwd_buf.data["obs"][0, m.bwd_buf.size[0] - 1, 6:].numpy(), s0)
    at_rho0 = _obs(s0, SPEC.goal_states[0])  # the env's own goal half is ignored
    _step(m, o, at_rho0)  # reached rho0 after 2 of 5 steps: early switch, terminal, reward 1
    assert m.phase[0] == FORWARD and m.phase_steps[0] == 0
    assert _last(m.bwd_buf, "reward") == 1.0 and _last(m.bwd_buf, "terminal") and not _last(m.bwd_buf, "truncated")
    assert any(np.array_equal(m.goal[0], g) for g in SPEC.goal_states)  # forward: a fresh task goal
    assert _last(m.fwd_buf, "first")


def test_running_std_normalises_a_known_stream():
    rng = np.random.default_rng(0)
    rms = RunningMeanStd(2, (), "cpu")
    seen = [[], []]
    for k in range(50):
        x = rng.normal(3.0, 2.0, size=(2, int(rng.integers(1, 40))))
        mask = np.array([True, k % 3 != 0])
        rms.update(torch.as_tensor(x, dtype=torch.float32), mask)
        for i in np.flatnonzero(mask):
            seen[i].extend(np.float32(x[i]).tolist())
    for i in range(2):
        normalised = np.array(seen[i]) / rms.std[i].item()
        assert normalised.std() == pytest.approx(1.0, abs=1e-5)
        assert rms.count[i].item() == len(seen[i])


def test_r3l_backward_buffer_has_no_demos_and_reward_is_normalised_novelty(demos):
    m = _make(R3L, R3LConfig, demos, seed_steps=0, switch_every=4, batch_size=8)
    assert int(m.fwd_buf.num_transitions[0]) == 1278
    assert m.bwd_buf.size[0] == 0 and int(m.bwd_buf.num_transitions[0]) == 0
    o = _obs(AWAY, SPEC.goal_states[0])
    m.on_reset(o, np.ones(1, bool))
    for t in range(11):  # forward 4, backward 4 (its first step has nothing to sample), forward 3
        _step(m, o, _obs(AWAY + 0.01 * t, SPEC.goal_states[0]))
    assert int(m.backward.critic_opt.step_count[0]) == 3  # backward updates once it holds a transition
    assert int(m.rnd.opt.step_count[0]) == 3  # one predictor step per backward update
    assert m.rnd.obs_rms.count[0].item() == 5  # the FIRST state and 4 backward steps
    batch = m.bwd_buf.sample(8)
    states = batch["next_obs"][..., :6]
    novelty = m.rnd.novelty(states).detach()
    reward = m.backward_reward(batch, np.ones(1, bool))
    torch.testing.assert_close(reward, novelty / m.rnd.novelty_rms.std[:, None])


def test_fbrl_vice_positives_are_rho0_pairs(demos):
    m = _make(FBRLVICE, FBRLVICEConfig, demos)
    pos = m.pos_buf.data["x"][0, : m.pos_buf.size[0]].numpy()
    expected = {tuple(np.concatenate([s, g])) for s in SPEC.initial_states for g in SPEC.goal_states}
    assert len(pos) == 4 and {tuple(p) for p in pos} == expected


def test_dac_gradient_penalty_on_a_linear_discriminator():
    w = torch.tensor([3.0, 4.0, 0.0])  # ||w|| = 5: penalty 10 * (5 - 1)^2 = 160 wherever it is evaluated
    gen = torch.Generator().manual_seed(0)
    expert, agent = torch.randn(2, 8, 3, generator=gen), torch.randn(2, 8, 3, generator=gen)
    u = torch.rand(2, 8, 1, generator=gen)
    gp = gradient_penalty(lambda x: x @ w, expert, agent, u, weight=10.0)
    torch.testing.assert_close(gp, torch.full((2,), 160.0))


def test_dac_reward_is_the_logit_and_discriminator_learns(demos):
    m = _make(GAILNaive, GAILNaiveConfig, demos, batch_size=32)
    batch = m.buf.sample(32)
    d = torch.sigmoid(m.disc.logits(torch.cat([batch["obs"], batch["action"]], -1))).detach()
    torch.testing.assert_close(m.reward(batch), torch.log(d) - torch.log(1 - d), rtol=1e-4, atol=1e-4)
    agent = torch.cat([batch["obs"], torch.zeros_like(batch["action"])], -1)
    losses = [m.disc.update(m.expert.sample(32), agent)["discriminator_loss"].item() for _ in range(30)]
    assert losses[-1] < losses[0]
    assert m.cfg.bootstrap_on_truncation and not m.cfg.end_on_success
    # success ends no GAIL episode, so the demos end in time-outs too: their last steps bootstrap as the agent's do
    stored = slice(0, int(m.buf.size[0]))
    n_demos = int(demos.forward.terminals.sum())
    assert m.buf.data["terminal"][0, stored].sum() == 0 and m.buf.data["truncated"][0, stored].sum() == n_demos
    naive = _make(Naive, NaiveConfig, demos)  # naive RL ends on success: its demos end terminal
    assert naive.buf.data["terminal"][0, : int(naive.buf.size[0])].sum() == n_demos


def test_bc_loss_decreases_to_near_zero_on_the_demos(demos):
    m = BC(SPEC, demos, BCConfig(batch_size=256), [0], torch.device("cpu"))
    all_pairs = m.data.data["x"][:, : m.data.size[0]]
    first = m.loss(all_pairs).item()
    o = np.zeros((1, 12), np.float32)
    for _ in range(400):
        take_step(m, o, o, np.zeros(1, bool))  # one gradient step per training step, in update
    assert (m.act(o) == 0).all() and m.grad_step == 400
    final = m.loss(all_pairs).item()
    assert final < 0.05 and final < first / 10
    obs = demos.forward.observations[:5]
    np.testing.assert_allclose(m.eval_act(obs[:1]), m.eval_act(obs[:1]))  # deterministic


def test_oracle_asks_for_a_reset_every_eval_horizon_and_on_success(demos):
    m = _make(Oracle, OracleConfig, demos, seed_steps=50)
    o = _obs(AWAY, SPEC.goal_states[0])
    m.on_reset(o, np.ones(1, bool))
    asks = [bool(_step(m, o, o)[0]) for _ in range(SPEC.eval_horizon)]
    assert asks == [False] * (SPEC.eval_horizon - 1) + [True]  # H_E = 200 for tabletop
    assert _last(m.buf, "truncated") and not _last(m.buf, "terminal")
    m.on_reset(o, np.ones(1, bool))
    assert not _step(m, o, o)[0]
    assert _step(m, o, _obs(SPEC.goal_states[0], SPEC.goal_states[0]))[0]  # success: terminal, reset
    assert _last(m.buf, "terminal") and _last(m.buf, "reward") == 1.0


def test_oracle_starts_from_the_forward_demos_unless_buffer_demos_is_off(demos):
    """[MC]'s oracle.py seeds its buffer with the forward demos; ``buffer_demos=False`` starts it empty (TF-Agents)."""
    n = len(demos.forward.actions)
    assert _make(Oracle, OracleConfig, demos).buf.size[0] >= n  # every demo transition (and each segment's end)
    empty = _make(Oracle, OracleConfig, demos, seeds=(0, 1), buffer_demos=False)
    assert empty.buf.size.tolist() == [0, 0]


def test_oracle_logs_q_at_each_episode_start_beside_the_discounted_return(demos):
    """episode/q_start is the critic's min-Q at the first (obs, action) of an episode started after the seed phase;
    episode/return the episode's task reward, scaled by 10 and discounted by 0.99 per step from that first step."""
    m = _make(Oracle, OracleConfig, demos, seed_steps=3)
    o, win = _obs(AWAY, SPEC.goal_states[0]), _obs(SPEC.goal_states[0], SPEC.goal_states[0])
    calls, q_value = [], m.agent.q_value
    m.agent.q_value = lambda obs, action: calls.append((obs.clone(), action.clone(), q := q_value(obs, action))) or q
    m.on_reset(o, np.ones(1, bool))
    for _ in range(3):
        _step(m, o, o)
    assert _step(m, o, win)[0] and not calls  # the seed-phase episode ends in success, unlogged
    assert all(np.isnan(v).all() for k, v in m.metrics().items() if k in ("episode/q_start", "episode/return"))
    m.on_reset(o, np.ones(1, bool))
    action = m.act(o)
    assert len(calls) == 1
    np.testing.assert_array_equal(calls[0][0].numpy(), o)
    np.testing.assert_array_equal(calls[0][1].numpy(), action)
    m.update()
    m.store(o, np.zeros(1, bool))
    assert not m.observe(o, np.zeros(1, bool))[0]
    _step(m, o, o)
    assert _step(m, o, win)[0] and len(calls) == 1  # success on the episode's third step
    logged = m.metrics()
    assert logged["episode/q_start"][0] == pytest.approx(calls[0][2].item())
    assert logged["episode/return"][0] == pytest.approx(10 * 0.99**2)
    m.on_reset(o, np.ones(1, bool))
    for _ in range(SPEC.eval_horizon):  # a truncated episode without success: return 0
        asked = _step(m, o, o)[0]
    assert asked and len(calls) == 2 and m.metrics()["episode/return"][0] == 0.0
    with torch.no_grad():
        obs, act = torch.as_tensor(o), torch.as_tensor(action)
        np.testing.assert_allclose(q_value(obs, act).numpy(), m.agent.critic(obs[:, None], act[:, None]).amin((1, 2)))


def test_naive_cuts_pseudo_episodes_with_fresh_goals_and_never_resets(demos):
    m = _make(Naive, NaiveConfig, demos)
    o = _obs(AWAY, SPEC.goal_states[0])
    m.on_reset(o, np.ones(1, bool))
    goals, firsts = [], []
    for t in range(1, 1501):
        assert not _step(m, o, o)[0]
        if t % 300 == 0:
            assert _last(m.buf, "first")  # a new segment right after the truncated cut
            k = m.buf.size[0] - 2
            assert m.buf.data["truncated"][0, k].item() and not m.buf.data["terminal"][0, k].item()
            goals.append(tuple(m.goal[0]))
            firsts.append(m.buf.size[0] - 1)
        else:
            assert not _last(m.buf, "first")
    assert all(g in {tuple(x) for x in SPEC.goal_states} for g in goals) and len(set(goals)) > 1
    rng = np.random.default_rng([0, Stream.TASK_GOALS])  # the member's goal stream: one draw per cut
    assert goals == [tuple(SPEC.goal_states[rng.integers(4)]) for _ in goals]


def test_fbrl_members_are_independent(demos):
    """E = 2 gives each member what an E = 1 run with its seed gives, across phases and masked updates, to float
    rounding: a member-batched product may round differently from an E = 1 one (other shapes, alignments and, on
    AVX-512 CPUs, kernels: ~1e-7 per step), hence a tolerance and no bitwise check across E."""
    kw = dict(seed_steps=100, batch_size=16, switch_every=25)
    both = rollout_actions(_make(FBRL, FBRLConfig, demos, (3, 5), **kw), ENV, (3, 5), 300)
    for i, s in enumerate((3, 5)):
        single = rollout_actions(_make(FBRL, FBRLConfig, demos, (s,), **kw), ENV, (s,), 300)
        np.testing.assert_allclose(both[:, i], single[:, 0], atol=1e-4)
