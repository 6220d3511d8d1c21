"""SAC math on small hand-checkable cases (docs/algorithms.md §3.2)."""

import math

import pytest
import torch
from torch.distributions import Normal, TransformedDistribution
from torch.distributions.transforms import TanhTransform

from algorithms.core import SAC, SACConfig, squashed_gaussian_log_prob
from algorithms.core.nets import Stream, member_generators

OBS, ACT = 5, 2
SMALL = SACConfig(hidden_dim=16, feature_dim=8)


def make_batch(E, B, seed=0, terminal=None, truncated=None):
    g = torch.Generator().manual_seed(seed)
    return {
        "obs": torch.randn(E, B, OBS, generator=g),
        "action": torch.rand(E, B, ACT, generator=g) * 2 - 1,
        "reward": torch.rand(E, B, generator=g),
        "next_obs": torch.randn(E, B, OBS, generator=g),
        "terminal": torch.zeros(E, B, dtype=torch.bool) if terminal is None else terminal,
        "truncated": torch.zeros(E, B, dtype=torch.bool) if truncated is None else truncated,
    }


@torch.no_grad()
def pin_outputs(sac, mean, log_std, q1, q2):
    """Zero the last layers so the actor outputs (mean, log_std) and the TARGET critic heads output q1, q2 everywhere."""
    last = sac.actor.mlp.layers[-1]
    last.weight.zero_()
    last.bias.copy_(torch.tensor(mean + log_std).view(1, 1, -1))
    head = sac.critic_target.heads.layers[-1]
    head.weight.zero_()
    head.bias.copy_(torch.tensor([q1, q2]).view(2, 1, 1))


def test_squashed_log_prob_matches_torch_distributions():
    mean = torch.tensor([[0.3, -0.5], [1.0, 0.0], [-0.2, 0.7]])
    log_std = torch.tensor([[-1.0, 0.2], [0.0, -0.5], [0.5, 0.1]])
    eps = torch.tensor([[0.1, -1.2], [0.5, 0.3], [-0.7, 0.9]])
    u = mean + log_std.exp() * eps
    ours = squashed_gaussian_log_prob(u, eps, log_std)
    ref = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()]).log_prob(torch.tanh(u)).sum(-1)
    torch.testing.assert_close(ours, ref, atol=1e-4, rtol=1e-5)


def test_td_target_hand_computed():
    sac = SAC(OBS, ACT, [0], SMALL)
    with torch.no_grad():
        sac.log_alpha.fill_(math.log(0.5))
    pin_outputs(sac, mean=[0.2, -0.1], log_std=[-1.0, 0.0], q1=3.0, q2=2.5)
    terminal = torch.tensor([[False, True, False]])
    batch = make_batch(1, 3, terminal=terminal)
    batch["reward"] = torch.tensor([[1.0, 0.0, 0.5]])
    eps = torch.tensor([[[0.5, -1.0], [0.0, 0.0], [1.5, 0.2]]])
    # by hand: u = mu + sigma * eps; log pi from the Normal density and the tanh Jacobian
    mu, sigma = torch.tensor([0.2, -0.1]), torch.tensor([math.exp(-1.0), 1.0])
    u = mu + sigma * eps[0]
    log_pi = (Normal(mu, sigma).log_prob(u) - torch.log(1 - torch.tanh(u) ** 2)).sum(-1)
    expected = 10.0 * batch["reward"][0] + 0.99 * torch.tensor([1.0, 0.0, 1.0]) * (2.5 - 0.5 * log_pi)
    torch.testing.assert_close(sac.td_target(batch, batch["reward"], eps)[0], expected, atol=1e-4, rtol=1e-5)


@pytest.mark.parametrize("bootstrap_on_truncation", [False, True])
def test_bootstrap_mask(bootstrap_on_truncation):
    sac = SAC(OBS, ACT, [0], SACConfig(hidden_dim=16, feature_dim=8, bootstrap_on_truncation=bootstrap_on_truncation))
    terminal = torch.tensor([[False, True, False, True]])
    truncated = torch.tensor([[False, False, True, True]])
    expected = [1.0, 0.0, 1.0 if bootstrap_on_truncation else 0.0, 0.0]
    assert sac.bootstrap_mask(terminal, truncated).tolist() == [expected]
    # and through the target: y = 10 r exactly where m = 0
    pin_outputs(sac, mean=[0.0, 0.0], log_std=[0.0, 0.0], q1=7.0, q2=7.0)
    batch = make_batch(1, 4, terminal=terminal, truncated=truncated)
    y = sac.td_target(batch, batch["reward"], torch.zeros(1, 4, ACT))
    stopped = torch.tensor(expected) == 0
    torch.testing.assert_close(y[0, stopped], 10 * batch["reward"][0, stopped])
    assert (y[0, ~stopped] > 10 * batch["reward"][0, ~stopped] + 5).all()


@pytest.mark.parametrize("log_std,direction", [(-4.0, +1), (0.0, -1)])
def test_alpha_loss_value_and_gradient_sign(log_std, direction):
    """Entropy below H_target (small sigma) must raise alpha, above it lower it; loss = alpha * mean(-log pi - H)."""
    sac = SAC(OBS, ACT, [3], SMALL)
    pin_outputs(sac, mean=[0.0, 0.0], log_std=[log_std, log_std], q1=0.0, q2=0.0)
    sac.actor_opt.lr = 0.0  # keep the actor fixed so the fresh sample's log-prob is computable here
    batch = make_batch(1, 8)
    eps = torch.randn((3, 8, ACT), generator=member_generators([3], stream=Stream.SAC_UPDATE)[0])[2]
    log_pi = squashed_gaussian_log_prob(torch.exp(torch.tensor(log_std)) * eps, eps, torch.full_like(eps, log_std))
    expected = 1.0 * (-log_pi - sac.target_entropy).mean()  # alpha_0 = 1
    metrics = sac.update(batch)
    torch.testing.assert_close(metrics["alpha_loss"][0], expected, atol=1e-4, rtol=1e-5)
    assert math.copysign(1, sac.log_alpha.item()) == direction
    assert abs(sac.log_alpha.item()) == pytest.approx(3e-4, rel=1e-3)  # first Adam step moves by lr


