"""A training step is GPU-shaped: the host reads one device tensor per step (the actions), and nothing in the step asks
the device for a value to branch on.

On a GPU every device->host read is a synchronisation that drains the queue of kernels, so a step that reads twice
runs at half the launch rate it could. On the CPU the same reads are free and invisible, so this test counts them
where they happen: ``Tensor.cpu`` calls (a device->host copy on a GPU; the algorithms call it only on device tensors)
and the dispatcher ops that read a device value on the host (``.item()``, ``bool(t)``, ``float(t)``, ``int(t)`` all
become ``_local_scalar_dense``; ``nonzero`` / ``masked_select`` / ``unique`` have data-dependent shapes).
"""

from __future__ import annotations

import collections

import numpy as np
import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from algorithms.api import DemoSet
from algorithms.common import to_host
from harness.data import load_demos
from harness.envs import get_spec
from harness.protocol import Interaction
from harness.registry import ALGORITHMS
from harness.suites import resolve_algo_config

from .conftest import requires_data

ENV = "tabletop_manipulation"
SYNC_OPS = {"_local_scalar_dense", "nonzero", "masked_select", "_unique", "_unique2", "unique_dim",
            "unique_consecutive", "equal", "is_nonzero"}


class DeviceReads(TorchDispatchMode):
    """Counts the dispatcher ops that need a device value on the host."""

    def __init__(self):
        super().__init__()
        self.ops = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.overloadpacket.__name__
        if name in SYNC_OPS:
            self.ops[name] += 1
        return func(*args, **(kwargs or {}))


@requires_data
@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_a_training_step_reads_the_device_once(algo, monkeypatch):
    cls = ALGORITHMS[algo]
    # short phases so that phase starts (VaPRL's subgoal choice, RISC's switches) happen within the counted steps
    cfg = resolve_algo_config(cls.Config, algo, ENV, {"all": {"seed_steps": 20, "batch_size": 8},
                                                       "risc": {"minimum_steps": 5}, "risc_no_tab": {"minimum_steps": 5},
                                                       "vaprl": {"phase_step_limit": 20},
                                                       "vaprl_risc": {"phase_step_limit": 20}})
    demos = DemoSet(load_demos(ENV, "forward"), load_demos(ENV, "reverse"))
    agent = cls(get_spec(ENV), demos, cfg, [0, 1], torch.device("cpu"))
    inter = Interaction(ENV, [0, 1])
    try:
        inter.start(agent)
        for _ in range(30):  # past the seed phase: updates on
            inter.step(agent)
        reads = collections.Counter()
        cpu = torch.Tensor.cpu

        def counted_cpu(self, *args, **kwargs):
            reads["cpu"] += 1
            return cpu(self, *args, **kwargs)

        monkeypatch.setattr(torch.Tensor, "cpu", counted_cpu)
        n, per_step = 100, []
        with DeviceReads() as mode:
            for _ in range(n):
                before = reads["cpu"]
                inter.step(agent)
                per_step.append(reads["cpu"] - before)
        monkeypatch.undo()
    finally:
        inter.close()
    assert not mode.ops, f"{algo}: a step asks the device for values: {dict(mode.ops)}"
    per_step = np.array(per_step)
    if algo.startswith("vaprl"):
        # VaPRL values its subgoal candidates when a backward phase starts (V(c, g*), and V(s_now, c) with
        # use_minimum): two more reads, at most once per 2 * phase_step_limit steps
        assert (per_step <= 3).all() and (per_step > 1).sum() <= n // 40 + 1, per_step
    else:
        assert (per_step <= 1).all(), f"{algo}: device reads per step {np.unique(per_step)}"


def test_to_host_is_one_transfer_and_keeps_shapes(monkeypatch):
    calls = []
    cpu = torch.Tensor.cpu
    monkeypatch.setattr(torch.Tensor, "cpu", lambda self, *a, **k: calls.append(1) or cpu(self, *a, **k))
    a, p = torch.arange(6, dtype=torch.float32).reshape(3, 2), torch.tensor([0.25, 0.5, 0.75])
    ha, none, hp = to_host(a, None, p)
    assert len(calls) == 1 and none is None
    np.testing.assert_array_equal(ha, a.numpy())
    np.testing.assert_array_equal(hp, p.numpy())
    assert to_host(None) == [None]
