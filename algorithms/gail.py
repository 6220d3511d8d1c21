"""naive GAIL / oracle GAIL, implemented as DAC (Discriminator-Actor-Critic) on the SAC core (docs/algorithms.md section 13).

DAC (Kostrikov et al. 2018) is an off-policy GAIL: a discriminator D(o, a) separates the forward demos' (o, a) pairs
from the agent's, and the learner maximises the reward r = log D - log(1 - D), i.e. D's logit ([DC] "airl" default),
computed at sample time with the current D. [MP] runs it reset-free (naive GAIL: like naive RL, section 4) and
episodically (oracle GAIL: like oracle RL, section 5).

DEFAULTs of section 13.3 (NOT FOUND what MEDAL used), used here:
- learner: the SAC core (section 3), obs = [s, g], the DAC reward only (no task reward), reward scale 10;
- discriminator: DAC's architecture, MLP (o, a) -> 256 -> tanh -> 256 -> tanh -> 1 logit, member-batched with the
  core's Xavier init (not [DC]'s orthogonal init); loss = BCE (demo pairs label 1, agent pairs label 0) + 10 x
  E[(||grad_x D(x)|| - 1)^2] at x = u x_agent + (1 - u) x_demo, u ~ U(0, 1) per pair; Adam 3e-4 (MemberAdam);
  one step per env step after the seed phase, after the SAC update, on ``batch_size`` (256) demo pairs (with
  replacement) + the SAC batch's pairs as agent pairs (uniform from the replay buffer, which also holds the demos);
  no mixup; demo and policy actions are not clipped (13.4's saturated tabletop grasp is left as is);
- no early termination on success in either variant and episode ends treated as time-outs (bootstrapped:
  ``bootstrap_on_truncation=True``), hence no absorbing states; the forward demos' ends too (``end_on_success``
  False: stored truncated, not terminal, so a demo's last step bootstraps as the agent's own steps do);
- replay buffer <- forward demos (their stored rewards are replaced by D-rewards at sample time);
- naive GAIL: 300-step pseudo-episodes in the train env, task goal re-drawn per pseudo-episode, hard reset at H_T;
  oracle GAIL: an env reset every H_E steps, uniform random actions in the seed phase (as oracle RL).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from algorithms.api import DemoSet, Task, setting
from algorithms.core.buffer import StateBuffer
from algorithms.core.discriminator import Discriminator
from algorithms.core.nets import MemberLinear, Stream, member_generators, member_randn
from algorithms.core.optim import MemberAdam
from algorithms.naive import Naive, NaiveConfig
from algorithms.oracle import Oracle, OracleConfig


def gradient_penalty(logits: Callable[[torch.Tensor], torch.Tensor], expert: torch.Tensor, agent: torch.Tensor,
                     u: torch.Tensor, weight: float = 10.0) -> torch.Tensor:
    """weight * mean_B (||grad_x logits(x)||_2 - 1)^2 at x = u * agent + (1 - u) * expert; per member (E,).
    expert, agent (E, B, d); u (E, B, 1). Differentiable w.r.t. the discriminator's parameters."""
    x = (u * agent + (1 - u) * expert).detach().requires_grad_(True)
    (grad,) = torch.autograd.grad(logits(x).sum(), x, create_graph=True)
    return weight * (grad.norm(dim=-1) - 1).square().mean(-1)


