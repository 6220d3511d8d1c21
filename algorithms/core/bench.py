"""Timing of one member-batched SAC update against a plain single-seed ``nn.Module`` SAC (same math, docs/algorithms.md §3).

``bench_update(members, obs_dim, act_dim, device, n)`` returns milliseconds per update; no CLI.
"""

from __future__ import annotations

import time

import torch
import torch.nn.functional as F
from torch import nn

from .sac import SAC, SACConfig, squashed_gaussian_log_prob


def _mlp(in_dim: int, out_dim: int, cfg: SACConfig) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(in_dim, cfg.hidden_dim), nn.ReLU(), nn.Linear(cfg.hidden_dim, cfg.hidden_dim), nn.ReLU(),
        nn.Linear(cfg.hidden_dim, out_dim),
    )


def _trunk(obs_dim: int, cfg: SACConfig) -> nn.Sequential:
    return nn.Sequential(nn.Linear(obs_dim, cfg.feature_dim), nn.LayerNorm(cfg.feature_dim), nn.Tanh())


class PlainSAC:
    """Reference single-seed SAC written the usual way (nn.Linear, torch.optim.Adam, zero_grad/backward), as in [MC]."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: SACConfig, device):
        self.cfg = cfg
        self.actor = nn.Sequential(_trunk(obs_dim, cfg), _mlp(cfg.feature_dim, 2 * act_dim, cfg)).to(device)
        self.trunk = _trunk(obs_dim, cfg).to(device)
        self.heads = nn.ModuleList(_mlp(cfg.feature_dim + act_dim, 1, cfg) for _ in range(2)).to(device)
        self.critic = nn.ModuleList([self.trunk, self.heads])
        self.target = nn.ModuleList([_trunk(obs_dim, cfg), nn.ModuleList(_mlp(cfg.feature_dim + act_dim, 1, cfg)
                                                                         for _ in range(2))]).to(device)
        self.target.load_state_dict(self.critic.state_dict())
        self.log_alpha = torch.zeros((), device=device, requires_grad=True)
        self.opts = [torch.optim.Adam(m, lr=cfg.lr) for m in
                     (self.actor.parameters(), self.critic.parameters(), [self.log_alpha])]
        self.target_entropy = -cfg.target_entropy_scale * act_dim

    def q(self, critic, obs, action):
        h = torch.cat([critic[0](obs), action], -1)
        return torch.min(critic[1][0](h), critic[1][1](h)).squeeze(-1), critic[1][0](h).squeeze(-1)

    def pi(self, obs):
        mean, log_std = self.actor(obs).chunk(2, -1)
        log_std = log_std.clamp(self.cfg.log_std_min, self.cfg.log_std_max)
        eps = torch.randn_like(mean)
        u = mean + log_std.exp() * eps
        return torch.tanh(u), squashed_gaussian_log_prob(u, eps, log_std)

    def update(self, b):
        cfg, alpha = self.cfg, self.log_alpha.exp().detach()
        actor_opt, critic_opt, alpha_opt = self.opts
        with torch.no_grad():
            a2, lp2 = self.pi(b["next_obs"])
            m = (~(b["terminal"] | b["truncated"])).float()
            y = cfg.reward_scale * b["reward"] + cfg.gamma * m * (self.q(self.target, b["next_obs"], a2)[0] - alpha * lp2)
        h = torch.cat([self.trunk(b["obs"]), b["action"]], -1)
        loss = 0.5 * (F.mse_loss(self.heads[0](h).squeeze(-1), y) + F.mse_loss(self.heads[1](h).squeeze(-1), y))
        critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        critic_opt.step()
        a, lp = self.pi(b["obs"])
        actor_loss = (alpha * lp - self.q(self.critic, b["obs"], a)[0]).mean()
        actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward()
        actor_opt.step()
        with torch.no_grad():
            _, lp = self.pi(b["obs"])
        alpha_loss = (self.log_alpha.exp() * (-lp - self.target_entropy)).mean()
        alpha_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        alpha_opt.step()
        with torch.no_grad():
            for p, tp in zip(self.critic.parameters(), self.target.parameters()):
                tp.lerp_(p, cfg.tau)


def _random_batch(E: int, B: int, obs_dim: int, act_dim: int, device) -> dict:
    g = torch.Generator().manual_seed(0)
    batch = dict(
        obs=torch.randn(E, B, obs_dim, generator=g), action=torch.rand(E, B, act_dim, generator=g) * 2 - 1,
        reward=torch.rand(E, B, generator=g), next_obs=torch.randn(E, B, obs_dim, generator=g),
        terminal=torch.rand(E, B, generator=g) < 0.05, truncated=torch.rand(E, B, generator=g) < 0.05,
    )
    return {k: v.to(device) for k, v in batch.items()}


def _time_ms(fn, n: int, device) -> float:
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    for _ in range(max(3, n // 10)):  # warm-up
        fn()
    sync()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    sync()
    return (time.perf_counter() - start) / n * 1e3


def bench_update(members: int, obs_dim: int = 14, act_dim: int = 4, device="cpu", n: int = 100,
                 cfg: SACConfig | None = None, threads: int | None = None) -> dict[str, float]:
    """Milliseconds per update: member SAC with ``members`` seeds (all updating, and with a half mask) and the plain
    single-seed SAC, at cfg.batch_size (default 256). ``threads``: torch intra-op threads for the measurement (on a busy
    CPU, more than one thread can make these small ops stall by orders of magnitude)."""
    cfg = cfg or SACConfig()
    if threads is not None:
        torch.set_num_threads(threads)
    sac = SAC(obs_dim, act_dim, list(range(members)), cfg, device)
    batch = _random_batch(members, cfg.batch_size, obs_dim, act_dim, device)
    half = torch.arange(members) % 2 == 0
    plain = PlainSAC(obs_dim, act_dim, cfg, device)
    plain_batch = {k: v[0] for k, v in batch.items()}
    return {
        "members": members,
        "threads": torch.get_num_threads(),
        "member_sac_ms": _time_ms(lambda: sac.update(batch), n, device),
        "member_sac_masked_ms": _time_ms(lambda: sac.update(batch, half), n, device),
        "plain_sac_ms": _time_ms(lambda: plain.update(plain_batch), n, device),
    }
