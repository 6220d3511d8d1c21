"""Segment replay buffer and state buffer (docs/algorithms.md §2.4, §3.5, §9.5)."""

import numpy as np
import pytest
import torch

from algorithms.core import SegmentReplayBuffer, StateBuffer

OBS, ACT = 2, 1


def run_segments(buf, member_offsets, lengths, end="terminal"):
    """Per member i, segments of the given lengths whose observations encode (segment id, step): obs = [seg, t] + off.
    Actions encode t, so any sampled transition must satisfy obs' = obs + [0, 1] and action = obs'[1]."""
    E = buf.num_members
    for seg, n in enumerate(lengths):
        buf.start_segment(np.array([[seg, 0.0] for _ in range(E)]) + member_offsets)
        for t in range(1, n + 1):
            nxt = np.array([[seg, float(t)] for _ in range(E)]) + member_offsets
            last = np.full(E, t == n)
            buf.add(np.full((E, ACT), float(t)), np.full(E, t), nxt, last & (end == "terminal"), last & (end == "truncated"))


def test_never_samples_across_segments_or_first_steps():
    buf = SegmentReplayBuffer(2, 200, OBS, ACT, seeds=[0, 1])
    offsets = np.array([[0.0, 0.0], [100.0, 0.0]])
    run_segments(buf, offsets, [3, 1, 5, 2])
    assert buf.num_transitions.tolist() == [11, 11]  # 15 stored steps - 4 FIRST steps
    s = buf.sample(4000)
    assert torch.equal(s["next_obs"][..., 0], s["obs"][..., 0])  # same segment
    assert torch.equal(s["next_obs"][..., 1], s["obs"][..., 1] + 1)  # consecutive steps: never a FIRST as target
    assert torch.equal(s["action"][..., 0], s["next_obs"][..., 1])
    assert (s["obs"][1, :, 0] >= 100).all() and (s["obs"][0, :, 0] < 100).all()  # members keep their own data
    # every valid transition is reachable (uniform over the 11, no rejection)
    assert len(torch.unique(s["next_obs"][0], dim=0)) == 11
    # terminal flag exactly on the last step of every segment
    lengths = torch.tensor([3.0, 1, 5, 2])
    assert torch.equal(s["terminal"], s["next_obs"][..., 1] == lengths[s["obs"][..., 0].long() % 100])


def test_segment_must_be_restarted_after_terminal_or_truncated():
    buf = SegmentReplayBuffer(2, 50, OBS, ACT)
    with pytest.raises(ValueError, match="start_segment"):
        buf.add(np.zeros((2, ACT)), np.zeros(2), np.zeros((2, OBS)), np.zeros(2, bool), np.zeros(2, bool))
    run_segments(buf, np.zeros((2, OBS)), [2], end="truncated")
    with pytest.raises(ValueError, match="no open segment"):
        buf.add(np.zeros((2, ACT)), np.zeros(2), np.zeros((2, OBS)), np.zeros(2, bool), np.zeros(2, bool))
    s = buf.sample(100)
    assert torch.equal(s["truncated"], s["next_obs"][..., 1] == 2) and not s["terminal"].any()


def test_masked_add_and_fill_counts():
    buf = SegmentReplayBuffer(3, 50, OBS, ACT)
    buf.start_segment(np.zeros((3, OBS)))
    for t in range(4):
        mask = np.array([True, t % 2 == 0, False])
        buf.add(np.zeros((3, ACT)), np.ones(3), np.full((3, OBS), t + 1.0), np.zeros(3, bool), np.zeros(3, bool), mask)
    assert buf.num_transitions.tolist() == [4, 2, 0]
    assert buf.size.tolist() == [5, 3, 1]
    s = buf.sample(50, mask=torch.tensor([True, True, False]))
    assert set(s["next_obs"][1, :, 0].tolist()) == {1.0, 3.0}  # member 1 stored only steps 1 and 3
    with pytest.raises(ValueError, match="member 2 has nothing"):
        buf.sample(5)


