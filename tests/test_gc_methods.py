"""RISC (docs/algorithms.md 14) and VaPRL (8): switching rule, success-critic target, bootstrap masks, subgoal
curriculum, relabelled rewards, member independence."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from algorithms.api import BACKWARD, FORWARD, DemoSet
from algorithms.common import to_host
from algorithms.core import SAC, SACConfig, Stream
from algorithms.core.nets import member_randn
from algorithms.core.optim import polyak_update
from algorithms.goal_conditioned import AuxCritic
from algorithms.risc import (
    RISC,
    RISCConfig,
    RISCNoTAB,
    RISCNoTABConfig,
    success_squash,
    success_target,
    switch_probability,
)
from algorithms.vaprl import VaPRL, VaPRLConfig, VaPRLRISC, VaPRLRISCConfig
from algorithms.vaprl_curriculum import (
    LagrangeMultiplier,
    choose_subgoal,
    demo_prefix_relabel,
    demo_time_index,
    final_state_relabel,
    goal_test,
    lagrangian_subgoal,
    subgoal_candidates,
    value_ceiling,
)
from harness.data import Demos, load_demos
from harness.envs import get_spec
from tests.stepping import take_step

from .conftest import requires_data

pytestmark = requires_data
ENV = "tabletop_manipulation"



_DEMOS = {}


def _demos(env=ENV):
    if env not in _DEMOS:
        _DEMOS[env] = DemoSet(load_demos(env, "forward"), load_demos(env, "reverse"))
    return _DEMOS[env]


def _make(cls, cfg_cls, seeds=(0,), env=ENV, **kw):
    cfg = cfg_cls(**{**dict(seed_steps=50, batch_size=16, buffer_capacity=100_000), **kw})
    return cls(get_spec(env), _demos(env), cfg, list(seeds), torch.device("cpu"))


def _run(algo, env, seeds, steps):
    """Protocol steps through harness.protocol.Interaction; the actions taken (steps, E, A)."""
    from harness.protocol import Interaction

    loop = Interaction(env, list(seeds))
    loop.start(algo)
    return np.stack([(loop.step(algo), algo._action.copy())[1] for _ in range(steps)])


# -- RISC ------------------------------------------------------------------------------------------------
def test_switch_probability_function():
    t = np.arange(1, 301)
    p = switch_probability(np.full(300, 0.8), t, 0.9, 100)
    assert (p[t < 100] == 0).all()
    np.testing.assert_allclose(p[t >= 100], 0.8 * (1 - 0.9 ** t[t >= 100]))


@pytest.mark.parametrize("proportion", [1.0, 0.5])
def test_switch_frequency_matches_rule(monkeypatch, proportion):
    """Counted over many draws: 0 before minimum_steps, proportion * P * (1 - c^t) after (per-step redraw)."""
    r = _make(RISC, RISCConfig, minimum_steps=3, conservative_factor=0.5, trajectory_proportion=proportion)
    monkeypatch.setattr(r, "success_probability", lambda obs, mask=None: torch.full((r.E,), 0.6))
    obs = torch.zeros(1, r.task.obs_dim)
    for steps_done, expected in ((1, 0.0), (2, proportion * 0.6 * (1 - 0.5**3)), (4, proportion * 0.6 * (1 - 0.5**5))):
        r.phase_steps[:] = steps_done  # t = steps_done + 1
        n = 4000
        freq = np.mean([r.early_switch(to_host(r.switch_request(obs))[0])[0] for _ in range(n)])
        assert abs(freq - expected) < 4 * np.sqrt(max(expected * (1 - expected), 1e-9) / n) + 1e-9


def test_success_critic_target_and_update(monkeypatch):
    gamma = 0.99
    term = torch.tensor([[True, False, False]])
    heads = torch.tensor([[[0.2, 0.5, 0.9], [0.3, 0.4, 1.0]]])
    torch.testing.assert_close(success_target(term, heads, gamma), torch.tensor([[1.0, gamma * 0.4, gamma * 0.9]]))
    # the success critic's update uses exactly that target, truncated or not
    r = _make(RISC, RISCConfig)
    seen = {}
    orig = r.success.update

    def spy(actor, batch, target_fn, mask=None):
        nxt = torch.rand(1, 2, batch["obs"].shape[1])
        seen["y"], seen["want"] = target_fn(nxt), success_target(batch["terminal"], nxt, gamma)
        return orig(actor, batch, target_fn, mask)

    monkeypatch.setattr(r.success, "update", spy)
    batch = r.buffer.sample(64)
    r.update_aux(batch)
    torch.testing.assert_close(seen["y"], seen["want"])
    p = r.success_probability(torch.as_tensor(r.buffer.data["obs"][:, :1]).reshape(1, -1))
    assert p.shape == (1,) and 0.0 <= float(p[0]) <= 1.0


def test_risc_vs_no_tab_differ_only_in_bootstrap_mask():
    a, b = _make(RISC, RISCConfig), _make(RISCNoTAB, RISCNoTABConfig)
    da, db = vars(a.cfg), vars(b.cfg)
    assert {k for k in da if da[k] != db[k]} == {"bootstrap_on_truncation"}
    assert a.cfg.bootstrap_on_truncation and not b.cfg.bootstrap_on_truncation
    term = torch.tensor([[True, False, False, True]])
    trunc = torch.tensor([[False, True, False, False]])
    assert a.sac.bootstrap_mask(term, trunc).tolist() == [[0.0, 1.0, 1.0, 0.0]]
    assert b.sac.bootstrap_mask(term, trunc).tolist() == [[0.0, 0.0, 1.0, 0.0]]
    # same seed, same networks and batch: TD targets agree except on truncated transitions
    batch = a.buffer.sample(256)
    batch["truncated"] = torch.arange(256)[None] % 3 == 0
    eps = torch.randn(1, 256, a.task.act_dim)
    ya, yb = a.sac.td_target(batch, batch["reward"], eps), b.sac.td_target(batch, batch["reward"], eps)
    same = ~batch["truncated"] | batch["terminal"]
    assert torch.equal(ya[same], yb[same]) and not torch.equal(ya, yb)


def test_risc_phases_goals_and_flags():
    spec = get_spec(ENV)
    r = _make(RISC, RISCConfig, phase_step_limit=5, minimum_steps=10**6, seed_steps=10**6)
    far = np.concatenate([[1.0, 1.0, 1.0, 1.0, -1, -1], spec.goal_states[0]]).astype(np.float32)[None]
    r.on_reset(far, np.ones(1, bool))
    assert r.direction[0] == FORWARD and any(np.allclose(r.goal[0], g) for g in spec.goal_states)
    n0 = r.buffer.size[0]
    for _ in range(5):
        take_step(r, far, far, np.zeros(1, bool))
    assert r.direction[0] == BACKWARD and np.allclose(r.goal[0], spec.initial_states[0])
    d = r.buffer.data
    assert d["truncated"][0, n0 + 4] and not d["terminal"][0, n0 + 4]  # phase limit: truncated, not terminal
    assert d["first"][0, n0 + 5]  # the backward phase is a new segment
    # reaching the backward goal: terminal, flip to forward
    home = np.concatenate([spec.initial_states[0], spec.goal_states[0]]).astype(np.float32)[None]
    take_step(r, far, home, np.zeros(1, bool))
    assert d["terminal"][0, n0 + 6] and d["reward"][0, n0 + 6] == 1.0 and r.direction[0] == FORWARD


def test_warmup_actions_are_uniform():
    r = _make(RISC, RISCConfig, seed_steps=10**6)
    o = np.zeros((1, r.task.obs_dim), np.float32)
    r.on_reset(o, np.ones(1, bool))
    a = np.stack([r.act(o)[0] for _ in range(300)])
    assert a.min() < -0.9 and a.max() > 0.9 and abs(a.mean()) < 0.1


# -- VaPRL ------------------------------------------------------------------------------------------------
def test_choose_subgoal_rule():
    values = np.array([9.0, 2.0, 6.0, 7.0, 1.0])
    distance = np.array([50, 0, 10, 5, 1])
    assert choose_subgoal(values, distance, 5.0) == 3  # feasible {0, 2, 3}: nearest to rho0
    assert choose_subgoal(values, distance, 8.0) == 0
    assert choose_subgoal(values, distance, 9.5) == 0  # none feasible: largest value
    allowed = np.array([True, True, True, False, True])  # exclude_solved: candidate 3 meets the goal already
    assert choose_subgoal(values, distance, 5.0, allowed) == 2
    assert choose_subgoal(values, distance, 9.5, ~np.eye(5, dtype=bool)[0]) == 3  # the largest allowed value


def test_candidates_and_time_index():
    pos, length = demo_time_index(np.array([0, 0, 1, 0, 1], bool))
    assert pos.tolist() == [0, 1, 2, 0, 1] and length.tolist() == [3, 3, 3, 2, 2]
    d = _demos()
    states, dist = subgoal_candidates(d.forward, d.reverse, 6)
    nf = len(d.forward.actions)
    assert states.shape == (nf + len(d.reverse.actions), 6)
    np.testing.assert_array_equal(states[:nf], d.forward.observations[:, :6])
    assert dist[0] == 0 and dist[1] == 1  # forward: steps since the demo start
    ends = np.flatnonzero(d.reverse.terminals)
    assert (dist[nf + ends] == 1).all()  # backward: steps left to the demo end, clean at every demo
    assert dist[nf] == ends[0] + 1


def test_vaprl_risc_subgoal_from_value_table(monkeypatch):
    v = _make(VaPRLRISC, VaPRLRISCConfig, kappa=0.5)
    N = len(v.candidates)
    table = np.zeros((1, N))
    monkeypatch.setattr(v, "candidate_values", lambda cands, mask: table)
    v.on_reset(np.zeros((1, v.task.obs_dim), np.float32), np.ones(1, bool))
    v.direction[:] = BACKWARD
    table[0, [30, 700, 1500]] = [6.0, 5.0, 9.0]  # eps = 5: feasible {30, 700, 1500}
    g = v.phase_goals(np.ones(1, bool))[0]
    want = min((30, 700, 1500), key=lambda i: (v.time_distance[i], i))
    np.testing.assert_array_equal(g, v.candidates[want])
    table[:] = 0.0
    table[0, 42] = 4.9  # nothing reaches eps: the largest value
    np.testing.assert_array_equal(v.phase_goals(np.ones(1, bool))[0], v.candidates[42])
    # the real value function: shape and finiteness
    monkeypatch.undo()
    vals = v.candidate_values(v.current_candidates(np.ones(1, bool))[0], np.ones(1, bool))
    assert vals.shape == (1, N) and np.isfinite(vals).all()


@pytest.mark.parametrize("tab", [True, False])
def test_vaprl_risc_relabelled_rewards_match_env_predicate(tab):
    """4 copies per transition: reward = terminal = the env predicate for the new goal; truncated only where the
    phase ended, so without timeout-aware bootstrapping (vaprl_risc_no_tab) a copy of a mid-phase transition still
    bootstraps and only the phase's last one stops."""
    v = _make(VaPRLRISC, VaPRLRISCConfig, seed_steps=10**6, phase_step_limit=40, bootstrap_on_truncation=tab)
    spec = v.task
    n0 = v.buffer.size[0]
    _run(v, ENV, (0,), 40)  # exactly one phase
    r = v.buffer.data
    k = slice(n0 + 41, n0 + 41 + 2 * 4 * 40)  # after the phase's 41 steps: the relabelled segments
    first = r["first"][0, k].numpy()
    assert first[::2].all() and not first[1::2].any()
    assert int(v.buffer.size[0]) == n0 + 41 + 2 * 4 * 40 + 1  # + the next phase's FIRST step
    next_obs = r["obs"][0, k][1::2].numpy()
    obs = r["obs"][0, k][0::2].numpy()
    ok = spec.is_success(next_obs)
    np.testing.assert_array_equal(r["reward"][0, k][1::2].numpy(), ok.astype(np.float32))
    np.testing.assert_array_equal(r["terminal"][0, k][1::2].numpy(), ok)
    last = np.repeat(np.arange(40), 4) == 39  # copies of the phase's last transition (its time limit)
    np.testing.assert_array_equal(r["truncated"][0, k][1::2].numpy(), ~ok & last)
    m = v.sac.bootstrap_mask(r["terminal"][:1, k][:, 1::2], r["truncated"][:1, k][:, 1::2])[0].numpy()
    np.testing.assert_array_equal(m, ~ok if tab else ~ok & ~last)
    np.testing.assert_array_equal(obs[:, 6:], next_obs[:, 6:])  # same goal on both sides
    assert ok.any()  # future goals include the own next state
    demo_goal = (next_obs[:, None, 6:] == v.candidates[None]).all(-1).any(-1)
    assert 0.3 < demo_goal.mean() < 0.7


