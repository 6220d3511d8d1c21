"""Member-batched Adam and Polyak averaging with per-member masks (ALGORITHMS.md §3.2-§3.3).

Both operate on :class:`FlatMembers`: the parameters of one network re-pointed into ONE contiguous vector, so an
optimizer step or a target update is a handful of elementwise ops over that vector (no loop over parameters or
members). Every parameter must have a leading dimension E * k stored member-major (k = 1 for plain layers, k = copies
for replicated heads); element j of the flat vector then belongs to member ``member_index[j]``.

Masking: members whose mask entry is False are left bitwise unchanged (parameters, Adam moments, step counters), i.e.
exactly as in a single-seed run in which that member did not update at this step. The arithmetic uses only correctly
rounded primitive ops (no fused lerp/addcmul), so member i's result does not depend on where its values sit in the
vector (SIMD body vs. tail): an E-member run reproduces E single-seed runs bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn


class FlatMembers:
    """Views ``params`` as one flat vector ``self.flat`` (the parameters' storage is moved into it, in place).

    Call this AFTER moving the module to its device: ``module.to(...)`` re-allocates parameters and breaks the aliasing.
    ``module.load_state_dict`` copies in place and is safe.
    """

    def __init__(self, params: Sequence[nn.Parameter], num_members: int):
        self.params = list(params)
        self.num_members = num_members
        for p in self.params:
            if p.shape[0] % num_members:
                raise ValueError(f"parameter leading dim {p.shape[0]} is not a multiple of E={num_members}")
        with torch.no_grad():
            self.flat = torch.cat([p.detach().reshape(-1) for p in self.params])
            offset = 0
            for p in self.params:
                p.data = self.flat[offset : offset + p.numel()].view_as(p)
                offset += p.numel()
        device = self.flat.device
        # member of every flat element; None for E=1, where per-member scalars simply broadcast
        self.member_index = (
            None
            if num_members == 1
            else torch.cat(
                [torch.arange(num_members, device=device).repeat_interleave(p.numel() // num_members) for p in self.params]
            )
        )

    def per_element(self, values: torch.Tensor) -> torch.Tensor:
        """Broadcast a per-member tensor (E,) to the flat layout (N,) (or (1,) when E=1)."""
        return values if self.member_index is None else values[self.member_index]

    def flat_grad(self, grads: Sequence[torch.Tensor | None] | None = None) -> torch.Tensor:
        """Concatenate ``grads`` (default: the ``.grad`` fields; None counts as zero) into the flat layout."""
        grads = [p.grad for p in self.params] if grads is None else grads
        return torch.cat([(torch.zeros_like(p) if g is None else g).reshape(-1) for p, g in zip(self.params, grads)])

    def masked_assign(self, dst: torch.Tensor, new: torch.Tensor, mask: torch.Tensor | None) -> None:
        """dst <- new for members with mask True (all members when mask is None)."""
        dst.copy_(new if mask is None else torch.where(self.per_element(mask), new, dst))


class MemberAdam:
    """Adam (PyTorch's formula incl. bias correction; no weight decay, no amsgrad) with per-member step counters.

    ``step(mask)`` only changes members with mask True: parameters, exp_avg, exp_avg_sq and step. Matches
    ``torch.optim.Adam`` on an E=1 run to float rounding (~1e-7 relative).
    """

    def __init__(
        self,
        params: Sequence[nn.Parameter],
        num_members: int,
        lr: float = 3e-4,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ):
        self.lr, self.betas, self.eps = lr, betas, eps
        self.members = FlatMembers(params, num_members)
        flat = self.members.flat
        self.exp_avg = torch.zeros_like(flat)
        self.exp_avg_sq = torch.zeros_like(flat)
        self.step_count = torch.zeros(num_members, dtype=torch.float32, device=flat.device)  # like torch's float step

    @property
    def params(self) -> list[nn.Parameter]:
        return self.members.params

    @torch.no_grad()
    def step(self, mask: torch.Tensor | None = None, grads: Sequence[torch.Tensor | None] | None = None) -> None:
        """One Adam step for the members in ``mask`` (bool (E,) on the parameters' device; None = all members).

        ``grads``: gradients aligned with the parameters (e.g. from ``torch.autograd.grad``); default their ``.grad``.
        """
        beta1, beta2 = self.betas
        members = self.members
        g = members.flat_grad(grads)
        step = self.step_count + 1
        # bias corrections in float64 like torch's Python-float path, then one float32 scalar per member
        step64 = step.double()
        step_size = members.per_element((self.lr / (1 - beta1**step64)).float())
        inv_bc2_sqrt = members.per_element((1 / torch.sqrt(1 - beta2**step64)).float())

        exp_avg = self.exp_avg + (g - self.exp_avg) * (1 - beta1)  # = lerp(exp_avg, g, 1 - beta1)
        exp_avg_sq = self.exp_avg_sq * beta2 + (g * g) * (1 - beta2)
        denom = exp_avg_sq.sqrt() * inv_bc2_sqrt + self.eps
        param = members.flat - (exp_avg * step_size) / denom

        for dst, new in ((self.exp_avg, exp_avg), (self.exp_avg_sq, exp_avg_sq), (members.flat, param)):
            members.masked_assign(dst, new, mask)
        self.step_count.copy_(step if mask is None else torch.where(mask, step, self.step_count))

    def state_dict(self) -> dict:
        return {
            "exp_avg": self.exp_avg.clone(),
            "exp_avg_sq": self.exp_avg_sq.clone(),
            "step": self.step_count.clone(),
            "lr": self.lr,
            "betas": self.betas,
            "eps": self.eps,
        }

    def load_state_dict(self, state: dict) -> None:
        self.exp_avg.copy_(state["exp_avg"])
        self.exp_avg_sq.copy_(state["exp_avg_sq"])
        self.step_count.copy_(state["step"])
        self.lr, self.betas, self.eps = state["lr"], tuple(state["betas"]), state["eps"]


@torch.no_grad()
def polyak_update(target: FlatMembers, source: FlatMembers, tau: float, mask: torch.Tensor | None = None) -> None:
    """target <- (1 - tau) * target + tau * source for members in ``mask`` (ALGORITHMS.md §3.2 step 4)."""
    target.masked_assign(target.flat, target.flat + (source.flat - target.flat) * tau, mask)
