"""Seed-batched ("member") network layers and per-member randomness.

Every parameter carries a leading member dimension E: one process trains E independent seeds in lockstep, and member i
of an E-member object is the same object as a single-seed (E=1) one built from member i's seed: equal at
construction, and through training to float rounding (a batched product may round differently with E).

* Layers take activations shaped (E, B, features) and never mix members (batched matmuls, per-member affine).
* Initialisation (docs/algorithms.md §3.1: Xavier-uniform weights, zero biases) draws each member's slice from that member's
  own ``torch.Generator`` on the CPU, layer after layer in construction order, so member i's values do not depend on E.
* Sampling noise comes from one generator per member (:func:`member_randn`); members that are masked out draw nothing,
  so each member's random stream advances exactly as it would in a single-seed run.

A network may hold ``copies`` independent replicas per member (e.g. the two Q-heads of the SAC critic): they are stored
member-major as E * copies "members" of the underlying layers, which keeps every parameter viewable as (E, -1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

# ---------------------------------------------------------------------------------------------------------------------
# Per-member randomness and masks
# ---------------------------------------------------------------------------------------------------------------------


class Stream:
    """The ids of a member's independent random streams: torch generators (:func:`member_generators`, via
    :func:`stream_seed`) and numpy ones (``algorithms.common.member_rngs``). No stream (``None``) is the member seed
    itself, which seeds network initialisation.

    Two streams of one run never share an id; an id is reused only by methods that never run together (the aliases at
    the end). Every value is frozen: changing one changes every result drawn from that stream, resumed runs included.
    tests/test_core_streams.py checks both, and that ``algorithms/`` passes no stream id as a bare number."""

    # every SAC agent (core/sac.py)
    SAC_ACT = 1  # acting noise (the action sampled from the policy)
    SAC_UPDATE = 2  # update noise (actions sampled for the critic target, the actor loss and the temperature loss)
    # the MEDAL / VICE discriminator (core/discriminator.py)
    MIXUP = 5  # mixup coefficients and permutations of the discriminator batch
    # Naive, Oracle, BC, GAIL and the forward/backward methods (FBRL, R3L, MEDAL and its ablations)
    TASK_GOALS = 7  # numpy: task-goal draws (Naive's cuts and seed-phase actions, forward/backward phase switches)
    REPLAY = 10  # minibatch sampling of the main buffer: Naive's replay, the forward buffer, BC's demo pairs
    BACKWARD_REPLAY = 11  # minibatch sampling of the backward buffer
    EXPERT_STATES = 12  # discriminator positives: MEDAL's demo states, GAIL's expert (o, a) pairs
    AGENT_STATES = 13  # discriminator negatives: MEDAL's visited states
    # the goal-conditioned methods (RISC, VaPRL; algorithms/goal_conditioned.py)
    GC_REPLAY = 20  # minibatch sampling of the one replay buffer (also StateBuffer's default)
    GC_GOALS = 21  # numpy: goal draws of new phases
    GC_WARMUP = 22  # numpy: the warm-up's uniform random actions
    SUCCESS_CRITIC = 30  # RISC's success critic (AuxCritic): 30 init, 31 update noise, 32 policy-value noise
    SWITCH = 33  # numpy: RISC's early-switch draws
    VALUE_CRITIC = 40  # VaPRL's separate value critic (AuxCritic): 40 init, 41 update noise, 42 policy-value noise
    RELABEL = 43  # numpy: VaPRL's relabelling draws
    SAC_VALUE = 44  # VaPRL: the actions that value subgoal candidates with the SAC critic
    # ids reused by methods that never run with the ids' first owner
    RND_INIT = SUCCESS_CRITIC  # R3L: initialisation of the RND target and predictor networks
    DAC_INIT = VALUE_CRITIC  # GAIL: initialisation of the DAC discriminator
    DAC_NOISE = VALUE_CRITIC + 1  # GAIL: the DAC discriminator's gradient-penalty interpolation


def stream_seed(seed: int, stream: int) -> int:
    """A 63-bit seed for random stream ``stream`` of a member seeded ``seed`` (independent streams via SeedSequence)."""
    return int(np.random.SeedSequence([stream, seed]).generate_state(2, np.uint32).astype(np.uint64) @ [1 << 31, 1])


def member_generators(seeds: Sequence[int], device: torch.device | str = "cpu", stream: int | None = None):
    """One ``torch.Generator`` per member on ``device``; ``stream=None`` seeds with the member seed itself (used for
    initialisation), an id from :class:`Stream` derives an independent stream per purpose (noise, sampling, ...)."""
    gens = []
    for seed in seeds:
        g = torch.Generator(device=device)
        g.manual_seed(int(seed) if stream is None else stream_seed(int(seed), stream))
        gens.append(g)
    return gens


def generator_states(gens: Sequence[torch.Generator]) -> list[torch.Tensor]:
    return [g.get_state() for g in gens]


def load_generator_states(gens: Sequence[torch.Generator], states: Sequence[torch.Tensor]) -> None:
    if len(gens) != len(states):
        raise ValueError(f"expected {len(gens)} generator states, got {len(states)}")
    for g, s in zip(gens, states):
        g.set_state(s)


def host_mask(mask, num_members: int) -> np.ndarray | None:
    """The member mask as a host bool array (None = all members). A CUDA tensor costs one device sync here: callers on a
    GPU hot path should pass the mask as a CPU tensor / numpy array (it is decided on the host anyway)."""
    if mask is None:
        return None
    if isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (num_members,):
        raise ValueError(f"mask must have shape ({num_members},), got {mask.shape}")
    return mask


def member_randn(gens: Sequence[torch.Generator], shape: tuple[int, ...], mask: np.ndarray | None, device) -> torch.Tensor:
    """Standard-normal noise (E, *shape): row i is drawn from ``gens[i]``; rows of masked-out members are zeros and
    consume no random numbers. The Python loop is over members only (E small draws)."""
    rows = [
        torch.randn(shape, generator=g, device=device) if mask is None or mask[i] else torch.zeros(shape, device=device)
        for i, g in enumerate(gens)
    ]
    return torch.stack(rows)


# ---------------------------------------------------------------------------------------------------------------------
# Layers
# ---------------------------------------------------------------------------------------------------------------------

#: result widths up to which :func:`member_matmul` runs the product transposed
NARROW = 16


def member_matmul(a: torch.Tensor, b: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """a (E, n, k) @ b (E, k, m) (+ bias (E, 1, m)), one product per member. The CPU's batched GEMM is 3-10x slower
    for a narrow result (m <= ``NARROW``: an actor's 2A, dQ/da) than for the same product transposed, (b^T a^T)^T,
    and for one column (m = 1, a critic head) or an outer product (k = 1) than for a broadcast multiply (and sum), so
    those run that way (``harness bench matmul``). Same math; the rounding of a sum may differ in the last bit."""
    if a.shape[-1] == 1:
        return a * b if bias is None else torch.addcmul(bias, a, b)
    if b.shape[-1] == 1:  # a row-wise dot product: as fast, and each member's result is the same for any E
        out = (a * b.transpose(1, 2)).sum(-1, keepdim=True)
        return out if bias is None else out + bias
    if b.shape[-1] <= NARROW and a.shape[1] == 1:  # one row per member (acting): a broadcast multiply and sum,
        out = (a.transpose(1, 2) * b).sum(1, keepdim=True)  # whose result for a member is the same for any E
        return out if bias is None else out + bias
    if b.shape[-1] <= NARROW:
        at, bt = a.transpose(1, 2), b.transpose(1, 2)
        return (torch.bmm(bt, at) if bias is None else torch.baddbmm(bias.transpose(1, 2), bt, at)).transpose(1, 2)
    return torch.bmm(a, b) if bias is None else torch.baddbmm(bias, a, b)


class MemberLinear(nn.Module):
    """E independent ``nn.Linear`` layers: weight (E, in, out), bias (E, 1, out); y = x @ W + b (:func:`member_matmul`).

    Xavier-uniform weights (bound sqrt(6 / (in + out)), gain 1) drawn per member from ``generators[i]``; zero biases.
    """

    def __init__(self, num_members: int, in_features: int, out_features: int, generators: Sequence[torch.Generator]):
        super().__init__()
        if len(generators) != num_members:
            raise ValueError(f"need one generator per member ({num_members}), got {len(generators)}")
        self.in_features, self.out_features = in_features, out_features
        bound = math.sqrt(6.0 / (in_features + out_features))
        weight = torch.stack(
            [torch.empty(in_features, out_features).uniform_(-bound, bound, generator=g) for g in generators]
        )
        self.weight = nn.Parameter(weight)
        self.bias = nn.Parameter(torch.zeros(num_members, 1, out_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return member_matmul(x, self.weight, self.bias)

    def extra_repr(self) -> str:
        return f"members={self.weight.shape[0]}, in_features={self.in_features}, out_features={self.out_features}"


class MemberLayerNorm(nn.Module):
    """Per-member ``nn.LayerNorm(dim)`` (eps 1e-5): normalise the last dim, then a per-member affine (E, 1, dim)."""

    def __init__(self, num_members: int, dim: int, eps: float = 1e-5):
        super().__init__()
        self.dim, self.eps = dim, eps
        self.weight = nn.Parameter(torch.ones(num_members, 1, dim))
        self.bias = nn.Parameter(torch.zeros(num_members, 1, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.addcmul(self.bias, F.layer_norm(x, (self.dim,), eps=self.eps), self.weight)


class MemberTrunk(nn.Module):
    """The feature layer of docs/algorithms.md §3.1: Linear(in -> feature_dim) -> LayerNorm -> Tanh."""

    def __init__(self, num_members: int, in_features: int, feature_dim: int, generators: Sequence[torch.Generator]):
        super().__init__()
        self.linear = MemberLinear(num_members, in_features, feature_dim, generators)
        self.norm = MemberLayerNorm(num_members, feature_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.norm(self.linear(x)))


class MemberMLP(nn.Module):
    """Linear -> ReLU -> ... -> Linear over ``dims`` = [in, hidden..., out], ``copies`` independent replicas per member.

    Input (E, B, in); output (E, B, out), or (E, copies, B, out) when ``copies > 1``. Replicas are initialised one after
    the other from the member's generator (layer by layer), so they differ and member i never depends on E.
    """

    def __init__(self, num_members: int, dims: Sequence[int], generators: Sequence[torch.Generator], copies: int = 1):
        super().__init__()
        self.copies = copies
        replica_gens = [g for g in generators for _ in range(copies)]  # member-major: (member 0: copy 0, 1, ...), ...
        self.layers = nn.ModuleList(
            MemberLinear(num_members * copies, d_in, d_out, replica_gens) for d_in, d_out in zip(dims[:-1], dims[1:])
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        E, B, _ = x.shape
        if self.copies > 1:
            x = x.unsqueeze(1).expand(E, self.copies, B, x.shape[-1]).reshape(E * self.copies, B, -1)
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = torch.relu(x)
        return x if self.copies == 1 else x.view(E, self.copies, B, -1)
