"""Seed-batched learning core: member layers, masked Adam, SAC (docs/algorithms.md §3), segment replay (§3.5) and the
MEDAL discriminator (§9)."""

from .buffer import MemberStorage, SegmentReplayBuffer, StateBuffer
from .discriminator import Discriminator, discriminator_reward
from .losses import squashed_gaussian_log_prob
from .nets import (
    MemberLayerNorm,
    MemberLinear,
    MemberMLP,
    MemberTrunk,
    Stream,
    member_generators,
    member_randn,
)
from .optim import FlatMembers, MemberAdam, polyak_update
from .sac import SAC, Actor, Critic, SACConfig

__all__ = [
    "Actor",
    "Critic",
    "Discriminator",
    "FlatMembers",
    "MemberAdam",
    "MemberLayerNorm",
    "MemberLinear",
    "MemberMLP",
    "MemberStorage",
    "MemberTrunk",
    "SAC",
    "SACConfig",
    "SegmentReplayBuffer",
    "StateBuffer",
    "Stream",
    "discriminator_reward",
    "member_generators",
    "member_randn",
    "polyak_update",
    "squashed_gaussian_log_prob",
]
