"""Seed-batched SAC as in the MEDAL reference code (ALGORITHMS.md §3).

One :class:`SAC` object holds E independent agents ("members", one per seed) with a leading member dimension on every
parameter, optimizer state and random stream. Member i behaves exactly like an E=1 agent built with ``seeds[i]``.

Randomness (documented choice): each member owns two ``torch.Generator`` on the agent's device, one for acting noise and
one for update noise (streams derived from its seed, see :func:`nets.stream_seed`); noise is drawn per member (a loop of
E small draws) and members that are masked out draw nothing. Both generators are part of :meth:`SAC.state_dict`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from .nets import (
    MemberMLP,
    MemberTrunk,
    generator_states,
    host_mask,
    load_generator_states,
    member_generators,
    member_randn,
)
from .optim import FlatMembers, MemberAdam, polyak_update

ACT_STREAM, UPDATE_STREAM = 1, 2  # random-stream ids (see nets.stream_seed)
HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


@dataclass
class SACConfig:
    """Defaults = MEDAL reference values (ALGORITHMS.md §3.3)."""

    lr: float = 3e-4
    batch_size: int = 256
    gamma: float = 0.99
    tau: float = 0.005
    reward_scale: float = 10.0
    init_temperature: float = 1.0
    target_entropy_scale: float = 0.5  # target entropy = -scale * |A|
    log_std_min: float = -20.0
    log_std_max: float = 2.0  # RISC uses 10 (§14.2)
    feature_dim: int = 50
    hidden_dim: int = 256
    use_trunk: bool = True  # Linear -> LayerNorm -> Tanh feature layer before the MLPs (§3.1)
    bootstrap_on_truncation: bool = False  # False: [MC]-faithful (truncation masks the bootstrap); True: RISC (§2.3)


def squashed_gaussian_log_prob(u: torch.Tensor, eps: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log pi(tanh(u)) for u = mu + sigma * eps, summed over the last dim (§3.2):
    sum_d [ log N(u; mu, sigma) - 2 * (log 2 - u - softplus(-2u)) ], the second term being log(1 - tanh(u)^2)."""
    normal = -0.5 * eps.square() - log_std - HALF_LOG_2PI
    log_det = 2.0 * (math.log(2.0) - u - nn.functional.softplus(-2.0 * u))
    return (normal - log_det).sum(-1)