def test_final_state_relabel_cuts_at_first_success():
    """One hindsight copy with goal = the phase's final state, ending at the first transition within the task's
    success radius of it (the original relabel_function), terminal only there."""
    spec = get_spec(ENV)
    s = np.zeros((6, 6), np.float32)
    s[:, 0] = [0.0, 1.0, 2.0, 2.9, 3.05, 3.1]  # gripper x
    s2 = np.vstack([s[1:], [[3.2, 0, 0, 0, 0, 0]]]).astype(np.float32)  # s' of the last row: 3.2
    a = np.arange(18, dtype=np.float32).reshape(6, 3)
    copy = final_state_relabel(np.concatenate([s, a, s2], axis=1), 6, 3, spec.is_success)
    # next states x: 1, 2, 2.9, 3.05, 3.1, 3.2; goal x 3.2: the first within 0.2 is 3.05 (the 4th transition)
    assert len(copy["terminals"]) == 4
    np.testing.assert_array_equal(copy["terminals"], [False, False, False, True])
    np.testing.assert_array_equal(copy["rewards"], [0, 0, 0, 1])
    np.testing.assert_array_equal(copy["observations"][:, 6:], np.broadcast_to(s2[-1], (4, 6)))
    np.testing.assert_array_equal(copy["next_observations"][:, :6], s2[:4])
    np.testing.assert_array_equal(copy["actions"], a[:4])