def test_polyak_after_update():
    sac = SAC(OBS, ACT, [0, 1], SMALL)
    before = [p.detach().clone() for p in sac.critic_target.parameters()]
    sac.update(make_batch(2, 4), torch.tensor([True, False]))
    for old, tgt, src in zip(before, sac.critic_target.parameters(), sac.critic.parameters()):
        old, tgt, src = old.view(2, -1), tgt.view(2, -1), src.view(2, -1)
        torch.testing.assert_close(tgt[0], 0.995 * old[0] + 0.005 * src[0], atol=1e-7, rtol=1e-6)
        assert torch.equal(tgt[1], old[1])


def test_target_starts_as_copy_and_actor_critic_independent_trunks():
    sac = SAC(OBS, ACT, [0], SMALL)
    for a, b in zip(sac.critic.parameters(), sac.critic_target.parameters()):
        assert torch.equal(a, b)
    assert not torch.equal(sac.actor.trunk.linear.weight, sac.critic.trunk.linear.weight)
    heads = sac.critic.heads.layers[0].weight  # (E * 2, in, out): the two Q-heads differ
    assert not torch.equal(heads[0], heads[1])


def test_act_shapes_and_deterministic():
    sac = SAC(OBS, ACT, [0, 1, 2], SMALL)
    obs = torch.randn(3, OBS)
    a = sac.act(obs)
    assert a.shape == (3, ACT) and a.abs().max() <= 1
    assert sac.act(torch.randn(3, 7, OBS)).shape == (3, 7, ACT)
    mean, _ = sac.actor(obs.unsqueeze(1))
    torch.testing.assert_close(sac.act(obs, deterministic=True), torch.tanh(mean[:, 0]))


def test_act_noise_per_member_matches_single_seed_runs():
    seeds = [4, 5, 6]
    multi = SAC(OBS, ACT, seeds, SMALL)
    singles = [SAC(OBS, ACT, [s], SMALL) for s in seeds]
    obs = torch.randn(3, OBS)
    mask = torch.tensor([True, False, True])
    for _ in range(3):
        a = multi.act(obs, mask=mask)
        for i, single in enumerate(singles):
            if mask[i]:  # same noise; the E = 3 and E = 1 products may round differently (other shapes)
                torch.testing.assert_close(a[i], single.act(obs[i : i + 1])[0], atol=1e-6, rtol=0)


def test_state_dict_round_trip_reproduces_updates():
    sac = SAC(OBS, ACT, [0, 1], SMALL)
    for n in range(3):
        sac.update(make_batch(2, 4, seed=n))
    clone = SAC(OBS, ACT, [7, 8], SMALL)
    clone.load_state_dict(sac.state_dict())
    for n in range(3, 6):
        m1, m2 = sac.update(make_batch(2, 4, seed=n)), clone.update(make_batch(2, 4, seed=n))
        assert all(torch.equal(m1[k], m2[k]) for k in m1)
    assert torch.equal(sac.act(torch.zeros(2, OBS)), clone.act(torch.zeros(2, OBS)))
    for a, b in zip(sac.critic_target.parameters(), clone.critic_target.parameters()):
        assert torch.equal(a, b)


def test_reward_override_and_metrics_are_per_member():
    sac = SAC(OBS, ACT, [0, 1], SMALL)
    batch = make_batch(2, 4)
    metrics = sac.update(batch, reward=torch.full((2, 4), 3.0))
    assert torch.equal(metrics["batch_reward"], torch.tensor([3.0, 3.0]))
    assert all(v.shape == (2,) for v in metrics.values())


@pytest.mark.parametrize("use_trunk", [True, False])
def test_hand_written_backward_matches_autograd(use_trunk):
    """20 updates of SAC.update (hand-written gradients, actor run once on [o'; o]) against update="autograd" (module
    forwards, torch.autograd.grad), with a member mask and log-sigma values outside the clamp range (their gradient
    must be zero)."""
    cfg = SACConfig(hidden_dim=16, feature_dim=8, use_trunk=use_trunk, log_std_min=-1.0, log_std_max=0.5)
    ours, ref = SAC(OBS, ACT, [3, 4], cfg), SAC(OBS, ACT, [3, 4], cfg)
    ref.use_autograd_update()
    for n in range(20):
        batch = make_batch(2, 16, seed=n, terminal=torch.rand(2, 16) < 0.2)
        mask = torch.tensor([True, n % 3 != 0])
        m_ours, m_ref = ours.update(batch, mask), ref.update(batch, mask)
        assert m_ours.keys() == m_ref.keys()
        for k in m_ours:  # same losses, same diagnostics
            torch.testing.assert_close(m_ours[k], m_ref[k], atol=1e-5, rtol=1e-4, msg=k)
    a, b = ours.state_dict(), ref.state_dict()
    for net in ("actor", "critic", "critic_target"):
        for k in a[net]:
            torch.testing.assert_close(a[net][k], b[net][k], atol=2e-6, rtol=1e-5, msg=f"{net}.{k}")
    torch.testing.assert_close(a["log_alpha"], b["log_alpha"], atol=1e-6, rtol=1e-6)
    for opt in ("actor_opt", "critic_opt"):
        torch.testing.assert_close(a[opt]["exp_avg"], b[opt]["exp_avg"], atol=1e-6, rtol=1e-4)
