"""Seed-batched members: masked Adam, init and training equivalence with single-seed runs, discriminator."""

import math
import time

import numpy as np
import pytest
import torch
from torch import nn

from algorithms.core import SAC, Discriminator, MemberAdam, MemberMLP, SACConfig, discriminator_reward
from algorithms.core.nets import NARROW, member_generators, member_matmul

SKIP = (None, 3, 5)  # member 0 updates always, member 1 skips every 3rd update, member 2 every 5th


def active(member: int, step: int) -> bool:
    return SKIP[member] is None or step % SKIP[member] != SKIP[member] - 1


def quadratic_grads(params, step):
    """A deterministic, step-dependent loss so Adam's moments see varying gradients."""
    loss = sum(((p - math.sin(step + k)) ** 2 * (1 + k)).sum() + (p**3).sum() * 0.01 for k, p in enumerate(params))
    return torch.autograd.grad(loss, params)


def test_member_adam_matches_torch_adam_per_member_with_skips():
    E = 3
    g = torch.Generator().manual_seed(0)
    # the last parameter holds 2 replicas per member (member-major), like the critic's Q-heads
    init = [torch.randn(E, 4, 3, generator=g), torch.randn(E, 1, 5, generator=g), torch.randn(2 * E, 7, generator=g)]
    ours = [nn.Parameter(t.clone()) for t in init]
    opt = MemberAdam(ours, E)
    refs = [[nn.Parameter(t.view(E, -1)[i].clone()) for t in init] for i in range(E)]
    ref_opts = [torch.optim.Adam(r, lr=3e-4, betas=(0.9, 0.999), eps=1e-8) for r in refs]
    for step in range(200):
        mask = torch.tensor([active(i, step) for i in range(E)])
        opt.step(mask, quadratic_grads(ours, step))
        for i in range(E):
            if mask[i]:
                ref_opts[i].zero_grad()
                for p, gr in zip(refs[i], quadratic_grads(refs[i], step)):
                    p.grad = gr
                ref_opts[i].step()
    for i in range(E):
        for p, r in zip(ours, refs[i]):
            torch.testing.assert_close(p.view(E, -1)[i], r.view(-1), atol=1e-6, rtol=0)
        ref_avg = torch.cat([ref_opts[i].state[r]["exp_avg"].view(-1) for r in refs[i]])
        mine = torch.cat([m.view(E, -1)[i] for m in opt.exp_avg.split([p.numel() for p in ours])])
        torch.testing.assert_close(mine, ref_avg, atol=1e-7, rtol=1e-5)
        assert opt.step_count[i].item() == ref_opts[i].state[refs[i][0]]["step"].item()


def test_masked_members_bitwise_unchanged():
    E = 4
    net = MemberMLP(E, [3, 8, 2], member_generators(range(E)))
    opt = MemberAdam(list(net.parameters()), E)
    x = torch.randn(E, 5, 3)
    for _ in range(3):
        opt.step(None, torch.autograd.grad(net(x).square().sum(), opt.params))
    before = {k: v.clone() for k, v in opt.state_dict().items() if isinstance(v, torch.Tensor)}
    params = [p.detach().clone() for p in net.parameters()]
    mask = torch.tensor([False, True, False, True])
    opt.step(mask, torch.autograd.grad(net(x).square().sum(), opt.params))
    after = opt.state_dict()
    for k in ("exp_avg", "exp_avg_sq"):
        old, new = opt.members.member_views(before[k]), opt.members.member_views(after[k])
        for i in range(E):
            assert all(torch.equal(a, b) for a, b in zip(old[i], new[i])) == (not mask[i]), (k, i)
    assert after["step"].tolist() == [3, 4, 3, 4]
    for old, p in zip(params, net.parameters()):
        assert torch.equal(old.view(E, -1)[~mask], p.view(E, -1)[~mask])