def test_demo_prefix_relabel_is_the_original_data_multiplier():
    """relabel_demos (the original relabel_offline_data): per demo of length L, L copies; copy j has goal s_j (the
    state the demo reaches after j transitions), the demo's own first transitions, and ends terminal with reward 1 at
    its first success for that goal."""
    spec = get_spec(ENV)
    x = np.array([0.0, 1.0, 1.1, 2.0, 5.0, 5.05], np.float32)  # gripper x of s_0..s_3 (demo A), s_0..s_1 (demo B)
    obs = np.zeros((4, 12), np.float32)
    obs[:, 0] = [x[0], x[1], x[2], x[4]]
    nxt = np.zeros((4, 12), np.float32)
    nxt[:, 0] = [x[1], x[2], x[3], x[5]]
    act = np.arange(12, dtype=np.float32).reshape(4, 3)
    demos = Demos(env=ENV, direction="forward", observations=obs, actions=act, rewards=np.zeros(4, np.float32), next_observations=nxt,
                  terminals=np.array([False, False, True, True]))
    c = demo_prefix_relabel(demos, 6, 3, spec.is_success)
    # demo A (s: 0, 1, 1.1, 2): goal 1 -> [0->1]; goal 1.1 -> [0->1] already within 0.2; goal 2 -> all three.
    # demo B (s: 5, 5.05): goal 5.05 -> [5->5.05]
    np.testing.assert_allclose(c["observations"][:, 6], [1.0, 1.1, 2.0, 2.0, 2.0, 5.05])
    np.testing.assert_allclose(c["observations"][:, 0], [0.0, 0.0, 0.0, 1.0, 1.1, 5.0])
    np.testing.assert_allclose(c["next_observations"][:, 0], [1.0, 1.0, 1.0, 1.1, 2.0, 5.05])
    np.testing.assert_array_equal(c["terminals"], [True, True, False, False, True, True])
    np.testing.assert_array_equal(c["rewards"], c["terminals"].astype(np.float32))
    np.testing.assert_array_equal(c["actions"], act[[0, 0, 0, 1, 2, 3]])
    # in the agent: the copies join the demos in every member's buffer, before any step
    plain = _make(VaPRL, VaPRLConfig, seeds=(0, 1))
    relabelled = _make(VaPRL, VaPRLConfig, seeds=(0, 1), relabel_demos=True, buffer_capacity=400_000)
    d = _demos()
    extra = sum(len(demo_prefix_relabel(x, 6, 3, spec.is_success)["terminals"]) for x in (d.forward, d.reverse))
    assert extra > 100_000  # ~L^2 / 2 per demo: 134k transitions for tabletop's 24 demos
    np.testing.assert_array_equal(relabelled.buffer.num_transitions, plain.buffer.num_transitions + extra)


