"""CUDA: the same algorithms and protocol on a GPU (skipped where torch sees no GPU; scripts/gpu_check.sh runs them).

What is compared, and why not bitwise: parameters are initialised on the CPU from per-member generators and then
moved, so both devices start from identical networks; CUDA generators (Philox) and CPU ones (mt19937) give different
noise, and GPU matrix products round differently, so training on the two devices agrees in distribution (learning
curves within seed noise, shown by the measured comparison in docs/performance.md), not in bits. Within one device everything
is exact: a CUDA run resumed from its checkpoint equals the uninterrupted CUDA run.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from algorithms.core import SAC, SACConfig
from algorithms.core import sac as sac_module
from algorithms.core.nets import member_generators, member_randn
from harness.planning import plan_words
from harness.protocol import CheckpointError, load_checkpoint
from harness.runner import run_group

from .conftest import requires_data

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

E, O, A, B = 3, 10, 4, 64


def _batch(device, seed=0):
    g = torch.Generator().manual_seed(seed)
    batch = {"obs": torch.randn(E, B, O, generator=g), "action": torch.rand(E, B, A, generator=g) * 2 - 1,
             "reward": (torch.rand(E, B, generator=g) < 0.2).float(), "next_obs": torch.randn(E, B, O, generator=g),
             "terminal": torch.rand(E, B, generator=g) < 0.1, "truncated": torch.rand(E, B, generator=g) < 0.05}
    return {k: v.to(device) for k, v in batch.items()}


def test_networks_start_identical_on_both_devices():
    cpu, gpu = SAC(O, A, [0, 1, 2]), SAC(O, A, [0, 1, 2], device="cuda")
    for (k, a), b in zip(cpu.actor.state_dict().items(), gpu.actor.state_dict().values()):
        assert torch.equal(a, b.cpu()), k


def test_an_update_on_cuda_matches_the_cpu_given_the_same_noise(monkeypatch):
    """The update's arithmetic (manual backward, member Adam, Polyak) on CUDA equals the CPU's within float
    tolerance when both draw the same noise (drawn on the CPU from the same seeds and moved)."""
    cpu_gens = {"cpu": member_generators([7, 8, 9], "cpu", 99), "cuda": member_generators([7, 8, 9], "cpu", 99)}

    def same_noise(device):
        def draw(gens, shape, mask, dev):
            return member_randn(cpu_gens[device], shape, mask, "cpu").to(dev)
        return draw

    agents = {}
    for device in ("cpu", "cuda"):
        monkeypatch.setattr(sac_module, "member_randn", same_noise(device))
        agent = SAC(O, A, [0, 1, 2], SACConfig(), device=device)
        mask = np.array([True, False, True])
        for step in range(5):
            metrics = agent.update(_batch(device, step), mask=None if step % 2 else mask)
        agents[device] = (agent, {k: v.cpu() for k, v in metrics.items()})
    (cpu, m_cpu), (gpu, m_gpu) = agents["cpu"], agents["cuda"]
    for k in m_cpu:
        torch.testing.assert_close(m_gpu[k], m_cpu[k], rtol=1e-4, atol=1e-4, msg=k)
    for name in ("actor", "critic", "critic_target"):
        for (k, a), b in zip(getattr(cpu, name).state_dict().items(), getattr(gpu, name).state_dict().values()):
            torch.testing.assert_close(b.cpu(), a, rtol=1e-4, atol=1e-5, msg=f"{name}.{k}")
    torch.testing.assert_close(gpu.critic_opt.step_count.cpu(), cpu.critic_opt.step_count)  # masks honoured alike


@requires_data
@pytest.mark.parametrize("algo", ["medal", "risc", "vaprl"])
def test_a_cuda_run_resumes_exactly_and_its_checkpoint_loads_on_the_cpu(tmp_path, algo):
    words = [f"algo={algo}", "env=tabletop_manipulation", "seeds=0,1", "steps=400", "eval_every=100",
             "eval_episodes=2", "checkpoint_every=200", f"{algo}.seed_steps=50", f"{algo}.batch_size=32",
             "device=cuda", "members=2", "workers=1"]
    tables = {}
    for name in ("full", "resumed"):
        (spec,) = plan_words([*words, f"results={tmp_path / name}"]).groups
        run = spec.member_dirs()[0]
        if name == "resumed":  # stopped after the evaluation at 300; the checkpoint is at 200
            stop = lambda: pd.read_parquet(run / "evals.parquet").step.max() == 300  # noqa: E731
            assert run_group(spec, "test", should_stop=stop) is None
        assert run_group(spec, "test") is None
        tables[name] = [pd.read_parquet(d / "evals.parquet") for d in spec.member_dirs()]
    for full, resumed in zip(tables["full"], tables["resumed"]):
        exact = ~full.metric.str.contains("per_s|wall")
        pd.testing.assert_frame_equal(full[exact].reset_index(drop=True),
                                      resumed[~resumed.metric.str.contains("per_s|wall")].reset_index(drop=True))
    ck = spec.checkpoint_path()
    assert load_checkpoint(ck, "cuda")["device"] == "cuda"
    on_cpu = torch.load(ck, weights_only=False, map_location="cpu")  # tensors load anywhere, e.g. for inspection
    assert on_cpu["step"] == 400
    with pytest.raises(CheckpointError, match="resume it with device=cuda"):
        load_checkpoint(ck, "cpu")  # but its random streams only resume on CUDA