def test_member_init_equals_single_seed_init():
    cfg = SACConfig(hidden_dim=16, feature_dim=8)
    multi = SAC(6, 2, [11, 12, 13], cfg)
    single = SAC(6, 2, [12], cfg)
    for net in ("actor", "critic", "critic_target"):
        for a, b in zip(getattr(multi, net).parameters(), getattr(single, net).parameters()):
            assert torch.equal(a.view(3, -1)[1], b.view(-1))


@pytest.mark.parametrize("n, k, m", [
    (256, 256, 1),  # a critic head over a batch
    (256, 256, 6),  # an actor's output (2A)
    (1, 256, 6),  # the same when acting (one row per member)
    (256, 256, NARROW + 1),  # just wide enough for the plain product
    (256, 1, 256),  # an outer product: d (B, 1) @ W^T (1, hidden)
    (256, 256, 256),  # a hidden layer
])
def test_member_matmul_is_the_batched_product(n, k, m):
    """member_matmul equals torch.bmm / baddbmm (float rounding) for every shape the networks use, and where it takes
    its own route (one column, one row per member, an outer product) each member's result is bit for bit what an E = 1
    call gives, so a member never depends on which others share its process."""
    g = torch.Generator().manual_seed(n + k + m)
    a, b, bias = (torch.randn(s, generator=g) for s in ((3, n, k), (3, k, m), (3, 1, m)))
    torch.testing.assert_close(member_matmul(a, b), torch.bmm(a, b), rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(member_matmul(a, b, bias), torch.baddbmm(bias, a, b), rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(member_matmul(a.transpose(1, 2).contiguous().transpose(1, 2), b), torch.bmm(a, b),
                               rtol=1e-5, atol=1e-4)  # strided input, as x^T in a weight gradient
    if m == 1 or n == 1 or k == 1:
        single = torch.cat([member_matmul(a[i : i + 1], b[i : i + 1], bias[i : i + 1]) for i in range(3)])
        assert torch.equal(member_matmul(a, b, bias), single)


def test_xavier_uniform_bounds_and_zero_bias():
    net = MemberMLP(2, [30, 20], member_generators([0, 1]))
    w, b = net.layers[0].weight, net.layers[0].bias
    bound = math.sqrt(6 / 50)
    assert w.abs().max() <= bound and w.abs().max() > 0.9 * bound
    assert torch.equal(b, torch.zeros_like(b)) and not torch.equal(w[0], w[1])


N_UPDATES = 2000  # project acceptance: E=3 with per-member skips equals three single-seed runs after 2000 updates


def test_members_train_independently_2000_updates():
    """E=3 SAC (seeds a, b, c) on member-specific data with member-specific skips == three E=1 SACs (max |diff| < 1e-4)."""
    seeds, obs_dim, act_dim, B = [101, 202, 303], 6, 2, 32
    cfg = SACConfig(hidden_dim=32, feature_dim=8, batch_size=B)
    multi = SAC(obs_dim, act_dim, seeds, cfg)
    singles = [SAC(obs_dim, act_dim, [s], cfg) for s in seeds]
    g = torch.Generator().manual_seed(0)
    masks = torch.tensor([[active(i, n) for i in range(3)] for n in range(N_UPDATES)])
    start = time.perf_counter()
    for n in range(N_UPDATES):
        batch = {
            "obs": torch.randn(3, B, obs_dim, generator=g),
            "action": torch.rand(3, B, act_dim, generator=g) * 2 - 1,
            "reward": (torch.rand(3, B, generator=g) < 0.3).float(),
            "next_obs": torch.randn(3, B, obs_dim, generator=g),
            "terminal": torch.rand(3, B, generator=g) < 0.05,
            "truncated": torch.rand(3, B, generator=g) < 0.05,
        }
        multi.update(batch, masks[n])
        for i, single in enumerate(singles):
            if masks[n, i]:
                single.update({k: v[i : i + 1] for k, v in batch.items()})
    elapsed = time.perf_counter() - start
    state = multi.state_dict()
    worst = 0.0
    for i, single in enumerate(singles):
        ref = single.state_dict()
        for net in ("actor", "critic", "critic_target"):
            for k, v in ref[net].items():
                worst = max(worst, (state[net][k].view(3, -1)[i] - v.view(-1)).abs().max().item())
        worst = max(worst, abs(state["log_alpha"][i].item() - ref["log_alpha"][0].item()))
        assert state["critic_opt"]["step"][i].item() == masks[:, i].sum().item()
    assert worst < 1e-4, worst
    print(f"{N_UPDATES} lockstep updates in {elapsed:.1f}s, max |diff| = {worst:.2e}")


# ---------------------------------------------------------------------------------------------------------------------
# discriminator (docs/algorithms.md §9.3, §10)


def test_mixup_labels_are_the_mixed_labels():
    """With positives = all-ones and negatives = all-zeros states, every mixed input must equal its mixed label."""
    disc = Discriminator(3, [0, 1])
    x, y = disc.mix(torch.ones(2, 400, 3), torch.zeros(2, 400, 3), None)
    assert x.shape == (2, 800, 3) and y.shape == (2, 800)
    torch.testing.assert_close(x, y.unsqueeze(-1).expand_as(x))
    assert ((y > 0.01) & (y < 0.99)).float().mean() > 0.3  # labels really are soft
    assert abs(y.mean().item() - 0.5) < 0.05


def test_discriminator_reward_values():
    p = torch.tensor([0.0, 0.5, 0.9, 1.0])
    medal = discriminator_reward(p, "medal")
    torch.testing.assert_close(medal, torch.tensor([0.0, math.log(2), -math.log(0.1), -math.log(1e-10)]), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(discriminator_reward(p[1:], "logc"), torch.log(p[1:]))
    assert discriminator_reward(p[:1], "logc").item() == pytest.approx(math.log(1e-10), rel=1e-4)
    with pytest.raises(ValueError):
        discriminator_reward(p, "gail")
    # through the network: pin the logit to logit(0.8)
    disc = Discriminator(3, [0])
    with torch.no_grad():
        disc.net.layers[-1].weight.zero_()
        disc.net.layers[-1].bias.fill_(math.log(0.8 / 0.2))
    torch.testing.assert_close(disc.reward(torch.randn(1, 5, 3)), torch.full((1, 5), -math.log(0.2)), rtol=1e-5, atol=1e-5)


def test_discriminator_members_independent_and_learns():
    seeds, masks = [5, 6], [[True, True], [True, False], [False, True], [True, True]] * 25
    multi = Discriminator(3, seeds)
    singles = [Discriminator(3, [s]) for s in seeds]
    g = torch.Generator().manual_seed(1)
    for mask in masks:
        pos, neg = torch.randn(2, 400, 3, generator=g) + 1.5, torch.randn(2, 400, 3, generator=g) - 1.5
        multi.update(pos, neg, torch.tensor(mask))
        for i, single in enumerate(singles):
            if mask[i]:
                single.update(pos[i : i + 1], neg[i : i + 1])
    # not bitwise: a (1, 800) mean may sum in another order than the rows of a (2, 800) one
    for i, single in enumerate(singles):
        for a, b in zip(multi.net.parameters(), single.net.parameters()):
            torch.testing.assert_close(a.view(2, -1)[i], b.view(-1), atol=1e-6, rtol=0)
    probe = torch.tensor([[[1.5, 1.5, 1.5], [-1.5, -1.5, -1.5]]]).expand(2, 2, 3)
    p = multi.prob(probe)
    assert (p[:, 0] > 0.6).all() and (p[:, 1] < 0.4).all()  # 100 small Adam steps on soft (mixup) labels
    clone = Discriminator(3, [9, 9])
    clone.load_state_dict(multi.state_dict())
    pos, neg = torch.ones(2, 400, 3), -torch.ones(2, 400, 3)
    assert torch.equal(multi.update(pos, neg)["discriminator_loss"], clone.update(pos, neg)["discriminator_loss"])
    assert np.allclose(multi.prob(probe), clone.prob(probe))