def test_value_threshold_is_in_the_critics_units():
    """vaprl: success ends the phase, so V is at most one scaled reward (10) and the threshold is 5. With
    success_ends_phase=false the phases run to their limit and earn reward at every step at the goal, so V reaches
    reward_scale (1 - gamma^H) / (1 - gamma) (866 for H = 200); a unit of 10 there would put the threshold below every
    value the critic gives demo states and the curriculum would never leave rho0."""
    vaprl = _make(VaPRL, VaPRLConfig)
    assert vaprl.cfg.success_ends_phase and value_ceiling(vaprl.cfg) == 10.0 and vaprl.threshold == 5.0
    fixed = _make(VaPRL, VaPRLConfig, success_ends_phase=False)
    np.testing.assert_allclose(value_ceiling(fixed.cfg), 10 * (1 - 0.99**200) / 0.01)
    np.testing.assert_allclose(fixed.threshold, 0.5 * 10 * (1 - 0.99**200) / 0.01)
    assert 430 < fixed.threshold < 435
    door = VaPRLConfig(phase_step_limit=300, success_ends_phase=False)
    np.testing.assert_allclose(value_ceiling(door), 10 * (1 - 0.99**300) / 0.01)
    assert value_ceiling(VaPRLRISCConfig()) == 10.0 and value_ceiling(VaPRLConfig(phase_step_limit=300)) == 10.0
    assert value_ceiling(VaPRLConfig(v_max=42.0)) == 42.0  # an explicit unit wins
    endless = VaPRLConfig(bootstrap_on_truncation=True, success_ends_phase=False)  # rewards through phase ends
    np.testing.assert_allclose(value_ceiling(endless), 1000.0)


def test_lagrangian_rule_and_multiplier():
    values, dist = np.array([1.0, 5.0, 9.0]), np.array([0.0, 2.0, 4.0])
    assert lagrangian_subgoal(values, dist, 0.0) == 0  # lambda 0: the candidate nearest rho0
    assert lagrangian_subgoal(values, dist, 0.6) == 2  # 0-0.6, 2-3, 4-5.4: the valued one wins
    assert lagrangian_subgoal(values, dist, 0.6, np.array([True, True, False])) == 1  # 2 excluded: 2-3 < 0-0.6
    lam = LagrangeMultiplier(2, lr=0.01, upper=0.05)
    for _ in range(10):
        lam.record(0, 1.0)  # below the threshold 5: lambda grows, by ~lr per step (Adam), up to the clip
        lam.record(1, 9.0)  # above: lambda stays at its floor 0
        lam.step(threshold=5.0)
    np.testing.assert_allclose(lam.value, [0.05, 0.0])
    lam2 = LagrangeMultiplier(1, lr=0.01, upper=math.inf)
    lam2.record(0, 1.0)
    lam2.step(5.0)
    np.testing.assert_allclose(lam2.value, [0.01], rtol=1e-6)
    lam2.step(5.0)  # nothing recorded since: no step
    assert lam2.t[0] == 1


def test_vaprl_uses_the_original_codes_behaviour():
    """vaprl: no trunk, phase ends never bootstrapped, success ends a phase (use_reset_goals 3); with
    success_ends_phase=false (the code's ResetFreeWrapper) phases run to their limit; a final-state hindsight copy per
    phase, subgoals by the Lagrangian rule with V = min(V(s_now -> c), V(c -> g*)) from the SAC critic."""
    assert VaPRLConfig().success_ends_phase and not VaPRLConfig().bootstrap_on_truncation
    v = _make(VaPRL, VaPRLConfig, seed_steps=10**6, phase_step_limit=25, success_ends_phase=False)
    assert isinstance(v.sac.actor.trunk, torch.nn.Identity) and v.value is None
    m = v.sac.bootstrap_mask(torch.tensor([[False, False, True]]), torch.tensor([[False, True, False]]))
    np.testing.assert_array_equal(m.numpy(), [[1.0, 0.0, 0.0]])
    n0 = int(v.buffer.size[0])
    _run(v, ENV, (0,), 100)  # 4 phases of 25 steps
    d = {k: x[0, n0:int(v.buffer.size[0])].numpy() for k, x in v.buffer.data.items()}
    starts = np.flatnonzero(d["first"])
    ends = np.append(starts[1:], len(d["first"]))
    segs = [slice(a + 1, b) for a, b in zip(starts, ends)]
    copies = [g for g in segs if d["terminal"][g].any()]
    online = [g for g in segs if not d["terminal"][g].any() and g.stop > g.start]
    assert len(online) == 4 and len(copies) == 4  # 4 phases and one hindsight copy of each
    for g in online:  # exactly the limit, closed by truncation, no terminal inside although successes may occur
        assert g.stop - g.start == 25 and d["truncated"][g][-1] and not d["truncated"][g][:-1].any()
    for g in copies:  # each copy ends with its first success on its own goal (the phase's final state)
        assert d["terminal"][g][-1] and not d["terminal"][g][:-1].any() and d["reward"][g][-1] == 1.0
        assert get_spec(ENV).is_success(d["obs"][g][-1:])[0]
    # the curriculum: lambda 0 picks the candidate nearest rho0; use_minimum takes the smaller value
    seen = []
    v._values = lambda obs, mask: (seen.append(obs.copy()), np.full(obs.shape[:2], float(len(seen))))[1]
    vals = v.candidate_values(v.current_candidates(np.ones(1, bool))[0], np.ones(1, bool))
    np.testing.assert_array_equal(vals, 1.0)  # min(1, 2)
    np.testing.assert_array_equal(seen[1][0, :, 6:], v.candidates)  # second pass: goal = candidate
    np.testing.assert_array_equal(seen[1][0, :, :6], np.broadcast_to(v.phase_obs[0, :6], v.candidates.shape))
    v.direction[:] = BACKWARD
    g = v.phase_goals(np.ones(1, bool))[0]
    np.testing.assert_array_equal(g, v.candidates[np.argmin(v.l2_distance)])