class TanhMLP(nn.Module):
    """Member-batched Linear -> tanh -> ... -> Linear over ``dims`` (DAC's discriminator, 13.2)."""

    def __init__(self, num_members: int, dims: list[int], generators):
        super().__init__()
        self.layers = nn.ModuleList(MemberLinear(num_members, a, b, generators) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers[:-1]:
            x = torch.tanh(layer(x))
        return self.layers[-1](x)


class DACDiscriminator(Discriminator):
    """E members' D(o, a): 2 x 256 tanh MLP logit, BCE + gradient penalty, MemberAdam (13.2-13.3). Reuses the MEDAL
    discriminator's logits / prob / checkpointing with its own network, noise stream, reward and loss."""

    def __init__(self, in_dim: int, seeds: list[int], device, hidden: int, lr: float, gp_weight: float):
        super().__init__(in_dim, seeds, device, hidden_dim=hidden, lr=lr, mixup=False)
        gens = member_generators(self.seeds, "cpu", Stream.DAC_INIT)
        self.net = TanhMLP(self.num_members, [in_dim, hidden, hidden, 1], gens).to(self.device)
        self.opt = MemberAdam(list(self.net.parameters()), self.num_members, lr=lr)
        self.generators = member_generators(self.seeds, self.device, Stream.DAC_NOISE)
        self.gp_weight = gp_weight

    @torch.no_grad()
    def reward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """r = log D - log(1 - D) = the logit (E, B), current D, gradient stopped."""
        return self.logits(torch.cat([obs, action], -1))

    def update(self, expert: torch.Tensor, agent: torch.Tensor) -> dict[str, torch.Tensor]:
        """One Adam step for every member on expert / agent pairs (E, B, in_dim)."""
        u = torch.special.ndtr(member_randn(self.generators, (expert.shape[1], 1), None, self.device))  # U(0, 1)
        bce = 0.5 * (F.softplus(-self.logits(expert)).mean(1) + F.softplus(self.logits(agent)).mean(1))
        penalty = gradient_penalty(self.logits, expert, agent, u, self.gp_weight)
        self.opt.step(None, torch.autograd.grad((bce + penalty).sum(), self.opt.params))
        return {"discriminator_loss": bce.detach(), "gradient_penalty": penalty.detach()}


@dataclass
class DACFields:
    """What GAIL adds to (or changes in) the naive / oracle configs."""

    disc_hidden: int = setting(256, "hidden width of the DAC discriminator", ge=1, le=65_536)
    disc_lr: float = setting(3e-4, "Adam learning rate of the discriminator", gt=0, le=1)
    gp_weight: float = setting(10.0, "gradient-penalty weight", ge=0, le=1e6)
    end_on_success: bool = False
    bootstrap_on_truncation: bool = True


class DAC:
    """The GAIL part, mixed into :class:`Naive` / :class:`Oracle` through their reward / learn_extra hooks."""

    needs_demos = True  # the discriminator's expert (obs, action) pairs are the forward demos

    def __init__(self, task: Task, demos: DemoSet, cfg, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        pairs = np.concatenate([demos.forward.observations, demos.forward.actions], 1).astype(np.float32)
        in_dim = pairs.shape[1]
        self.disc = DACDiscriminator(in_dim, seeds, device, cfg.disc_hidden, cfg.disc_lr, cfg.gp_weight)
        self.expert = StateBuffer(self.E, len(pairs), in_dim, device, seeds, stream=Stream.EXPERT_STATES,
                                  name="demo pairs")
        self.expert.extend(pairs)

    def reward(self, batch):
        return self.disc.reward(batch["obs"], batch["action"])

    def learn_extra(self, batch):
        with self.timers("discriminator"):
            agent = torch.cat([batch["obs"], batch["action"]], -1)
            self.log.add("discriminator/", self.disc.update(self.expert.sample(agent.shape[1]), agent))

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "disc": self.disc.state_dict(), "expert": self.expert.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.disc.load_state_dict(state["disc"])
        self.expert.load_state_dict(state["expert"])


@dataclass
class GAILNaiveConfig(DACFields, NaiveConfig):
    pass


@dataclass
class GAILOracleConfig(DACFields, OracleConfig):
    pass


class GAILNaive(DAC, Naive):
    """naive GAIL: DAC reset-free, 300-step pseudo-episodes."""

    label = "naive GAIL"
    Config = GAILNaiveConfig


class GAILOracle(DAC, Oracle):
    """oracle GAIL: DAC with an env reset every H_E steps."""

    label = "oracle GAIL"
    Config = GAILOracleConfig
