"""BC: behaviour cloning on the forward demos (docs/algorithms.md section 12, [MP] section 5.2).

No environment interaction. DEFAULTs (NOT FOUND: loss, architecture, steps): the section-3 actor on o = [s, g_demo]
(trunk 50 + LayerNorm + Tanh, 2 x 256, squashed Gaussian head), Adam 3e-4, batches of 256 demo pairs drawn with
replacement, 20,000 gradient steps, then frozen. Loss: ``loss="mse"`` (default here, the card's alternative) =
mean (tanh(mu(o)) - a_demo)^2, which trains exactly the action that is evaluated; ``loss="nll"`` (the card's first
option) = -log pi(a_demo | o) with a_demo clipped to +-(1 - 1e-6). Evaluation: deterministic tanh(mu), the section
1.3 protocol.

Inside the protocol loop, ``act`` takes ONE gradient step per protocol step and returns zero actions; the loop still
steps the train env (harmless: nothing observed is used). So for BC the x-axis "training steps" of the results is
gradient steps (constant after ``grad_steps``). Data: forward demos, tabletop 1,278 / door 395 / peg 683 pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import AlgoConfig, Algorithm, DemoSet, Task, setting
from algorithms.common import TrainLog
from algorithms.core.buffer import StateBuffer
from algorithms.core.losses import squashed_gaussian_log_prob
from algorithms.core.nets import Stream, member_generators
from algorithms.core.optim import MemberAdam
from algorithms.core.sac import Actor, SACConfig

ACTION_CLIP = 1 - 1e-6


@dataclass
class BCConfig(AlgoConfig):
    lr: float = setting(3e-4, "Adam learning rate", gt=0, le=1)
    batch_size: int = setting(256, "demo transitions per gradient step", ge=1, le=65_536)
    grad_steps: int = setting(20_000, "gradient steps, then the policy is frozen; 0 = no limit", ge=0, le=10**9)
    loss: str = setting("mse", "mse on tanh(mu), or nll = -log pi(a_demo | o)", choices=("mse", "nll"))


class BC(Algorithm):
    """Behaviour cloning of the forward demos with the SAC actor."""

    label = "BC"
    Config = BCConfig
    needs_demos = True  # the forward demos are its only data

    def __init__(self, task: Task, demos: DemoSet, cfg: BCConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        O, A = task.obs_dim, task.act_dim
        self.actor = Actor(self.E, O, A, SACConfig(), member_generators(seeds)).to(device)
        self.opt = MemberAdam(list(self.actor.parameters()), self.E, lr=cfg.lr)
        pairs = np.concatenate([demos.forward.observations, demos.forward.actions], 1).astype(np.float32)
        self.data = StateBuffer(self.E, len(pairs), O + A, device, seeds, stream=Stream.REPLAY, name="demo pairs")
        self.data.extend(pairs)
        self.grad_step = 0
        self.log = TrainLog(self.E, device)

    def loss(self, pairs: torch.Tensor) -> torch.Tensor:
        """Per-member loss (E,) on demo pairs (E, B, O + A)."""
        obs, action = pairs.split([self.task.obs_dim, self.task.act_dim], dim=-1)
        mean, log_std = self.actor(obs)
        if self.cfg.loss == "mse":
            return (torch.tanh(mean) - action).square().mean(dim=(1, 2))
        if self.cfg.loss == "nll":
            u = torch.atanh(action.clamp(-ACTION_CLIP, ACTION_CLIP))
            return -squashed_gaussian_log_prob(u, (u - mean) / log_std.exp(), log_std).mean(1)
        raise ValueError(f"unknown BC loss {self.cfg.loss!r} (expected 'mse' or 'nll')")

    def train_step(self) -> torch.Tensor:
        loss = self.loss(self.data.sample(self.cfg.batch_size))
        self.opt.step(None, torch.autograd.grad(loss.sum(), self.opt.params))
        self.grad_step += 1
        return loss.detach()

    # -- the protocol interface -----------------------------------------------------------------------------------
    def on_reset(self, obs: np.ndarray, mask: np.ndarray) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The env gets zero actions (BC learns from the demos only)."""
        return np.zeros((self.E, self.task.act_dim), dtype=np.float32)

    def update(self) -> None:
        """One gradient step on demo pairs (until ``grad_steps``)."""
        if not self.cfg.grad_steps or self.grad_step < self.cfg.grad_steps:
            self.log.add("bc/", {"loss": self.train_step()})

    def observe(self, next_obs: np.ndarray, hard_reset: np.ndarray) -> np.ndarray:
        return np.zeros(self.E, dtype=bool)

    @torch.no_grad()
    def eval_act(self, obs: np.ndarray) -> np.ndarray:
        mean, _ = self.actor(torch.as_tensor(obs, device=self.device).unsqueeze(1))
        return torch.tanh(mean).squeeze(1).cpu().numpy()

    def metrics(self) -> dict[str, np.ndarray]:
        return self.log.pop()

    # -- checkpointing --------------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"actor": self.actor.state_dict(), "opt": self.opt.state_dict(), "data": self.data.state_dict(),
                "grad_step": self.grad_step}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.actor.load_state_dict(state["actor"])
        self.opt.load_state_dict(state["opt"])
        self.data.load_state_dict(state["data"])
        self.grad_step = state["grad_step"]