def test_phase_any_success_diagnostic():
    """phase/*_any_success: the share of phases that reached their goal at some step; with phases that success does
    not end (success_ends_phase=false) a phase that touches its goal and leaves counts there, not in *_end_success."""
    v = _make(VaPRL, VaPRLConfig, seeds=(0, 1), seed_steps=10**6, phase_step_limit=10, success_ends_phase=False)

    class Scripted:  # the task, but the per-step success check (both members' rows) hits member 0 at steps 3 and 15
        def __init__(self, task):
            self.task, self.calls = task, 0

        def __getattr__(self, name):
            return getattr(self.task, name)

        def is_success(self, obs):
            if len(obs) != 2:  # relabelling checks whole phases
                return self.task.is_success(obs)
            self.calls += 1
            return np.array([self.calls - 1 in (3, 15), False])  # forward phase 0-9, backward phase 10-19

    v.task = Scripted(v.task)
    _run(v, ENV, (0, 1), 40)
    m = v.metrics()
    np.testing.assert_allclose(m["phase/forward_any_success"], [0.5, 0.0])  # 2 forward phases each, one hit
    np.testing.assert_allclose(m["phase/backward_any_success"], [0.5, 0.0])
    np.testing.assert_allclose(m["phase/forward_end_success"], [0.0, 0.0])
    assert not v.phase_hit.any()


def test_phase_start_diagnostics_flag_phases_that_begin_at_their_goal():
    """phase/*_starts_at_goal and *_start_distance: a backward subgoal equal to the state the phase starts in (as
    `vaprl` on sawyer_door picked, a subgoal its backward phases reach without moving) counts as starting at its goal
    with distance 0; forward phases from rho0 start at the rho0-to-goal distance on the success coordinates."""
    v = _make(VaPRL, VaPRLConfig, seeds=(0, 1), seed_steps=10**6, phase_step_limit=10)
    goals = v.phase_goals

    def here_if_backward(mask):  # member 0's subgoal: where it stands; member 1 keeps the curriculum's
        out = goals(mask)
        if mask[0] and v.direction[0] != FORWARD:
            out[0] = v.phase_obs[0, : v.task.state_dim]
        return out

    v.phase_goals = here_if_backward
    _run(v, ENV, (0, 1), 9)  # the first forward phase only: from rho0
    m = v.metrics()
    spec = get_spec(ENV)
    rho0_gap = np.linalg.norm((spec.initial_states[0] - spec.goal_states[0])[list(spec.success_idx)])
    assert m["phase/forward_starts_at_goal"].tolist() == [0.0, 0.0]
    assert 0.5 * rho0_gap < m["phase/forward_start_distance"][0] <= 2 * rho0_gap
    assert np.isnan(m["phase/backward_starts_at_goal"]).all()  # no backward phase yet (the protocol drops NaN)
    # ... and from rho0 on the whole state: the distance to the nearest initial state, as close as the reset lands
    gap = np.linalg.norm(v.phase_obs[:, None, : spec.state_dim] - spec.initial_states, axis=-1).min(axis=1)
    np.testing.assert_allclose(m["phase/forward_start_rho0_distance"], gap)
    assert (gap < 0.1).all() and (gap < 0.5 * rho0_gap).all()
    _run(v, ENV, (0, 1), 40)
    m = v.metrics()
    assert m["phase/backward_starts_at_goal"][0] == 1.0 and m["phase/backward_start_distance"][0] == 0.0
    assert m["phase/backward_start_distance"][1] > 0.0


def test_vaprl_exclude_solved_never_picks_a_subgoal_that_already_meets_the_goal():
    """exclude_solved on sawyer_door: with values that make the shut-door candidates (handle within 0.02 of g*'s) the
    Lagrangian rule's pick, as in the 500k door run, the option picks a candidate with the door open instead."""
    picks = {}
    for exclude in (False, True):
        v = _make(VaPRL, VaPRLConfig, seeds=(0,), env="sawyer_door", exclude_solved=exclude)
        v.task_goal[0] = get_spec("sawyer_door").goal_states[0]
        solved = v.solved(v.candidates[None])[0]
        assert 0 < solved.sum() < len(solved)  # the demos hold shut-door states and others
        v.candidate_values = lambda cands, mask, s=solved: np.where(s, 10.0, 0.0)[None]
        v.lagrange.value[0] = 1.0  # value outweighs distance (< 1.5 between any two candidates)
        v.direction[0] = BACKWARD
        picks[exclude] = v.phase_goals(np.ones(1, bool))[0]
        assert v.solved(picks[exclude][None, None])[0, 0] == (not exclude)


