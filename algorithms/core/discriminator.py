"""MEDAL state discriminator C(s) for E members (docs/algorithms.md §9.3, §9.6, §10).

Linear(obs -> 128) -> ReLU -> Linear(128 -> 1) logit; C = sigmoid(logit). Label 1 = forward-demo states (positives),
label 0 = states visited by the backward policy (negatives). One update = BCE on 400 positives + 400 negatives with
mixup [MC]: per example a coefficient lambda ~ Beta(1, 1) (= Uniform(0, 1), drawn with ``torch.rand``), a partner from a
random permutation of the combined 800-batch, and BOTH inputs and soft labels mixed:
x = lambda * x_i + (1 - lambda) * x_perm(i), y = lambda * y_i + (1 - lambda) * y_perm(i).
[MC] applies ``BCELoss`` to ``sigmoid(logit)``; we use ``binary_cross_entropy_with_logits`` (same value, numerically
stable, without BCELoss's clamp of log at -100). Adam lr 3e-4 (:class:`MemberAdam`).

Deviation (documented): the layers are initialised like every network here (Xavier-uniform weights, zero biases);
[MC] never applies its ``weight_init`` to the discriminator, so it keeps ``nn.Linear``'s default (weights and biases
U(-1/sqrt(fan_in), 1/sqrt(fan_in))). MEDAL passes its tabletop check with this initialisation (docs/reproduction.md,
cell 1); changing it would change every MEDAL curve, so it stays.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from .nets import MemberMLP, Stream, generator_states, host_mask, load_generator_states, member_generators
from .optim import MemberAdam

REWARD_EPS = 1e-10  # §9.3 [MC] discrim_eps; §10 DEFAULT uses the same epsilon


def discriminator_reward(prob: torch.Tensor, form: str = "medal") -> torch.Tensor:
    """Backward reward from C(s'): "medal" -log(1 - C + 1e-10) (§9.3) or "logc" log(C + 1e-10) (§10)."""
    if form == "medal":
        return -torch.log(1.0 - prob + REWARD_EPS)
    if form == "logc":
        return torch.log(prob + REWARD_EPS)
    raise ValueError(f"unknown discriminator reward form {form!r} (expected 'medal' or 'logc')")


class Discriminator:
    """E independent MEDAL discriminators; member i is determined by ``seeds[i]`` (init and mixup draws)."""

    def __init__(self, obs_dim: int, seeds: Sequence[int], device="cpu", hidden_dim: int = 128, lr: float = 3e-4,
                 mixup: bool = True):
        self.seeds = list(seeds)
        self.num_members = E = len(self.seeds)
        self.device = torch.device(device)
        self.mixup = mixup
        self.net = MemberMLP(E, [obs_dim, hidden_dim, 1], member_generators(self.seeds)).to(self.device)
        self.opt = MemberAdam(list(self.net.parameters()), E, lr=lr)
        self.generators = member_generators(self.seeds, self.device, Stream.MIXUP)

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """x (E, B, obs_dim) -> logits (E, B)."""
        return self.net(x).squeeze(-1)

    @torch.no_grad()
    def prob(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(x))

    @torch.no_grad()
    def reward(self, next_obs: torch.Tensor, form: str = "medal") -> torch.Tensor:
        """Backward reward (E, B) from the CURRENT discriminator on next observations, gradient stopped (§9.6)."""
        return discriminator_reward(self.prob(next_obs), form)

    def mix(self, pos: torch.Tensor, neg: torch.Tensor, mask) -> tuple[torch.Tensor, torch.Tensor]:
        """Inputs (E, P+N, d) and labels (E, P+N): the mixup batch (or the plain one if mixup is off)."""
        E, P, _ = pos.shape
        x = torch.cat([pos, neg], dim=1)
        y = torch.cat([torch.ones(E, P, device=x.device), torch.zeros(E, neg.shape[1], device=x.device)], dim=1)
        if not self.mixup:
            return x, y
        n = x.shape[1]
        mask = host_mask(mask, E)
        # per member: n coefficients, then a permutation (members outside the mask draw nothing)
        lam, perm = [], []
        for i, g in enumerate(self.generators):
            active = mask is None or mask[i]
            lam.append(torch.rand(n, generator=g, device=x.device) if active else torch.ones(n, device=x.device))
            perm.append(torch.randperm(n, generator=g, device=x.device) if active else torch.arange(n, device=x.device))
        lam, perm = torch.stack(lam), torch.stack(perm)
        rows = torch.arange(E, device=x.device)[:, None]
        x = lam.unsqueeze(-1) * x + (1 - lam.unsqueeze(-1)) * x[rows, perm]
        y = lam * y + (1 - lam) * y[rows, perm]
        return x, y

    def update(self, pos: torch.Tensor, neg: torch.Tensor, mask=None) -> dict[str, torch.Tensor]:
        """One Adam step on BCE(mixup(pos (E,400,d), neg (E,400,d))) for members in ``mask``; per-member metrics:
        the loss, and (before the step, on the unmixed batch) the mean C on positives and on negatives and the
        balanced accuracy of C > 0.5."""
        with torch.no_grad():
            c_pos, c_neg = torch.sigmoid(self.logits(pos)), torch.sigmoid(self.logits(neg))
        x, y = self.mix(pos, neg, mask)
        loss = F.binary_cross_entropy_with_logits(self.logits(x), y, reduction="none").mean(dim=1)  # (E,)
        grads = torch.autograd.grad(loss.sum(), self.opt.params)
        self.opt.step(mask, grads)
        accuracy = 0.5 * ((c_pos > 0.5).float().mean(1) + (c_neg <= 0.5).float().mean(1))
        return {"discriminator_loss": loss.detach(), "c_positives": c_pos.mean(1), "c_negatives": c_neg.mean(1),
                "accuracy": accuracy}

    def state_dict(self) -> dict:
        return {"net": self.net.state_dict(), "opt": self.opt.state_dict(),
                "generators": generator_states(self.generators)}

    def load_state_dict(self, state: dict) -> None:
        self.net.load_state_dict(state["net"])
        self.opt.load_state_dict(state["opt"])
        load_generator_states(self.generators, state["generators"])
