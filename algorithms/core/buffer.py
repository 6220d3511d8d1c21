"""Member-batched replay storage on preallocated tensors (docs/algorithms.md §3.5, §2.3-2.4, §9.5).

* :class:`SegmentReplayBuffer` stores a stream of time steps per member. Step k holds obs[k] (the observation reached),
  action[k], reward[k], terminal[k], truncated[k] (the step that led to it) and first[k]. Transition k is
  (obs[k-1], action[k], reward[k], obs[k]) and exists only if first[k] is False, so no transition ever spans two
  segments (§2.4). A segment starts with :meth:`~SegmentReplayBuffer.start_segment` (a FIRST step) and ends with a
  terminal or truncated step; after that, :meth:`~SegmentReplayBuffer.add` refuses to continue until a new segment
  starts. Sampling is uniform with replacement over the valid transitions (§3.3) through a per-member index of valid
  positions, so nothing is rejected or dropped.
* :class:`StateBuffer` stores plain vectors (MEDAL's discriminator positives / negatives, §9.3-9.5), sampled uniformly
  with replacement (§9.7 DEFAULT).

Both share :class:`MemberStorage` (allocation, masked appends, per-member uniform index draws, compact checkpoints).
Appends are host-driven (environment data): fill counts live in numpy on the host, so neither appends nor sampling
synchronise with the device. Randomness: one generator per member on the buffer's device, derived from the member seed
and ``stream`` (give every buffer of a member its own :class:`~.nets.Stream` id); members masked out of ``sample``
draw nothing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from algorithms.api import demo_segments

from .nets import Stream, generator_states, host_mask, load_generator_states, member_generators

INITIAL_ALLOCATION = 65_536  # slots per member allocated up front


def _host_bool(x) -> np.ndarray:
    return (x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)).astype(bool)


class MemberStorage:
    """Per-member preallocated fields (E, capacity, *shape) with host fill counts and per-member generators."""

    def __init__(self, name: str, num_members: int, capacity: int, fields: dict[str, tuple[tuple[int, ...], torch.dtype]],
                 device, seeds: Sequence[int], stream: int):
        if len(seeds) != num_members:
            raise ValueError(f"{name}: need one seed per member ({num_members}), got {len(seeds)}")
        self.name, self.num_members, self.capacity = name, num_members, capacity
        self.device = torch.device(device)
        # storage grows on demand (doubling) up to ``capacity``: a 10M-step bound costs nothing until used
        self.allocated = min(capacity, INITIAL_ALLOCATION)
        self.data = {k: torch.zeros((num_members, self.allocated, *shape), dtype=dtype, device=self.device)
                     for k, (shape, dtype) in fields.items()}
        self.size = np.zeros(num_members, dtype=np.int64)  # stored entries per member
        self.generators = member_generators(seeds, self.device, stream)
        self._rows = torch.arange(num_members, device=self.device)[:, None]

    def _members(self, mask) -> np.ndarray:
        mask = host_mask(mask, self.num_members)
        return np.arange(self.num_members) if mask is None else np.flatnonzero(mask)

    def _write(self, members: np.ndarray, values: dict[str, torch.Tensor]) -> np.ndarray:
        """Append ``values[k]`` (M, L, *shape) to members ``members`` at their current ends; returns positions (M, L)."""
        length = next(iter(values.values())).shape[1]
        positions = self.size[members, None] + np.arange(length)
        full = self.size[members] + length > self.capacity
        if full.any():
            raise ValueError(
                f"{self.name}: capacity {self.capacity} exceeded (member {members[full][0]} holds "
                f"{self.size[members[full][0]]} entries, adding {length})"
            )
        needed = int(self.size[members].max(initial=0)) + length
        if needed > self.allocated:
            self._grow(min(self.capacity, max(2 * self.allocated, needed)))
        rows = torch.as_tensor(members, device=self.device)[:, None]
        cols = torch.as_tensor(positions, device=self.device)
        for k, v in values.items():
            self.data[k][rows, cols] = v.to(self.data[k].dtype)
        self.size[members] += length
        return positions

    def _grow(self, new: int) -> None:
        """Reallocate every field with ``new`` slots per member, keeping the stored prefix."""
        for k, v in self.data.items():
            grown = torch.zeros((v.shape[0], new, *v.shape[2:]), dtype=v.dtype, device=self.device)
            grown[:, : self.allocated] = v
            self.data[k] = grown
        self.allocated = new

    def _as_rows(self, x, members: np.ndarray, per_member: bool) -> torch.Tensor:
        """(M, L, ...) device tensor from per-member single entries x (E, ...) or one shared sequence x (L, ...)."""
        x = torch.as_tensor(x, device=self.device)
        if per_member:
            return x[torch.as_tensor(members, device=self.device)].unsqueeze(1)
        return x.unsqueeze(0).expand(len(members), *x.shape)

    def _draw(self, counts: np.ndarray, n: int, mask) -> torch.Tensor:
        """Indices (E, n), row i uniform over [0, counts[i]) from generator i; masked-out rows are 0 and draw nothing."""
        mask = host_mask(mask, self.num_members)
        rows = []
        for i, g in enumerate(self.generators):
            if mask is not None and not mask[i]:
                rows.append(torch.zeros(n, dtype=torch.long, device=self.device))
            elif counts[i] == 0:
                raise ValueError(f"{self.name}: member {i} has nothing to sample")
            else:
                rows.append(torch.randint(int(counts[i]), (n,), generator=g, device=self.device))
        return torch.stack(rows)

    # compact checkpoints: only the filled prefix of every field
    def state_dict(self) -> dict:
        filled = int(self.size.max(initial=0))
        return {
            "size": self.size.copy(),
            "data": {k: v[:, :filled].cpu().clone() for k, v in self.data.items()},
            "generators": generator_states(self.generators),
        }

    def load_state_dict(self, state: dict) -> None:
        self.size[:] = state["size"]
        filled = next(iter(state["data"].values())).shape[1]
        if filled > self.allocated:
            self._grow(filled)
        for k, v in state["data"].items():
            self.data[k].zero_()
            self.data[k][:, : v.shape[1]] = v.to(self.device)
        load_generator_states(self.generators, state["generators"])


class StateBuffer(MemberStorage):
    """Plain vectors per member (e.g. discriminator positives/negatives, §9.5); uniform sampling with replacement."""

    def __init__(self, num_members: int, capacity: int, dim: int, device="cpu", seeds: Sequence[int] | None = None,
                 stream: int = Stream.GC_REPLAY, name: str = "state buffer"):
        seeds = range(num_members) if seeds is None else seeds
        super().__init__(name, num_members, capacity, {"x": ((dim,), torch.float32)}, device, seeds, stream)

    def add(self, x, mask=None) -> None:
        """One vector per member: x (E, dim); only members in ``mask`` store theirs."""
        members = self._members(mask)
        self._write(members, {"x": self._as_rows(x, members, per_member=True)})

    def extend(self, xs, mask=None) -> None:
        """The same sequence xs (L, dim) appended to every member in ``mask`` (e.g. demo states)."""
        members = self._members(mask)
        self._write(members, {"x": self._as_rows(xs, members, per_member=False)})

    def sample(self, n: int, mask=None) -> torch.Tensor:
        """(E, n, dim); rows of members outside ``mask`` are unspecified."""
        return self.data["x"][self._rows, self._draw(self.size, n, mask)]

    @property
    def num_states(self) -> torch.Tensor:
        return torch.as_tensor(self.size)


class SegmentReplayBuffer(MemberStorage):
    """Segment-aware transition replay per member (§3.5). See the module docstring for the storage layout.

    ``filter_first=True`` (RL buffers) samples transitions only. ``filter_first=False`` samples every stored step,
    FIRST steps included, as used for state samples (§3.6); for a FIRST step, ``obs`` is that step's own observation
    (never the previous segment's).
    """

    def __init__(self, num_members: int, capacity: int, obs_dim: int, act_dim: int, device="cpu",
                 seeds: Sequence[int] | None = None, filter_first: bool = True, stream: int = Stream.REPLAY,
                 name: str = "replay buffer"):
        seeds = range(num_members) if seeds is None else seeds
        fields = {
            "obs": ((obs_dim,), torch.float32),
            "action": ((act_dim,), torch.float32),
            "reward": ((), torch.float32),
            "terminal": ((), torch.bool),
            "truncated": ((), torch.bool),
            "first": ((), torch.bool),
        }
        super().__init__(name, num_members, capacity, fields, device, seeds, stream)
        self.filter_first = filter_first
        self.valid = torch.zeros((num_members, self.allocated), dtype=torch.long, device=self.device)  # positions
        self.n_valid = np.zeros(num_members, dtype=np.int64)
        self.open = np.zeros(num_members, dtype=bool)  # member has a segment that accepts further steps

    def _append_steps(self, members: np.ndarray, steps: dict[str, torch.Tensor], first: np.ndarray) -> None:
        """Write L steps (M, L, ...) per member; ``first`` (L,) is shared by all members. Non-FIRST positions are
        appended to the valid-transition index."""
        positions = self._write(members, {**steps, "first": torch.as_tensor(first, device=self.device).expand(
            len(members), len(first))})
        transitions = positions[:, ~first]
        slots = self.n_valid[members, None] + np.arange(transitions.shape[1])
        self.valid[torch.as_tensor(members, device=self.device)[:, None], torch.as_tensor(slots, device=self.device)] = (
            torch.as_tensor(transitions, device=self.device))
        self.n_valid[members] += transitions.shape[1]

    def _grow(self, new: int) -> None:
        super()._grow(new)
        grown = torch.zeros((self.num_members, new), dtype=torch.long, device=self.device)
        grown[:, : self.valid.shape[1]] = self.valid
        self.valid = grown

    def start_segment(self, obs, mask=None) -> None:
        """A FIRST step (dummy action and reward 0) with obs (E, obs_dim) for members in ``mask``. Starting a segment
        while one is open simply ends the open one without a LAST step (its last transition keeps bootstrapping)."""
        members = self._members(mask)
        obs = self._as_rows(obs, members, per_member=True)
        zeros = {k: torch.zeros((len(members), 1, *self.data[k].shape[2:]), device=self.device)
                 for k in ("action", "reward", "terminal", "truncated")}
        self._append_steps(members, {"obs": obs, **zeros}, np.ones(1, dtype=bool))
        self.open[members] = True

    def add(self, action, reward, next_obs, terminal, truncated, mask=None) -> None:
        """Append one step per member in ``mask``: action (E, A), reward (E,), next_obs (E, O), terminal / truncated (E,)
        bool. A terminal or truncated step closes the member's segment. Raises if a member has no open segment."""
        members = self._members(mask)
        closed = members[~self.open[members]]
        if closed.size:
            raise ValueError(f"{self.name}: member(s) {closed.tolist()} have no open segment; call start_segment first")
        steps = {k: self._as_rows(x, members, per_member=True) for k, x in
                 (("action", action), ("reward", reward), ("obs", next_obs), ("terminal", terminal),
                  ("truncated", truncated))}
        self._append_steps(members, steps, np.zeros(1, dtype=bool))
        self.open[members] = ~(_host_bool(terminal) | _host_bool(truncated))[members]

    def add_demo(self, observations, actions, rewards, next_observations, terminals, mask=None,
                 ends_terminal: bool = True) -> None:
        """Insert N demo transitions as segments (§3.5), split after every terminal, into every member in ``mask``.

        Each segment becomes FIRST(observations[start]) followed by one step per transition (obs = next_observations);
        its last step is terminal as given, or marked truncated if the data end without a terminal. With
        ``ends_terminal=False`` every segment's last step is stored truncated instead (a time-out: for a method whose
        own episodes do not end on success, so that its demos bootstrap where its own data do).
        """
        terminals = _host_bool(terminals).reshape(-1)
        n = len(terminals)
        if n == 0:
            return
        starts, segment = demo_segments(terminals)  # first transition of every segment, segment id of each
        transition_pos = np.arange(n) + segment + 1  # stream position: each earlier segment adds one FIRST step
        first_pos = starts + np.arange(len(starts))
        length = n + len(starts)

        def stream(values, positions, fill_shape):
            out = torch.zeros((length, *fill_shape), dtype=torch.float32)
            out[positions] = torch.as_tensor(np.asarray(values), dtype=torch.float32)
            return out

        obs = stream(next_observations, transition_pos, self.data["obs"].shape[2:])
        obs[first_pos] = torch.as_tensor(np.asarray(observations)[starts], dtype=torch.float32)
        ends = terminals.copy()
        ends[-1] = True  # each segment's last transition
        stored_terminals = terminals if ends_terminal else np.zeros(n, dtype=bool)
        truncated = ends & ~stored_terminals
        steps = {
            "obs": obs,
            "action": stream(actions, transition_pos, self.data["action"].shape[2:]),
            "reward": stream(rewards, transition_pos, ()),
            "terminal": stream(stored_terminals, transition_pos, ()),
            "truncated": stream(truncated, transition_pos, ()),
        }
        first = np.zeros(length, dtype=bool)
        first[first_pos] = True
        members = self._members(mask)
        self._append_steps(members, {k: self._as_rows(v, members, per_member=False) for k, v in steps.items()}, first)
        self.open[members] = False

    def sample(self, batch_size: int, mask=None) -> dict[str, torch.Tensor]:
        """Uniform (with replacement) batch per member: obs, action, reward, next_obs, terminal, truncated, each
        (E, B, ...). Members outside ``mask`` draw no random numbers; their rows are unspecified."""
        if self.filter_first:
            k = self.valid.gather(1, self._draw(self.n_valid, batch_size, mask))
        else:
            k = self._draw(self.size, batch_size, mask)
        d, rows = self.data, self._rows
        prev = torch.where(d["first"][rows, k], k, (k - 1).clamp_min(0))
        return {
            "obs": d["obs"][rows, prev],
            "action": d["action"][rows, k],
            "reward": d["reward"][rows, k],
            "next_obs": d["obs"][rows, k],
            "terminal": d["terminal"][rows, k],
            "truncated": d["truncated"][rows, k],
        }

    def sample_states(self, n: int, mask=None) -> torch.Tensor:
        """``n`` stored observations per member (E, n, obs_dim), uniform with replacement over every stored step (segment
        starts included), from the members' sampling streams; rows of members outside ``mask`` are unspecified."""
        return self.data["obs"][self._rows, self._draw(self.size, n, mask)]

    @property
    def num_transitions(self) -> torch.Tensor:
        return torch.as_tensor(self.n_valid)

    def state_dict(self) -> dict:
        state = super().state_dict()
        state.update(valid=self.valid[:, : int(self.n_valid.max(initial=0))].cpu().clone(),
                     n_valid=self.n_valid.copy(), open=self.open.copy())
        return state

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.valid.zero_()
        self.valid[:, : state["valid"].shape[1]] = state["valid"].to(self.device)
        self.n_valid[:] = state["n_valid"]
        self.open[:] = state["open"]