def test_vaprl_goal_test_judges_goals_on_other_coordinates_and_rejudges_the_demos():
    """goal_coords/goal_threshold (VaPRL's own door test: hand and handle, L2 <= 0.2): the agent's rewards, phase ends
    and demos follow it; the env's spec (EARL's handle test at 0.02) is untouched; bad coordinates get one clear line."""
    spec = get_spec("sawyer_door")
    assert goal_test(spec, VaPRLConfig()) is spec  # the default: EARL's test
    test = goal_test(spec, VaPRLConfig(goal_coords="0,1,2,4,5,6", goal_threshold=0.2))
    assert test.success_idx == (0, 1, 2, 4, 5, 6) and test.success_threshold == 0.2
    assert spec.success_idx == (4, 5, 6) and spec.success_threshold == 0.02
    obs = np.zeros((3, 14), np.float32)
    obs[1, 4] = 0.05  # handle 0.05 from the goal's: fails EARL's test, passes VaPRL's
    obs[2, 0] = 0.5  # hand 0.5 from the goal's, handle at it: passes EARL's, fails VaPRL's
    np.testing.assert_array_equal(spec.is_success(obs), [True, False, True])
    np.testing.assert_array_equal(test.is_success(obs), [True, True, False])
    for bad, match in (("0,1,x", "distinct non-negative integers"), ("1,1", "distinct"), ("0,7", "has 7 coordinates")):
        with pytest.raises(ValueError, match=match):
            goal_test(spec, VaPRLConfig(goal_coords=bad))
    demos = _demos("sawyer_door")
    v = _make(VaPRL, VaPRLConfig, env="sawyer_door", goal_coords="0,1,2,4,5,6", goal_threshold=0.2)
    assert v.task.success_idx == (0, 1, 2, 4, 5, 6)
    rows = v.demo_rows(demos)
    n_traj = sum(int(np.asarray(d.terminals).sum()) for d in (demos.forward, demos.reverse))
    assert len(rows) == n_traj  # one add_demo call per trajectory
    for r in rows:  # each ends at its first success under the agent's test (terminal, reward 1), or truncated
        ok = test.is_success(r["next_observations"])
        assert not ok[:-1].any() and r["terminals"][-1] == ok[-1] == bool(r["rewards"][-1])
        assert not r["terminals"][:-1].any()
    kept = sum(len(r["terminals"]) for r in rows)
    assert 0 < kept <= len(demos.forward.terminals) + len(demos.reverse.terminals)
    assert v.buffer.size[0] == kept + len(rows)  # each segment: its FIRST step and its transitions
    default = _make(VaPRL, VaPRLConfig, env="sawyer_door")
    assert default.task is spec  # EARL's test: the spec itself, demos as given


def test_vaprl_task_goal_keeps_its_test_while_other_goals_take_the_agents():
    """task_goal_test=task: subgoals and relabelled goals are judged on hand and handle (0.02), g* by EARL's handle
    test alone (EARL's door goal puts the hand at the handle's coordinates, where no demo's hand can be)."""
    spec = get_spec("sawyer_door")
    cfg = dict(goal_coords="0,1,2,4,5,6", goal_threshold=0.02, task_goal_test="task")
    test = goal_test(spec, VaPRLConfig(**cfg))
    assert test.state_dim == 7 and test.obs_dim == 14 and test.goal_states is spec.goal_states
    g_star, other = spec.goal_states[0].astype(np.float32), np.full(7, 0.3, np.float32)
    obs = np.zeros((4, 14), np.float32)
    obs[:2, 7:], obs[2:, 7:] = g_star, other
    obs[:, :7] = obs[:, 7:]
    obs[[0, 2], 0] += 0.5  # hand 0.5 off, handle at its goal
    obs[[1, 3], 4] += 0.05  # handle 0.05 off, hand at its goal
    np.testing.assert_array_equal(test.is_task_goal(obs), [True, True, False, False])
    # g*: EARL's test (hand free, handle within 0.02); another goal: hand and handle within 0.02
    np.testing.assert_array_equal(test.is_success(obs), [True, False, False, False])
    np.testing.assert_allclose(test.goal_distance(obs), [0.0, 2.5, 25.0, 2.5], rtol=1e-5)  # in threshold units
    np.testing.assert_array_equal(test.compute_reward(obs), [1.0, 0.0, 0.0, 0.0])
    assert goal_test(spec, VaPRLConfig(goal_coords="0,1,2,4,5,6", goal_threshold=0.02)).success_idx == (0, 1, 2, 4, 5, 6)
    with pytest.raises(ValueError, match="task_goal_test=.both. is not allowed"):
        VaPRLConfig(task_goal_test="both").validate()
    v = _make(VaPRL, VaPRLConfig, env="sawyer_door", **cfg)
    demos = _demos("sawyer_door")
    rows = v.demo_rows(demos)
    is_forward = [bool(test.is_task_goal(r["observations"][:1])[0]) for r in rows]
    forward = [r for r, f in zip(rows, is_forward) if f]
    assert len(forward) == int(np.asarray(demos.forward.terminals).sum())  # forward demos: as EARL judges them
    assert sum(len(r["terminals"]) for r in forward) == len(demos.forward.terminals)
    assert all(r["terminals"][-1] and r["rewards"][-1] == 1 for r in forward)
    # reverse demos (goal rho0): they stop once the handle is back, the hand 0.11 from rho0's: never a success
    assert all(not r["terminals"].any() for r, f in zip(rows, is_forward) if not f)
    v.task_goal[0] = g_star  # the solved test of candidates stays EARL's: shut-door demo states meet it
    assert v.solved(v.candidates[None]).any()