def test_demos_inserted_as_segments_in_every_member():
    buf = SegmentReplayBuffer(2, 100, OBS, ACT)
    n = 7
    obs = np.stack([np.arange(n), np.zeros(n)], 1).astype(np.float32)
    terminals = np.array([0, 0, 1, 0, 0, 0, 1], bool)
    buf.add_demo(obs, obs[:, :ACT] + 0.5, terminals.astype(np.float32), obs + [1, 0], terminals)
    assert buf.size.tolist() == [9, 9] and buf.num_transitions.tolist() == [7, 7]  # N + one FIRST per demo
    stored = buf.data["obs"][0, :9, 0].tolist()
    assert stored == [0, 1, 2, 3, 3, 4, 5, 6, 7]
    assert buf.data["first"][0, :9].tolist() == [True, False, False, False, True, False, False, False, False]
    s = buf.sample(2000)
    assert torch.equal(s["next_obs"][..., 0], s["obs"][..., 0] + 1)  # never 3 -> 3 across the demo boundary
    assert torch.equal(s["action"][..., 0], s["obs"][..., 0] + 0.5)
    assert torch.equal(s["terminal"], (s["next_obs"][..., 0] == 3) | (s["next_obs"][..., 0] == 7))
    assert torch.equal(s["terminal"].float(), s["reward"])
    # demo segments are closed: online data must start a new segment
    with pytest.raises(ValueError):
        buf.add(np.zeros((2, ACT)), np.zeros(2), np.zeros((2, OBS)), np.zeros(2, bool), np.zeros(2, bool))
    # data that stop without a terminal end with a truncated step
    buf.add_demo(obs[:2], obs[:2, :ACT], np.zeros(2), obs[:2] + [1, 0], np.zeros(2, bool), mask=[False, True])
    assert buf.data["truncated"][1, 9:12].tolist() == [False, False, True] and buf.size.tolist() == [9, 12]
    # ends_terminal=False: the same segments, each ending truncated (a time-out), none terminal
    timeouts = SegmentReplayBuffer(1, 100, OBS, ACT)
    timeouts.add_demo(obs, obs[:, :ACT] + 0.5, terminals.astype(np.float32), obs + [1, 0], terminals,
                      ends_terminal=False)
    assert torch.equal(timeouts.data["obs"][0, :9], buf.data["obs"][0, :9])
    assert timeouts.data["terminal"][0, :9].sum() == 0
    assert timeouts.data["truncated"][0, :9].tolist() == [False] * 3 + [True] + [False] * 4 + [True]
    timeouts.add_demo(obs[:2], obs[:2, :ACT], np.zeros(2), obs[:2] + [1, 0], np.zeros(2, bool), ends_terminal=False)
    assert timeouts.data["truncated"][0, 9:12].tolist() == [False, False, True]  # data without a terminal: as before


def test_capacity_error_names_buffer():
    buf = SegmentReplayBuffer(1, 4, OBS, ACT, name="forward buffer")
    run_segments(buf, np.zeros((1, OBS)), [3])
    with pytest.raises(ValueError, match="forward buffer: capacity 4"):
        buf.start_segment(np.zeros((1, OBS)))
    states = StateBuffer(2, 3, OBS, name="negatives")
    states.extend(np.zeros((3, OBS)))
    with pytest.raises(ValueError, match="negatives: capacity 3"):
        states.add(np.zeros((2, OBS)), mask=[False, True])


def test_state_dict_round_trip_reproduces_samples():
    buf = SegmentReplayBuffer(2, 100, OBS, ACT, seeds=[3, 4])
    run_segments(buf, np.array([[0.0, 0.0], [50.0, 0.0]]), [4, 6])
    buf.start_segment(np.zeros((2, OBS)), mask=[True, False])
    buf.sample(7)
    state = buf.state_dict()
    assert state["data"]["obs"].shape[1] == 13  # compact: only the filled prefix
    clone = SegmentReplayBuffer(2, 100, OBS, ACT, seeds=[8, 9])
    clone.load_state_dict(state)
    for _ in range(3):
        a, b = buf.sample(16), clone.sample(16)
        assert all(torch.equal(a[k], b[k]) for k in a)
    step = (np.ones((2, ACT)), np.ones(2), np.ones((2, OBS)), np.zeros(2, bool), np.zeros(2, bool), [True, False])
    buf.add(*step)
    clone.add(*step)
    with pytest.raises(ValueError):  # the open/closed flags came back too
        clone.add(*step[:-1], [False, True])
    assert torch.equal(buf.sample(16)["obs"], clone.sample(16)["obs"])


def test_sampling_per_member_streams_and_mask():
    """Member i's draws equal those of a single-member buffer with seed i; masked-out members draw nothing."""
    multi = SegmentReplayBuffer(2, 100, OBS, ACT, seeds=[10, 11])
    single = SegmentReplayBuffer(1, 100, OBS, ACT, seeds=[11])
    run_segments(multi, np.zeros((2, OBS)), [5, 7])
    run_segments(single, np.zeros((1, OBS)), [5, 7])
    multi.sample(8, mask=[True, False])
    for _ in range(2):
        assert torch.equal(multi.sample(8)["obs"][1], single.sample(8)["obs"][0])


def test_filter_first_false_samples_states_without_crossing():
    buf = SegmentReplayBuffer(1, 50, OBS, ACT, filter_first=False)
    run_segments(buf, np.zeros((1, OBS)), [2, 2])
    s = buf.sample(500)
    first = s["next_obs"][..., 1] == 0
    assert first.any()  # FIRST steps are sampled as states
    assert torch.equal(s["obs"][first], s["next_obs"][first])  # and never paired with the previous segment
    assert torch.equal(s["obs"][~first][:, 1] + 1, s["next_obs"][~first][:, 1])


def test_state_buffer():
    buf = StateBuffer(2, 20, 3, seeds=[0, 1])
    buf.extend(np.ones((4, 3)))
    buf.add(np.stack([np.zeros(3), np.full(3, 2.0)]), mask=torch.tensor([False, True]))
    assert buf.num_states.tolist() == [4, 5]
    x = buf.sample(500)
    assert x.shape == (2, 500, 3)
    assert set(x[0, :, 0].tolist()) == {1.0} and set(x[1, :, 0].tolist()) == {1.0, 2.0}
    clone = StateBuffer(2, 20, 3)
    clone.load_state_dict(buf.state_dict())
    assert torch.equal(buf.sample(10), clone.sample(10))
