"""Forward and hand-written backward passes of the member networks (used by the SAC update, docs/algorithms.md §3).

The SAC update needs gradients of three small losses through 2 x 256 MLPs. On a CPU the autograd engine, its graph
bookkeeping and the extra elementwise passes it makes cost as much as the matrix products themselves, so the update
runs the layers below instead: each ``*_forward`` returns its output and a cache of the activations, each ``*_backward``
returns the parameter gradients (in ``module.parameters()`` order) and, where asked, the gradient of the input. The math
is the textbook one (tests compare every gradient with autograd's); shapes are member-batched (E, B, features) as in
:mod:`nets`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .nets import MemberMLP, MemberTrunk, member_matmul


def _t(x: Tensor) -> Tensor:
    return x.transpose(1, 2)


def _relu_backward(grad: Tensor, out: Tensor) -> Tensor:
    """d/dz relu(z) given the upstream gradient and relu's OUTPUT: autograd's own kernel (one pass; a masked_fill with
    a comparison is ~15x slower on the CPU)."""
    return torch.ops.aten.threshold_backward(grad, out, 0)


# ---------------------------------------------------------------------------------------------------------------------
# Linear -> LayerNorm -> Tanh feature layer


def trunk_forward(trunk: MemberTrunk, x: Tensor) -> tuple[Tensor, tuple]:
    lin, norm = trunk.linear, trunk.norm
    z = member_matmul(x, lin.weight, lin.bias)
    normed, mean, rstd = torch.native_layer_norm(z, (norm.dim,), None, None, norm.eps)
    h = torch.tanh(torch.addcmul(norm.bias, normed, norm.weight))
    return h, (x, z, normed, mean, rstd, h)


def trunk_backward(trunk: MemberTrunk, cache: tuple, dh: Tensor) -> list[Tensor]:
    """Gradients of [linear.weight, linear.bias, norm.weight, norm.bias] (the observation needs none)."""
    x, z, normed, mean, rstd, h = cache
    dy = dh * (1.0 - h * h)
    d_gamma = (dy * normed).sum(1, keepdim=True)
    d_beta = dy.sum(1, keepdim=True)
    dz = torch.ops.aten.native_layer_norm_backward(
        dy * trunk.norm.weight, z, (trunk.norm.dim,), mean, rstd, None, None, [True, False, False])[0]
    return [member_matmul(_t(x), dz), dz.sum(1, keepdim=True), d_gamma, d_beta]


# ---------------------------------------------------------------------------------------------------------------------
# Linear -> ReLU -> ... -> Linear


def mlp_forward(mlp: MemberMLP, x: Tensor) -> tuple[Tensor, list[Tensor]]:
    """Like ``MemberMLP.forward`` (replicas expanded, output (E * copies, B, out)); the cache is every layer's input."""
    if mlp.copies > 1:
        E, B, d = x.shape
        x = x.unsqueeze(1).expand(E, mlp.copies, B, d).reshape(E * mlp.copies, B, d)
    inputs = []
    for i, layer in enumerate(mlp.layers):
        inputs.append(x)
        x = member_matmul(x, layer.weight, layer.bias)
        if i < len(mlp.layers) - 1:
            x = torch.relu_(x)
    return x, inputs


def mlp_backward(mlp: MemberMLP, inputs: list[Tensor], dout: Tensor, weights: bool = True,
                 input_cols: slice | None = None) -> tuple[list[Tensor], Tensor | None]:
    """Back through the layers from ``dout`` (E * copies, B, out).

    weights: also return the parameter gradients ([w0, b0, w1, b1, ...]); False skips those products (e.g. the actor
    loss, which only needs dQ/da). input_cols: return the gradient of these input columns (per replica; None: none).
    """
    grads: list[Tensor] = []
    d = dout
    for i in range(len(mlp.layers) - 1, -1, -1):
        layer, x = mlp.layers[i], inputs[i]
        if weights:
            grads[:0] = [member_matmul(_t(x), d), d.sum(1, keepdim=True)]
        if i > 0:
            d = _relu_backward(member_matmul(d, _t(layer.weight)), x)
        elif input_cols is not None:
            return grads, member_matmul(d, _t(layer.weight[:, input_cols]))
    return grads, None


# ---------------------------------------------------------------------------------------------------------------------
# The SAC networks (``sac.Actor``, ``sac.Critic``: an optional trunk, then a MemberMLP)


def _trunk(module) -> MemberTrunk | None:
    return module.trunk if isinstance(module.trunk, MemberTrunk) else None


def actor_forward(actor, obs: Tensor) -> tuple[Tensor, tuple]:
    """Raw actor output (E, B, 2A) (mean, unclamped log sigma) and its cache."""
    trunk = _trunk(actor)
    feat, trunk_cache = trunk_forward(trunk, obs) if trunk else (obs, None)
    out, mlp_cache = mlp_forward(actor.mlp, feat)
    return out, (trunk_cache, mlp_cache)


def actor_backward(actor, cache: tuple, d_out: Tensor, rows: slice = slice(None)) -> list[Tensor]:
    """Parameter gradients from dL/d output (E, B', 2A) for the batch ``rows`` of the forward pass only."""
    trunk_cache, mlp_cache = cache
    trunk = _trunk(actor)
    grads, d_feat = mlp_backward(actor.mlp, [x[:, rows] for x in mlp_cache], d_out,
                                 input_cols=slice(None) if trunk else None)
    if not trunk:
        return grads
    rows_cache = tuple(t[:, rows].contiguous() for t in trunk_cache)  # the layer-norm kernel wants contiguous
    return trunk_backward(trunk, rows_cache, d_feat) + grads


def critic_forward(critic, obs: Tensor, action: Tensor) -> tuple[Tensor, tuple]:
    """Head outputs (E, 2, B) at (obs, action) and the cache."""
    trunk = _trunk(critic)
    feat, trunk_cache = trunk_forward(trunk, obs) if trunk else (obs, None)
    q, mlp_cache = mlp_forward(critic.heads, torch.cat([feat, action], dim=-1))
    return q.view(obs.shape[0], critic.heads.copies, -1), (trunk_cache, mlp_cache, feat.shape[-1])


def critic_backward(critic, cache: tuple, d_q: Tensor, weights: bool = True) -> tuple[list[Tensor], Tensor | None]:
    """From dL/d heads (E, 2, B): ``weights`` True, the parameter gradients (and None); False, [] and dL/d action
    (E, B, A) (the actor loss's path)."""
    trunk_cache, mlp_cache, n_feat = cache
    E, copies, B = d_q.shape
    trunk = _trunk(critic)
    # training the critic needs the input's gradient only for a trunk (all columns: the shapes its results were
    # computed with since the first runs, so resumed runs go on bit for bit)
    cols = slice(n_feat, None) if not weights else slice(0, None) if trunk else None
    grads, d_in = mlp_backward(critic.heads, mlp_cache, d_q.reshape(E * copies, B, 1), weights, cols)
    if d_in is not None:
        d_in = d_in.view(E, copies, B, -1).sum(dim=1)  # every head reads the same input
    if not weights:
        return [], d_in
    if trunk:
        grads = trunk_backward(trunk, trunk_cache, d_in[..., :n_feat]) + grads
    return grads, None