class Actor(nn.Module):
    """[trunk] -> 256 -> ReLU -> 256 -> ReLU -> 2|A| (mean, log sigma); squashed Gaussian policy (§3.1)."""

    def __init__(self, num_members, obs_dim, act_dim, cfg: SACConfig, generators):
        super().__init__()
        self.trunk = MemberTrunk(num_members, obs_dim, cfg.feature_dim, generators) if cfg.use_trunk else nn.Identity()
        in_dim = cfg.feature_dim if cfg.use_trunk else obs_dim
        self.mlp = MemberMLP(num_members, [in_dim, cfg.hidden_dim, cfg.hidden_dim, 2 * act_dim], generators)
        self.log_std_bounds = (cfg.log_std_min, cfg.log_std_max)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = self.mlp(self.trunk(obs)).chunk(2, dim=-1)
        return mean, log_std.clamp(*self.log_std_bounds)  # plain clamp, not the tanh rescaling (§3.1)

    def sample(self, obs: torch.Tensor, eps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised action tanh(mu + sigma * eps) and its log-prob (E, B)."""
        mean, log_std = self(obs)
        u = mean + log_std.exp() * eps
        return torch.tanh(u), squashed_gaussian_log_prob(u, eps, log_std)


class Critic(nn.Module):
    """Shared [trunk] on o, then two heads on concat(features, a): 256 -> ReLU -> 256 -> ReLU -> 1 (§3.1).
    The two heads are stored as 2 replicas per member of one MemberMLP; output Q (E, 2, B)."""

    def __init__(self, num_members, obs_dim, act_dim, cfg: SACConfig, generators):
        super().__init__()
        self.trunk = MemberTrunk(num_members, obs_dim, cfg.feature_dim, generators) if cfg.use_trunk else nn.Identity()
        in_dim = (cfg.feature_dim if cfg.use_trunk else obs_dim) + act_dim
        self.heads = MemberMLP(num_members, [in_dim, cfg.hidden_dim, cfg.hidden_dim, 1], generators, copies=2)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.heads(torch.cat([self.trunk(obs), action], dim=-1)).squeeze(-1)


class SAC:
    """E-member SAC (ALGORITHMS.md §3). ``seeds[i]`` fully determines member i (init, acting and update noise)."""

    def __init__(self, obs_dim: int, act_dim: int, seeds: list[int], cfg: SACConfig | None = None, device="cpu"):
        self.cfg = cfg = cfg or SACConfig()
        self.obs_dim, self.act_dim, self.seeds = obs_dim, act_dim, list(seeds)
        self.num_members = E = len(self.seeds)
        self.device = torch.device(device)
        self.target_entropy = -cfg.target_entropy_scale * act_dim

        # parameters are created on the CPU from per-member generators (actor first, then critic), then moved
        init_gens = member_generators(self.seeds)
        self.actor = Actor(E, obs_dim, act_dim, cfg, init_gens).to(self.device)
        self.critic = Critic(E, obs_dim, act_dim, cfg, init_gens).to(self.device)
        self.critic_target = Critic(E, obs_dim, act_dim, cfg, init_gens).to(self.device).requires_grad_(False)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.log_alpha = nn.Parameter(torch.full((E,), math.log(cfg.init_temperature), device=self.device))

        self.actor_opt = MemberAdam(list(self.actor.parameters()), E, lr=cfg.lr)
        self.critic_opt = MemberAdam(list(self.critic.parameters()), E, lr=cfg.lr)
        self.alpha_opt = MemberAdam([self.log_alpha], E, lr=cfg.lr)
        self.target_params = FlatMembers(list(self.critic_target.parameters()), E)

        self.act_generators = member_generators(self.seeds, self.device, ACT_STREAM)
        self.update_generators = member_generators(self.seeds, self.device, UPDATE_STREAM)

    @property
    def alpha(self) -> torch.Tensor:
        return self.log_alpha.detach().exp()

    # -----------------------------------------------------------------------------------------------------------------
    @torch.no_grad()
    def act(self, obs, deterministic: bool = False, generator: torch.Generator | None = None, mask=None) -> torch.Tensor:
        """Actions for obs (E, obs_dim) or (E, B, obs_dim) -> (E, [B,] act_dim) in [-1, 1] (§3.4).

        Stochastic actions use each member's acting generator; members with ``mask`` False draw no noise and get the
        deterministic action. ``generator``: one generator for all members instead (e.g. stochastic evaluation that
        must not disturb the training streams).
        """
        obs = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        squeeze = obs.dim() == 2
        obs = obs.unsqueeze(1) if squeeze else obs
        mean, log_std = self.actor(obs)
        if deterministic:
            action = torch.tanh(mean)
        else:
            if generator is not None:
                eps = torch.randn(mean.shape, generator=generator, device=self.device)
            else:
                eps = member_randn(self.act_generators, mean.shape[1:], host_mask(mask, self.num_members), self.device)
            action = torch.tanh(mean + log_std.exp() * eps)
        return action.squeeze(1) if squeeze else action

    def bootstrap_mask(self, terminal: torch.Tensor, truncated: torch.Tensor) -> torch.Tensor:
        """m = 0 after a terminal step, or a truncated one unless ``bootstrap_on_truncation``; else 1 (§2.3, §3.2)."""
        stop = terminal if self.cfg.bootstrap_on_truncation else terminal | truncated
        return (~stop).float()

    @torch.no_grad()
    def td_target(self, batch: dict, reward: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """y = scale * r + gamma * m * (min_j Qtarget_j(o', a') - alpha * log pi(a'|o')), a' = tanh(mu + sigma * eps)
        sampled at o' = batch["next_obs"] (§3.2 step 1); (E, B)."""
        cfg = self.cfg
        next_action, next_log_prob = self.actor.sample(batch["next_obs"], eps)
        target_v = self.critic_target(batch["next_obs"], next_action).min(dim=1).values
        target_v = target_v - self.alpha[:, None] * next_log_prob
        m = self.bootstrap_mask(batch["terminal"], batch["truncated"])
        return cfg.reward_scale * reward + cfg.gamma * m * target_v

    def update(self, batch: dict, mask=None, reward: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """One SAC update (§3.2, in order: critic, actor, temperature, Polyak) for the members in ``mask``.

        batch: obs (E,B,O), action (E,B,A), reward (E,B), next_obs (E,B,O), terminal (E,B) bool, truncated (E,B) bool.
        mask: bool (E,) (CPU tensor / array preferred, see nets.host_mask) or None for all members; masked-out members
        are left bitwise unchanged, including optimizer state and random streams.
        reward: optional (E,B) replacement for batch["reward"] (e.g. MEDAL's discriminator reward, §9.6).
        Returns per-member metrics (E,) as tensors (no host sync).
        """
        cfg, E = self.cfg, self.num_members
        mask_host = host_mask(mask, E)
        mask_dev = None if mask_host is None else torch.as_tensor(mask_host).to(self.device, non_blocking=True)
        obs, action = batch["obs"], batch["action"]
        reward = batch["reward"] if reward is None else reward
        B = obs.shape[1]
        # all update noise at once: [next-action sample, actor sample, fresh temperature sample]
        noise = member_randn(self.update_generators, (3, B, self.act_dim), mask_host, self.device)
        alpha = self.alpha

        # 1. critic
        target_q = self.td_target(batch, reward, noise[:, 0])
        q = self.critic(obs, action)  # (E, 2, B)
        # 0.5 * (MSE1 + MSE2) per member; summing over members keeps their gradients apart
        critic_loss = 0.5 * (q - target_q.unsqueeze(1)).square().mean(dim=2).sum(dim=1)
        self._step(self.critic_opt, critic_loss, mask_dev)

        # 2. actor: mean(alpha * log pi(a|o) - min Q(o, a)), a ~ pi(.|o); gradients taken w.r.t. actor params only, so
        # nothing leaks into the critic's next step (the [MC] pitfall of §3.6 cannot occur)
        new_action, log_prob = self.actor.sample(obs, noise[:, 1])
        q_pi = self.critic(obs, new_action).min(dim=1).values
        actor_loss = (alpha[:, None] * log_prob - q_pi).mean(dim=1)
        self._step(self.actor_opt, actor_loss, mask_dev)

        # 3. temperature: FRESH sample from the updated actor; loss mean(alpha * (-log pi - H_target).detach())
        with torch.no_grad():
            _, fresh_log_prob = self.actor.sample(obs, noise[:, 2])
        alpha_loss = (self.log_alpha.exp()[:, None] * (-fresh_log_prob - self.target_entropy)).mean(dim=1)
        self._step(self.alpha_opt, alpha_loss, mask_dev)

        # 4. target critic
        polyak_update(self.target_params, self.critic_opt.members, cfg.tau, mask_dev)

        return {
            "critic_loss": critic_loss.detach(),
            "actor_loss": actor_loss.detach(),
            "alpha_loss": alpha_loss.detach(),
            "alpha": self.alpha,
            "q1": q[:, 0].detach().mean(dim=1),
            "target_q": target_q.mean(dim=1),
            "log_prob": fresh_log_prob.mean(dim=1),
            "batch_reward": reward.mean(dim=1),
        }

    @staticmethod
    def _step(opt: MemberAdam, member_losses: torch.Tensor, mask: torch.Tensor | None) -> None:
        grads = torch.autograd.grad(member_losses.sum(), opt.params)
        opt.step(mask, grads)

    # -----------------------------------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "config": asdict(self.cfg),
            "seeds": list(self.seeds),
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "alpha_opt": self.alpha_opt.state_dict(),
            "act_generators": generator_states(self.act_generators),
            "update_generators": generator_states(self.update_generators),
        }

    def load_state_dict(self, state: dict) -> None:
        # Module.load_state_dict copies in place, which keeps the flat optimizer views valid
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.alpha_opt.load_state_dict(state["alpha_opt"])
        load_generator_states(self.act_generators, state["act_generators"])
        load_generator_states(self.update_generators, state["update_generators"])
