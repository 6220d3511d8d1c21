"""Seed-batched SAC as in the MEDAL reference code (docs/algorithms.md §3); its losses are in :mod:`.losses`.

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

from algorithms.api import setting
from algorithms.update_modes import UPDATES

from . import manual
from .losses import (
    actor_loss,
    actor_loss_grads,
    critic_loss,
    critic_loss_grad,
    squashed_gaussian_backward,
    squashed_gaussian_log_prob,
    temperature_loss,
)
from .nets import (
    MemberMLP,
    MemberTrunk,
    Stream,
    generator_states,
    host_mask,
    load_generator_states,
    member_generators,
    member_randn,
)
from .optim import FlatMembers, MemberAdam, polyak_update, polyak_update_masked


@dataclass
class SACConfig:
    """Defaults = MEDAL reference values (docs/algorithms.md §3.3)."""

    lr: float = setting(3e-4, "Adam learning rate of actor, critic and temperature", gt=0, le=1)
    batch_size: int = setting(256, "transitions per SAC update", ge=1, le=65_536)
    gamma: float = setting(0.99, "discount", ge=0, lt=1)
    tau: float = setting(0.005, "Polyak rate of the target critic", gt=0, le=1)
    reward_scale: float = setting(10.0, "reward multiplier inside the critic target", gt=0, le=1e6)
    init_temperature: float = setting(1.0, "initial entropy temperature alpha", gt=0, le=1e6)
    target_entropy_scale: float = setting(0.5, "target entropy = -scale * |A|", ge=0, le=100)
    log_std_min: float = setting(-20.0, "lower clamp of the policy's log sigma", ge=-100, le=0)
    log_std_max: float = setting(2.0, "upper clamp of the policy's log sigma (RISC: 10)", ge=-10, le=100)
    feature_dim: int = setting(50, "width of the Linear-LayerNorm-Tanh trunk", ge=1, le=65_536)
    hidden_dim: int = setting(256, "width of the two hidden layers of actor and critic", ge=1, le=65_536)
    use_trunk: bool = setting(True, "Linear -> LayerNorm -> Tanh feature layer before the MLPs (3.1)")
    bootstrap_on_truncation: bool = setting(False, "bootstrap through time-outs and switches (RISC's TAB); "
                                                   "False: they end bootstrapping as terminals do (MEDAL code)")


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
    """E-member SAC (docs/algorithms.md §3). ``seeds[i]`` fully determines member i (init, acting and update noise)."""

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

        self.act_generators = member_generators(self.seeds, self.device, Stream.SAC_ACT)
        self.update_generators = member_generators(self.seeds, self.device, Stream.SAC_UPDATE)
        self.static = False  # see use_static_update
        self._update_fn = self._update
        self._all_members = torch.ones(E, dtype=torch.bool, device=self.device)

    def use_static_update(self, compile: bool = False) -> None:
        """Run every later update on the static-shape path: the member mask becomes a device tensor and the optimizer
        and target steps whole-tensor arithmetic (``MemberAdam.step_masked``), so the update after its noise draw is
        one fixed sequence of kernels with no host decision. ``compile``: through ``torch.compile`` (on CUDA with
        ``mode="reduce-overhead"``, i.e. replayed as CUDA graphs). Equal to the default path within float rounding;
        the default path alone keeps an E-member agent bitwise equal to E single-seed ones."""
        self.static = True
        if compile:
            mode = "reduce-overhead" if self.device.type == "cuda" else None
            self._update_fn = torch.compile(self._update, mode=mode, dynamic=False)

    def use_update(self, update: str) -> None:
        """Run every later update in mode ``update``, one of :data:`UPDATES` (the default path is where an agent
        starts)."""
        if update == "autograd":
            self.use_autograd_update()
        elif update in ("static", "compiled"):
            self.use_static_update(compile=update == "compiled")
        elif update != "default":
            raise ValueError(f"unknown update {update!r}; known: {', '.join(UPDATES)}")

    def use_autograd_update(self) -> None:
        """Run every later update through torch.autograd (:meth:`_update_autograd`): the same losses and optimizer
        kernels, gradients from the module forwards instead of :mod:`manual`. Slower on a CPU; the path to edit first
        when changing a loss. Equal to the default path within float rounding."""
        self.static = False
        self._update_fn = self._update_autograd

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

    @torch.no_grad()
    def q_value(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """min_j Q_j(o, a) of the online critic, (E,) for obs (E, obs_dim) and action (E, act_dim)."""
        return self.critic(obs.unsqueeze(1), action.unsqueeze(1)).min(dim=1).values.squeeze(-1)

    def bootstrap_mask(self, terminal: torch.Tensor, truncated: torch.Tensor) -> torch.Tensor:
        """m = 0 after a terminal step, or a truncated one unless ``bootstrap_on_truncation``; else 1 (§2.3, §3.2)."""
        stop = terminal if self.cfg.bootstrap_on_truncation else terminal | truncated
        return (~stop).float()

    @torch.no_grad()
    def td_target(self, batch: dict, reward: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """y = scale * r + gamma * m * (min_j Qtarget_j(o', a') - alpha * log pi(a'|o')), a' = tanh(mu + sigma * eps)
        sampled at o' = batch["next_obs"] (§3.2 step 1); (E, B)."""
        return self._td_target(batch, reward, *self.actor(batch["next_obs"]), eps)

    @torch.no_grad()
    def _td_target(self, batch, reward, next_mean, next_log_std, eps) -> torch.Tensor:
        u = next_mean + next_log_std.exp() * eps
        next_action, next_log_prob = torch.tanh(u), squashed_gaussian_log_prob(u, eps, next_log_std)
        target_v = self.critic_target(batch["next_obs"], next_action).min(dim=1).values
        target_v = target_v - self.alpha[:, None] * next_log_prob
        m = self.bootstrap_mask(batch["terminal"], batch["truncated"])
        return self.cfg.reward_scale * reward + self.cfg.gamma * m * target_v

    @torch.no_grad()
    def update(self, batch: dict, mask=None, reward: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """One SAC update (§3.2, in order: critic, actor, temperature, Polyak) for the members in ``mask``.

        batch: obs (E,B,O), action (E,B,A), reward (E,B), next_obs (E,B,O), terminal (E,B) bool, truncated (E,B) bool.
        mask: bool (E,) (host array / CPU tensor preferred, see nets.host_mask) or None for all members; masked-out
        members are left bitwise unchanged, including optimizer state and random streams.
        reward: optional (E,B) replacement for batch["reward"] (e.g. MEDAL's discriminator reward, §9.6).
        Returns per-member metrics (E,) as tensors (no host sync).

        Gradients come from the hand-written backward passes of :mod:`manual` (no autograd graph; through autograd
        after :meth:`use_autograd_update`). The actor is evaluated once on [o'; o]: its parameters do not change before
        the actor step, so the target's next action and the actor loss's action come from one forward pass, as they
        would from two.
        """
        mask_host = host_mask(mask, self.num_members)
        B = batch["obs"].shape[1]
        # all update noise at once: [next-action sample, actor sample, fresh temperature sample]
        noise = member_randn(self.update_generators, (3, B, self.act_dim), mask_host, self.device)
        reward = batch["reward"] if reward is None else reward
        if self.static:
            keep = self._all_members if mask_host is None else torch.as_tensor(mask_host, device=self.device)
            return self._update_fn(batch, reward, noise, keep)
        return self._update_fn(batch, reward, noise, mask_host)

    def _update(self, batch: dict, reward: torch.Tensor, noise: torch.Tensor, mask) -> dict[str, torch.Tensor]:
        """The update after its noise draw, with hand-derived gradients. ``mask``: a host bool array or None
        (per-member optimizer kernels: the default path), or a bool tensor on the device (the static path, see
        :meth:`use_static_update`)."""
        obs = batch["obs"]
        B = obs.shape[1]
        alpha = self.alpha
        actor_out, actor_cache = manual.actor_forward(self.actor, torch.cat([batch["next_obs"], obs], dim=1))
        mean, log_std_raw = actor_out.chunk(2, dim=-1)
        log_std = log_std_raw.clamp(self.cfg.log_std_min, self.cfg.log_std_max)
        target_q = self._td_target(batch, reward, mean[:, :B], log_std[:, :B], noise[:, 0])
        loss_q, q = self._update_critic(obs, batch["action"], target_q, mask)
        loss_pi = self._update_actor(obs, alpha, mean[:, B:], log_std_raw[:, B:], log_std[:, B:], actor_cache,
                                     noise[:, 1], mask)
        loss_alpha, log_prob = self._update_temperature(obs, noise[:, 2], mask)
        self._update_target(mask)
        return self._metrics(loss_q, loss_pi, loss_alpha, q, target_q, log_prob, reward)

    def _update_critic(self, obs, action, target_q, mask) -> tuple[torch.Tensor, torch.Tensor]:
        """1. critic: :func:`critic_loss` at the batch's (o, a), gradients back through both heads and the trunk;
        returns the loss and the heads' values (E, 2, B)."""
        q, cache = manual.critic_forward(self.critic, obs, action)  # (E, 2, B)
        grads, _ = manual.critic_backward(self.critic, cache, critic_loss_grad(q, target_q))
        self._optimizer_step(self.critic_opt, grads, mask)
        return critic_loss(q, target_q), q

    def _update_actor(self, obs, alpha, mean, log_std_raw, log_std, actor_cache, eps, mask) -> torch.Tensor:
        """2. actor: :func:`actor_loss` with a = tanh(mu + sigma * eps) from the actor's output at o (rows B: of the
        forward pass on [o'; o]) and the critic just updated; gradients reach the actor's parameters only."""
        B = obs.shape[1]
        std = log_std.exp()
        u = mean + std * eps
        action, log_prob = torch.tanh(u), squashed_gaussian_log_prob(u, eps, log_std)
        q_pi, q_cache = manual.critic_forward(self.critic, obs, action)
        d_q, d_log_prob = actor_loss_grads(alpha, q_pi)
        _, d_action = manual.critic_backward(self.critic, q_cache, d_q, weights=False)
        bounds = (self.cfg.log_std_min, self.cfg.log_std_max)
        d_out = squashed_gaussian_backward(d_action, d_log_prob, action, std, eps, log_std_raw, bounds)
        self._optimizer_step(self.actor_opt, manual.actor_backward(self.actor, actor_cache, d_out, slice(B, None)), mask)
        return actor_loss(alpha, log_prob, q_pi)

    def _update_temperature(self, obs, eps, mask) -> tuple[torch.Tensor, torch.Tensor]:
        """3. temperature: :func:`temperature_loss` on a FRESH sample from the updated actor; returns the loss and the
        sample's log pi (E, B)."""
        mean, log_std = self.actor(obs)
        log_prob = squashed_gaussian_log_prob(mean + log_std.exp() * eps, eps, log_std)
        loss = temperature_loss(self.log_alpha, log_prob, self.target_entropy)
        self._optimizer_step(self.alpha_opt, [loss], mask)
        return loss, log_prob

    def _update_target(self, mask) -> None:
        """4. target critic: Polyak averaging toward the critic at rate tau."""
        if isinstance(mask, torch.Tensor):
            polyak_update_masked(self.target_params, self.critic_opt.members, self.cfg.tau, mask)
        else:
            polyak_update(self.target_params, self.critic_opt.members, self.cfg.tau, mask)

    @staticmethod
    def _optimizer_step(opt: MemberAdam, grads, mask) -> None:
        if isinstance(mask, torch.Tensor):
            opt.step_masked(mask, grads)
        else:
            opt.step(mask, grads)

    def _update_autograd(self, batch: dict, reward: torch.Tensor, noise: torch.Tensor, mask) -> dict[str, torch.Tensor]:
        """The same update, losses and order through torch.autograd: module forwards, ``torch.autograd.grad``.
        The actor runs three times here (target sample, actor loss, fresh temperature sample) where :meth:`_update`
        runs it twice."""
        obs = batch["obs"]
        alpha = self.alpha
        target_q = self.td_target(batch, reward, noise[:, 0])
        with torch.enable_grad():
            q = self.critic(obs, batch["action"])
            loss_q = critic_loss(q, target_q)
            self._optimizer_step(self.critic_opt, torch.autograd.grad(loss_q.sum(), self.critic_opt.params), mask)
            action, log_prob = self.actor.sample(obs, noise[:, 1])
            loss_pi = actor_loss(alpha, log_prob, self.critic(obs, action))
            self._optimizer_step(self.actor_opt, torch.autograd.grad(loss_pi.sum(), self.actor_opt.params), mask)
            with torch.no_grad():
                _, fresh_log_prob = self.actor.sample(obs, noise[:, 2])
            loss_alpha = temperature_loss(self.log_alpha, fresh_log_prob, self.target_entropy)
            self._optimizer_step(self.alpha_opt, torch.autograd.grad(loss_alpha.sum(), self.alpha_opt.params), mask)
        self._update_target(mask)
        return self._metrics(loss_q.detach(), loss_pi.detach(), loss_alpha.detach(), q.detach(), target_q,
                             fresh_log_prob, reward)

    def _metrics(self, loss_q, loss_pi, loss_alpha, q, target_q, log_prob, reward) -> dict[str, torch.Tensor]:
        """Per-member (E,) diagnostics of one update (no host sync)."""
        return {
            "critic_loss": loss_q,
            "actor_loss": loss_pi,
            "alpha_loss": loss_alpha,
            "alpha": self.alpha,
            "q1": q[:, 0].mean(dim=1),
            "target_q": target_q.mean(dim=1),
            "log_prob": log_prob.mean(dim=1),
            "entropy": -log_prob.mean(dim=1),
            "batch_reward": reward.mean(dim=1),
        }

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




def use_static_updates(algo, compile: bool = False) -> int:
    """Switch every SAC agent that ``algo`` holds as an attribute to :meth:`SAC.use_static_update`; returns how many
    (the forward and backward agents of MEDAL, the one agent of RISC, ...)."""
    agents = [a for a in vars(algo).values() if isinstance(a, SAC)]
    for agent in agents:
        agent.use_static_update(compile)
    return len(agents)


def set_update_mode(algo, update: str) -> int:
    """Run ``algo``'s SAC updates in mode ``update`` (one of :data:`UPDATES`): nothing to do for the default; autograd:
    :meth:`SAC.use_autograd_update` on every agent; else :func:`use_static_updates` (compiled: through
    ``torch.compile``). Returns how many agents were switched."""
    if update not in UPDATES:
        raise ValueError(f"unknown update {update!r}; known: {', '.join(UPDATES)}")
    if update == "default":
        return 0
    agents = [a for a in vars(algo).values() if isinstance(a, SAC)]
    for agent in agents:
        agent.use_update(update)
    return len(agents)