def test_vaprl_replay_candidates_are_states_from_each_members_buffer_drawn_once_per_period():
    """candidates=replay (the original code's num_reset_candidates): every phase_step_limit steps (the original's
    reset_goal_frequency) each member draws states from its own replay buffer, and the subgoal choices of the period
    share that draw; the Lagrangian rule then runs on their L2 distance to mean(rho0). The draw is checkpointed."""
    from harness.protocol import Interaction

    v = _make(VaPRL, VaPRLConfig, seeds=(0, 1), candidates="replay", num_candidates=64, seed_steps=10**6,
              phase_step_limit=20)
    loop = Interaction(ENV, [0, 1])
    loop.start(v)
    for _ in range(45):  # a forward and a backward phase: visited states join the demos in the buffers
        loop.step(v)
    sd, mask = v.task.state_dim, np.ones(2, bool)
    first, l2, time = v.current_candidates(mask)
    assert first.shape == (2, 64, sd) and np.isnan(time).all()
    for i in range(2):  # every candidate is a state member i stored
        stored = v.buffer.data["obs"][i, : v.buffer.size[i], :sd].numpy()
        assert all((np.abs(stored - c).max(axis=1) == 0).any() for c in first[i])
    np.testing.assert_allclose(l2, np.linalg.norm(first - v.rho0, axis=2), rtol=1e-6)
    for _ in range(14):  # to step 59: the same period, the same candidates
        loop.step(v)
    np.testing.assert_array_equal(v.current_candidates(mask)[0], first)
    v.direction[:] = BACKWARD
    v._values = lambda obs, mask: np.zeros(obs.shape[:2])  # lambda 0 and equal values: the state nearest rho0
    goals = v.phase_goals(mask)
    for i in range(2):
        assert (np.abs(first[i] - goals[i]).max(axis=1) == 0).any()  # chosen from the period's draw
    clone = _make(VaPRL, VaPRLConfig, seeds=(0, 1), candidates="replay", num_candidates=64, seed_steps=10**6,
                  phase_step_limit=20)
    clone.load_state_dict(v.state_dict())
    np.testing.assert_array_equal(clone.replay_candidates, first)
    before = v.buffer.generators[0].get_state()
    loop.step(v)  # step 60: a new period draws afresh, from the member's sampling stream
    assert not torch.equal(before, v.buffer.generators[0].get_state())
    assert not np.array_equal(v.current_candidates(mask)[0], first)
    with pytest.raises(ValueError, match="candidates=replay needs curriculum=lagrangian"):
        VaPRLConfig(candidates="replay", curriculum="nearest_feasible").validate()


def test_vaprl_config_rejects_unknown_choices():
    from harness.planning import plan_words
    from harness.suites import ConfigError

    with pytest.raises(ConfigError, match="relabel=.banana. is not allowed: must be one of final, final_failed, future_demo, none"):
        plan_words(["algo=vaprl", f"env={ENV}", "vaprl.relabel=banana", "results=/nonexistent/x"])


# -- both ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["risc", "vaprl", "vaprl_risc"])
def test_members_are_independent(which):
    """E = 2 gives each member what an E = 1 run with its seed gives: bitwise during the warm-up (host-drawn
    uniform actions), to float rounding afterwards (the core's batched forward differs from E = 1 by ~1 ulp)."""
    if which == "risc":
        mk = lambda seeds: _make(RISC, RISCConfig, seeds, phase_step_limit=40, minimum_steps=5, seed_steps=60)
    elif which == "vaprl":
        mk = lambda seeds: _make(VaPRL, VaPRLConfig, seeds, phase_step_limit=30, seed_steps=60)
    else:
        mk = lambda seeds: _make(VaPRLRISC, VaPRLRISCConfig, seeds, phase_step_limit=30, seed_steps=60)
    seeds, steps = (3, 8), 200
    batched = mk(seeds)
    acts = _run(batched, ENV, seeds, steps)
    for i, s in enumerate(seeds):
        single = mk((s,))
        a1 = _run(single, ENV, (s,), steps)
        np.testing.assert_array_equal(acts[:60, i], a1[:60, 0])
        np.testing.assert_allclose(acts[:, i], a1[:, 0], atol=1e-5, rtol=0)
        for pb, p1 in zip(batched.sac.actor.parameters(), single.sac.actor.parameters()):
            torch.testing.assert_close(pb.view(2, -1)[i], p1.view(-1), atol=1e-5, rtol=0)
    if which == "risc":
        assert batched.switches.sum() > 0


