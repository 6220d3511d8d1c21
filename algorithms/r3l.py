"""R3L: the backward ("perturbation") policy maximises RND novelty (docs/algorithms.md section 7; Zhu et al., ICLR 2020).

The forward policy attempts the task from the new state the backward policy reaches in each trial. State-based, with
the env's task reward for the forward policy (as in the EARL/MEDAL experiments: 1[success], or EARL's dense reward
on kitchen and minitaur).

Fixed by the sources (7.1): forward SAC on the task reward, buffer <- forward demos; backward SAC rewarded by Random
Network Distillation novelty (Burda et al. 2018): a frozen random target f and a trained, deeper predictor f^ map the
normalised state to features; novelty = mean over features of (f^(x) - f(x))^2. The backward buffer holds NO backward
demos (they would look non-novel before the backward policy ever visited them): it starts empty, so the backward agent
updates only once it has stored a transition.

DEFAULTs of section 7.2 (NOT FOUND in the sources), used here:
- switching as MEDAL: 300-step phases, the forward phase ends early on task success, the backward phase never does;
  hard reset -> forward phase. Backward observation [s, g_task] with g_task the goal the next forward phase pursues
  (MEDAL's conditioning, :meth:`ForwardBackward.next_goal`); RND sees the STATE half only.
- RND target state -> 256 -> 256 -> 512, predictor state -> 256 -> 256 -> 256 -> 512 (ReLU; member-batched
  :class:`MemberMLP` with the core's Xavier init rather than [NC]'s orthogonal one), Adam 3e-4 (:class:`MemberAdam`).
- states normalised by a running mean/std over every backward state stored, clipped to +-5;
- reward of a sampled backward transition = novelty(s') / running std of novelty, recomputed at sample time with the
  current predictor (the running std is updated with every batch of novelties computed this way); the x10 reward
  scale of section 3 is kept;
- one predictor step on the backward SAC batch's next states (256 backward-buffer states) each time the backward
  agent updates, after that update.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from algorithms.api import DemoSet, Task, setting
from algorithms.core.nets import MemberMLP, Stream, host_mask, member_generators
from algorithms.core.optim import MemberAdam
from algorithms.forward_backward import ForwardBackward, ForwardBackwardConfig


@dataclass
class R3LConfig(ForwardBackwardConfig):
    rnd_hidden: int = setting(256, "hidden width of the RND networks", ge=1, le=65_536)
    rnd_features: int = setting(512, "RND embedding width", ge=1, le=65_536)
    rnd_lr: float = setting(3e-4, "Adam learning rate of the RND predictor", gt=0, le=1)
    rnd_obs_clip: float = setting(5.0, "clip of the normalised RND input", gt=0, le=1e6)


class RunningMeanStd:
    """Per-member running mean and (population) variance of a stream, merged batch by batch (Chan et al.), float64.

    ``update(x (E, B, *shape), mask)``: members outside ``mask`` are left unchanged."""

    def __init__(self, num_members: int, shape: tuple[int, ...], device):
        self.device = torch.device(device)
        self.count = torch.zeros(num_members, dtype=torch.float64, device=self.device)
        self.mean = torch.zeros((num_members, *shape), dtype=torch.float64, device=self.device)
        self.m2 = torch.zeros_like(self.mean)  # sum of squared deviations

    @torch.no_grad()
    def update(self, x: torch.Tensor, mask=None) -> None:
        x = x.double()
        n = x.shape[1]
        count = self.count.view(-1, *[1] * (self.mean.dim() - 1))
        batch_mean = x.mean(1)
        delta = batch_mean - self.mean
        total = count + n
        mean = self.mean + delta * (n / total)
        m2 = self.m2 + (x - batch_mean.unsqueeze(1)).square().sum(1) + delta.square() * (count * n / total)
        keep = host_mask(mask, len(self.count))
        keep = torch.ones(len(self.count), dtype=torch.bool) if keep is None else torch.as_tensor(keep)
        keep = keep.to(self.device)
        self.mean = torch.where(keep.view_as(count), mean, self.mean)
        self.m2 = torch.where(keep.view_as(count), m2, self.m2)
        self.count = torch.where(keep, self.count + n, self.count)

    @property
    def std(self) -> torch.Tensor:
        """sqrt(variance), 1 before any data; float32 (E, *shape)."""
        count = self.count.view(-1, *[1] * (self.mean.dim() - 1))
        var = torch.where(count > 0, self.m2 / count.clamp_min(1), torch.ones_like(self.m2))
        return var.sqrt().clamp_min(1e-8).float()

    def state_dict(self) -> dict:
        return {"count": self.count.clone(), "mean": self.mean.clone(), "m2": self.m2.clone()}

    def load_state_dict(self, state: dict) -> None:
        self.count, self.mean, self.m2 = (state[k].to(self.device) for k in ("count", "mean", "m2"))


class RND:
    """E members' random network distillation on states (E, B, state_dim) (7.1-7.2)."""

    def __init__(self, state_dim: int, seeds: list[int], device, hidden: int, features: int, lr: float, clip: float):
        E = len(seeds)
        gens = member_generators(seeds, "cpu", Stream.RND_INIT)
        self.target = MemberMLP(E, [state_dim, hidden, hidden, features], gens).to(device).requires_grad_(False)
        self.predictor = MemberMLP(E, [state_dim, hidden, hidden, hidden, features], gens).to(device)
        self.opt = MemberAdam(list(self.predictor.parameters()), E, lr=lr)
        self.obs_rms = RunningMeanStd(E, (state_dim,), device)
        self.novelty_rms = RunningMeanStd(E, (), device)
        self.clip, self.device = clip, torch.device(device)

    def novelty(self, states: torch.Tensor) -> torch.Tensor:
        """mean_features (f^(x) - f(x))^2, x = clip((s - mean) / std, +-5); (E, B)."""
        mean = self.obs_rms.mean.float().unsqueeze(1)
        x = ((states - mean) / self.obs_rms.std.unsqueeze(1)).clamp(-self.clip, self.clip)
        return (self.predictor(x) - self.target(x)).square().mean(-1)

    @torch.no_grad()
    def reward(self, states: torch.Tensor, mask) -> torch.Tensor:
        """Normalised novelty (E, B): the running std of novelty is updated with this batch first."""
        novelty = self.novelty(states)
        self.novelty_rms.update(novelty, mask)
        return novelty / self.novelty_rms.std.unsqueeze(-1)

    def update(self, states: torch.Tensor, mask) -> torch.Tensor:
        """One predictor step on its own squared error for members in ``mask``; per-member loss (E,)."""
        loss = self.novelty(states).mean(1)
        grads = torch.autograd.grad(loss.sum(), self.opt.params)
        self.opt.step(mask, grads)
        return loss.detach()

    def state_dict(self) -> dict:
        return {"predictor": self.predictor.state_dict(), "target": self.target.state_dict(),
                "opt": self.opt.state_dict(), "obs_rms": self.obs_rms.state_dict(),
                "novelty_rms": self.novelty_rms.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.predictor.load_state_dict(state["predictor"])
        self.target.load_state_dict(state["target"])
        self.opt.load_state_dict(state["opt"])
        self.obs_rms.load_state_dict(state["obs_rms"])
        self.novelty_rms.load_state_dict(state["novelty_rms"])


class R3L(ForwardBackward):
    """Forward task policy + backward policy seeking RND-novel states."""

    label = "R3L"
    Config = R3LConfig
    state_goals = False  # goals are only ever task goals
    task_reward = True  # the forward controller learns from the task's reward (dense on kitchen and minitaur)

    def __init__(self, task: Task, demos: DemoSet, cfg: R3LConfig, seeds: list[int], device: torch.device):
        super().__init__(task, demos, cfg, seeds, device)
        self.rnd = RND(task.state_dim, seeds, device, cfg.rnd_hidden, cfg.rnd_features, cfg.rnd_lr, cfg.rnd_obs_clip)

    def _states(self, obs) -> torch.Tensor:
        return torch.as_tensor(obs, device=self.device)[..., : self.task.state_dim]

    def backward_reward(self, batch, mask):
        return self.rnd.reward(self._states(batch["next_obs"]), mask)

    def on_backward_states(self, obs, mask):
        self.rnd.obs_rms.update(self._states(obs).unsqueeze(1), mask)

    def learn_extra(self, bwd_batch, bwd_mask):
        if bwd_batch is not None:
            with self.timers("rnd"):
                loss = self.rnd.update(self._states(bwd_batch["next_obs"]), bwd_mask)
            self.log.add("rnd/", {"predictor_loss": loss}, bwd_mask)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "rnd": self.rnd.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.rnd.load_state_dict(state["rnd"])

    def metrics(self) -> dict[str, np.ndarray]:
        return {**super().metrics(), "rnd/novelty_std": self.rnd.novelty_rms.std.cpu().numpy().astype(np.float64)}
