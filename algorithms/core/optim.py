"""Member-batched Adam and Polyak averaging with per-member masks (docs/algorithms.md §3.2-§3.3).

Both operate on :class:`FlatMembers`: the parameters of one network re-pointed into ONE contiguous vector. Every
parameter must have a leading dimension E * k stored member-major (k = 1 for plain layers, k = copies for replicated
heads), so member i's part of parameter j is one contiguous slice, ``views[i][j]``. An optimizer step or a target update
is one multi-tensor kernel call over the slices of the members that update (no per-element Python, no mask arithmetic).

Masking: members whose mask entry is False are not in the call and stay bitwise unchanged (parameters, Adam moments,
step counters), exactly as in a single-seed run in which that member did not update at this step. Member i's slices
have the same sizes whatever E is and are processed alone, so member i's optimizer step is an E=1 run's bit for bit
(no dependence on where a value sits in a SIMD body or tail); the gradients it is given can still differ with E in
their last bits (batched products).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from .nets import host_mask


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
        self.views = self.member_views(self.flat)

    def param_views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        """Views of a tensor in the flat layout as one (E, n_j) view per parameter j: whole-tensor arithmetic with a
        per-member (E, 1) mask or scalar, as the static-shape paths use."""
        out, offset = [], 0
        for p in self.params:
            out.append(flat[offset : offset + p.numel()].view(self.num_members, -1))
            offset += p.numel()
        return out

    def member_views(self, flat: torch.Tensor) -> list[list[torch.Tensor]]:
        """Views of a tensor in the flat layout (the parameters themselves, or optimizer state shaped like them) as
        ``views[i][j]``: member i's contiguous slice of parameter j (with its replicas, member-major)."""
        per_param, offset = [], 0
        for p in self.params:
            per_param.append(flat[offset : offset + p.numel()].view(self.num_members, -1))
            offset += p.numel()
        return [[v[i] for v in per_param] for i in range(self.num_members)]

    def active(self, mask) -> list[int]:
        """The members to update: all for ``mask=None``, else the indices where the (E,) bool mask is True."""
        if mask is None:
            return list(range(self.num_members))
        return np.flatnonzero(host_mask(mask, self.num_members)).tolist()


class MemberAdam:
    """Adam (PyTorch's formula incl. bias correction; no weight decay, no amsgrad) with per-member step counters.

    ``step(mask)`` only changes members with mask True: parameters, exp_avg, exp_avg_sq and step. The arithmetic is
    PyTorch's own fused Adam kernel (``torch._fused_adam_``, the ``fused=True`` path of ``torch.optim.Adam``: one pass
    over each tensor), applied to the list of per-member slices of the members that update. Every member's slice of a
    parameter has the same size wherever it sits, so member i is processed exactly as in an E=1 run, bit for bit.
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
        self._views = {"param": self.members.views, "exp_avg": self.members.member_views(self.exp_avg),
                       "exp_avg_sq": self.members.member_views(self.exp_avg_sq)}
        # the static path reaches the parameters through the modules' own tensors (not views of ``flat``): a compiled
        # graph may then take them together with the forward pass's reads of the same parameters
        self._by_param = list(zip(self.members.params, self.members.param_views(self.exp_avg),
                                  self.members.param_views(self.exp_avg_sq)))

    @property
    def params(self) -> list[nn.Parameter]:
        return self.members.params

    @torch.no_grad()
    def step(self, mask=None, grads: Sequence[torch.Tensor | None] | None = None) -> None:
        """One Adam step for the members in ``mask`` (bool (E,), host array or tensor, see ``nets.host_mask``; None =
        all members). ``grads``: gradients aligned with the parameters (e.g. from ``torch.autograd.grad``); default
        their ``.grad`` (None counts as zero)."""
        members, E = self.members, self.members.num_members
        active = members.active(mask)
        if not active:
            return
        grads = [p.grad for p in self.params] if grads is None else grads
        grads = [(torch.zeros_like(p) if g is None else g).reshape(E, -1) for p, g in zip(self.params, grads)]
        if len(active) == E:
            self.step_count += 1
        else:
            self.step_count[active] += 1
        views, n = self._views, len(self.params)
        beta1, beta2 = self.betas
        torch._fused_adam_(
            [v for i in active for v in views["param"][i]],
            [g[i] for i in active for g in grads],
            [v for i in active for v in views["exp_avg"][i]],
            [v for i in active for v in views["exp_avg_sq"][i]],
            [],
            [self.step_count[i] for i in active for _ in range(n)],
            lr=self.lr, beta1=beta1, beta2=beta2, weight_decay=0.0, eps=self.eps, amsgrad=False, maximize=False,
        )

    @torch.no_grad()
    def step_masked(self, mask: torch.Tensor, grads: Sequence[torch.Tensor]) -> None:
        """:meth:`step` as whole-tensor arithmetic: ``mask`` is a bool (E,) tensor on the device, every member is
        computed and those outside ``mask`` keep their values (``torch.where``). No host decision and static shapes,
        so it can be captured (CUDA graphs) or compiled; equal to :meth:`step` within float rounding (the same formula,
        PyTorch's, evaluated by other kernels), members outside ``mask`` bitwise unchanged."""
        E, (beta1, beta2) = self.members.num_members, self.betas
        self.step_count.add_(mask.to(self.step_count.dtype))
        step = self.step_count[:, None]
        step_size = self.lr / (1.0 - torch.pow(beta1, step))  # inf for members that never stepped: not selected
        bias2_sqrt = (1.0 - torch.pow(beta2, step)).sqrt()
        keep = mask[:, None]
        for (param, exp_avg, exp_avg_sq), grad in zip(self._by_param, grads):
            grad, param = grad.reshape(E, -1), param.view(E, -1)
            exp_avg.copy_(torch.where(keep, exp_avg.lerp(grad, 1.0 - beta1), exp_avg))
            exp_avg_sq.copy_(torch.where(keep, exp_avg_sq * beta2 + (1.0 - beta2) * grad * grad, exp_avg_sq))
            denom = exp_avg_sq.sqrt() / bias2_sqrt + self.eps
            param.copy_(torch.where(keep, param - step_size * exp_avg / denom, param))

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
def polyak_update(target: FlatMembers, source: FlatMembers, tau: float, mask=None) -> None:
    """target <- target + tau * (source - target) for members in ``mask`` (docs/algorithms.md §3.2 step 4): one
    ``torch._foreach_lerp_`` over the per-member slices of the members that update."""
    active = target.active(mask)
    if active:
        dst, src = target.views, source.views
        torch._foreach_lerp_([v for i in active for v in dst[i]], [v for i in active for v in src[i]], tau)


@torch.no_grad()
def polyak_update_masked(target: FlatMembers, source: FlatMembers, tau: float, mask: torch.Tensor) -> None:
    """:func:`polyak_update` with a device bool (E,) ``mask`` and static shapes (see ``MemberAdam.step_masked``)."""
    keep, E = mask[:, None], target.num_members
    for dst, src in zip(target.params, source.params):
        dst, src = dst.view(E, -1), src.view(E, -1)
        dst.copy_(torch.where(keep, dst.lerp(src, tau), dst))