@pytest.mark.parametrize("squash", [None, success_squash])
def test_aux_critic_update_matches_autograd(squash):
    """AuxCritic.update (hand-written network backward, autograd only through the squash) equals the plain autograd
    step on 0.5 * sum_j MSE(squash(head_j(o, a)), y), over 10 masked updates."""
    cfg = SACConfig(hidden_dim=16, feature_dim=8)
    seeds, B, O, A = [1, 2], 12, 5, 2
    ours, ref = (AuxCritic(O, A, seeds, cfg, "cpu", Stream.SUCCESS_CRITIC, squash) for _ in range(2))
    actor = SAC(O, A, seeds, cfg).actor
    g = torch.Generator().manual_seed(0)
    target_fn = lambda nxt: 0.3 + 0.5 * nxt.min(dim=1).values  # noqa: E731
    for n in range(10):
        batch = {"obs": torch.randn(2, B, O, generator=g), "action": torch.rand(2, B, A, generator=g) * 2 - 1,
                 "next_obs": torch.randn(2, B, O, generator=g)}
        mask = np.array([True, n % 3 != 0])
        ours.update(actor, batch, target_fn, mask)
        with torch.no_grad():
            eps = member_randn(ref.update_gens, (B, A), mask, "cpu")
            y = target_fn(ref.heads(batch["next_obs"], actor.sample(batch["next_obs"], eps)[0], target=True))
        loss = 0.5 * (ref.heads(batch["obs"], batch["action"]) - y.unsqueeze(1)).square().mean(dim=2).sum(dim=1)
        ref.opt.step(mask, torch.autograd.grad(loss.sum(), ref.opt.params))
        polyak_update(ref.target_flat, ref.opt.members, ref.tau, mask)
    for a, b in zip(list(ours.net.parameters()) + list(ours.target.parameters()),
                    list(ref.net.parameters()) + list(ref.target.parameters())):
        torch.testing.assert_close(a, b, atol=2e-6, rtol=1e-5)


def _probe_script(name: str, tmp_path, env: str, steps: int = 100):
    """A tiny 2-member VaPRL run of ``steps`` on ``env`` (checkpoints every 100 steps, all kept) under ``tmp_path``,
    and ``scripts/<name>.py`` loaded as a module."""
    import importlib.util

    from harness.cli import main as harness_main

    assert harness_main(["run", "algo=vaprl", f"env={env}", f"steps={steps}", "keep_every=100", "eval_every=100",
                         "eval_episodes=1", "seeds=2", "members=2", "vaprl.seed_steps=50", "vaprl.phase_step_limit=20",
                         "checkpoint_every=100", f"results={tmp_path}"]) == 0
    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_vaprl_curriculum_probe_reads_a_run(tmp_path, capsys):
    """scripts/vaprl_curriculum_probe.py loads a real run's checkpoint and applies the Lagrangian rule: at lambda 0
    every pick is the candidate nearest rho0 (L2 0.0), one line per (task goal, seed) and rule; a directory without
    checkpoints is one error line and exit 2."""
    probe = _probe_script("vaprl_curriculum_probe", tmp_path, ENV)
    capsys.readouterr()
    assert probe.main([str(tmp_path / "adhoc" / ENV / "vaprl"), "lambdas=0,1e9"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("step 100;")
    goals = len(get_spec(ENV).goal_states)
    assert sum(line.startswith("g*") for line in lines) == goals * 2
    rules = [line.split() for line in lines if line.startswith("    ")]
    assert len(rules) == goals * 2 * 2 and all("0:" in r and r[r.index("0:") + 1].startswith("0.0/") for r in rules)
    assert probe.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: give a VaPRL cell directory")
    assert probe.main([str(tmp_path / "adhoc" / ENV / "vaprl"), "lambdas=1,x"]) == 2
    assert capsys.readouterr().err.startswith("error: lambdas must be comma-separated numbers")


def test_start_pose_probe_rolls_each_member_from_both_starts(tmp_path, capsys):
    """scripts/start_pose_probe.py loads a 2-member sawyer_door checkpoint and prints, per seed, success from rho0 and
    from the handle pose; a directory without checkpoints or a bad episode count is one error line and exit 2."""
    probe = _probe_script("start_pose_probe", tmp_path, "sawyer_door", steps=200)
    pose = probe.handle_pose("sawyer_door")  # hand near the handle, well below rho0's raised hand
    assert pose.shape == (4,) and pose[2] < 0.15
    capsys.readouterr()
    assert probe.main([str(tmp_path / "adhoc" / "sawyer_door" / "vaprl"), "episodes=1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(" at step")[0] for line in lines] == ["sawyer_door/vaprl seed 0", "sawyer_door/vaprl seed 1"]
    assert all("from rho0 0." in line and "from hand at handle 0." in line for line in lines)
    assert all(" at step 200," in line for line in lines)
    # a suite cell's run names the cell; run.yaml's algo_class names the algorithm to build
    run_yaml = tmp_path / "adhoc" / "sawyer_door" / "vaprl" / "seed=0" / "run.yaml"
    meta = yaml.safe_load(run_yaml.read_text())
    assert meta["algo_class"] == "vaprl"
    run_yaml.write_text(yaml.safe_dump({**meta, "algo": "vaprl_some_cell"}))
    assert probe.main([str(tmp_path / "adhoc" / "sawyer_door" / "vaprl"), "episodes=1", "step=100"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert all(line.startswith("sawyer_door/vaprl_some_cell seed") and " at step 100," in line for line in lines)
    # the wrapper keeps rho0's door angle and puts the hand at the pose
    from harness.envs import make_eval_env

    start, _ = make_eval_env("sawyer_door").reset(seed=3)
    held, _ = probe.HandAtHandle(make_eval_env("sawyer_door"), pose).reset(seed=3)
    np.testing.assert_allclose(held[4:7], start[4:7], atol=1e-3)
    np.testing.assert_allclose(held[0:3], pose[0:3], atol=1e-3)
    assert probe.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: give a cell directory")
    assert probe.main([str(tmp_path / "adhoc" / "sawyer_door" / "vaprl"), "episodes=x"]) == 2
    assert capsys.readouterr().err.startswith("error: episodes and step must be")
    assert probe.main([str(tmp_path / "adhoc" / "sawyer_door" / "vaprl"), "step=300"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: give a cell directory with checkpoints/seeds=*/checkpoint-300.pt")
    assert err.rstrip().endswith("it keeps checkpoint-100.pt, checkpoint-200.pt)")
