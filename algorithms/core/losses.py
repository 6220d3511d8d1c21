"""The math of one SAC update (docs/algorithms.md §3.2) as plain functions: the squashed Gaussian policy's log
probability, and the three losses, each per member (E,) and each beside its hand-derived gradient.

Both update paths of :class:`~algorithms.core.sac.SAC` use them: ``update="autograd"`` differentiates the losses with
torch.autograd; the other modes run the gradient written under each loss through the hand-written backward passes of
:mod:`~algorithms.core.manual`. To change a loss, edit it here and train with ``update=autograd``, which needs no
gradient; then write its gradient (tests/test_core_sac.py compares the two paths update by update).
"""

from __future__ import annotations

import math

import torch
from torch import nn

HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


def squashed_gaussian_log_prob(u: torch.Tensor, eps: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log pi(tanh(u)) for u = mu + sigma * eps, summed over the last dim (§3.2):
    sum_d [ log N(u; mu, sigma) - 2 * (log 2 - u - softplus(-2u)) ], the second term being log(1 - tanh(u)^2)."""
    normal = -0.5 * eps.square() - log_std - HALF_LOG_2PI
    log_det = 2.0 * (math.log(2.0) - u - nn.functional.softplus(-2.0 * u))
    return (normal - log_det).sum(-1)


def squashed_gaussian_backward(d_action, d_log_prob, action, std, eps, log_std_raw, bounds) -> torch.Tensor:
    """The gradient of a = tanh(mu + sigma * eps) and its log pi with respect to the actor's raw output (mean, log sigma
    before the clamp), from dL/da and dL/d log pi: d log pi / du = 2 tanh(u) (the tanh Jacobian's term),
    d log pi / d log sigma = -1 at fixed eps, and no gradient where the clamp to ``bounds`` is active."""
    d_u = d_log_prob * 2.0 * action + d_action * (1.0 - action * action)
    in_range = (log_std_raw >= bounds[0]) & (log_std_raw <= bounds[1])
    d_log_std = (d_u * std * eps - d_log_prob) * in_range
    return torch.cat([d_u, d_log_std], -1)


def critic_loss(q: torch.Tensor, target_q: torch.Tensor) -> torch.Tensor:
    """0.5 * (MSE(Q1, y) + MSE(Q2, y)) for the heads q (E, 2, B) and the TD target y (E, B)."""
    return 0.5 * (q - target_q.unsqueeze(1)).square().mean(dim=2).sum(dim=1)


def critic_loss_grad(q: torch.Tensor, target_q: torch.Tensor) -> torch.Tensor:
    """d critic_loss / d q = (q - y) / B, (E, 2, B)."""
    return (q - target_q.unsqueeze(1)) / q.shape[2]


def actor_loss(alpha: torch.Tensor, log_prob: torch.Tensor, q_pi: torch.Tensor) -> torch.Tensor:
    """mean_b (alpha * log pi(a|o) - min_j Q_j(o, a)) for a ~ pi(.|o): alpha (E,), log_prob (E, B), q_pi (E, 2, B)."""
    return (alpha[:, None] * log_prob - q_pi.min(dim=1).values).mean(dim=1)


def actor_loss_grads(alpha: torch.Tensor, q_pi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(d actor_loss / d q_pi: -1/B at the smaller head, 0 at the other, (E, 2, B); d actor_loss / d log pi: alpha / B,
    (E, 1, 1))."""
    B = q_pi.shape[2]
    d_q = torch.zeros_like(q_pi).scatter_(1, q_pi.min(dim=1).indices.unsqueeze(1), -1.0 / B)
    return d_q, (alpha / B)[:, None, None]


def temperature_loss(log_alpha: torch.Tensor, log_prob: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """alpha * mean_b (-log pi(a|o) - H_target); its gradient with respect to log alpha is the loss itself."""
    return log_alpha.exp() * (-log_prob - target_entropy).mean(dim=1)
