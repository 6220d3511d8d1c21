"""The static-shape SAC update (``SAC.use_static_update``): the path a GPU captures as CUDA graphs. Run uncompiled on the
CPU it equals today's default update within float rounding; members outside the mask stay bitwise unchanged; compiled
(``torch.compile``) it equals the uncompiled static path."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from algorithms.core import SAC, SACConfig
from algorithms.core.optim import FlatMembers, MemberAdam, polyak_update, polyak_update_masked
from algorithms.core.sac import use_static_updates
from harness.planning import plan_words
from harness.runner import run_group

from .conftest import requires_data

E, O, A, B = 3, 9, 3, 32
MASKS = [None, np.array([True, False, True]), np.array([False, True, False]), None, np.array([True, True, False])]


def _batch(step: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(step)
    return {"obs": torch.randn(E, B, O, generator=g), "action": torch.rand(E, B, A, generator=g) * 2 - 1,
            "reward": (torch.rand(E, B, generator=g) < 0.3).float(), "next_obs": torch.randn(E, B, O, generator=g),
            "terminal": torch.rand(E, B, generator=g) < 0.1, "truncated": torch.rand(E, B, generator=g) < 0.1}


def _on(batch: dict[str, torch.Tensor], device) -> dict[str, torch.Tensor]:
    return {k: v.to(device) for k, v in batch.items()}


def _train(agent: SAC, steps: int = 10) -> list[dict[str, torch.Tensor]]:
    return [agent.update(_on(_batch(t), agent.device), mask=MASKS[t % len(MASKS)]) for t in range(steps)]


def _params(agent: SAC) -> dict[str, torch.Tensor]:
    out = {}
    for name in ("actor", "critic", "critic_target"):
        out.update({f"{name}.{k}": v.clone() for k, v in getattr(agent, name).state_dict().items()})
    out.update(log_alpha=agent.log_alpha.detach().clone(), critic_m=agent.critic_opt.exp_avg.clone(),
               critic_v=agent.critic_opt.exp_avg_sq.clone(), actor_steps=agent.actor_opt.step_count.clone())
    return out


def test_masked_adam_and_polyak_equal_the_per_member_kernels():
    torch.manual_seed(0)
    nets = [torch.nn.Parameter(torch.randn(E * k, 5, 4)) for k in (1, 2)]
    twins = [torch.nn.Parameter(p.detach().clone()) for p in nets]
    ref, static = MemberAdam(nets, E, lr=1e-2), MemberAdam(twins, E, lr=1e-2)
    for t, mask in enumerate(MASKS * 3):
        grads = [torch.randn_like(p) for p in nets]
        ref.step(mask, grads)
        static.step_masked(torch.ones(E, dtype=torch.bool) if mask is None else torch.as_tensor(mask), grads)
    for p, q in zip(nets, twins):
        torch.testing.assert_close(q, p, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(static.exp_avg_sq, ref.exp_avg_sq, rtol=1e-5, atol=1e-9)
    assert torch.equal(static.step_count, ref.step_count)
    # Polyak: masked members move, the others are bitwise untouched
    src = FlatMembers([torch.nn.Parameter(torch.randn(E, 7))], E)
    a, b = FlatMembers([torch.nn.Parameter(torch.zeros(E, 7))], E), FlatMembers([torch.nn.Parameter(torch.zeros(E, 7))], E)
    polyak_update(a, src, 0.1, np.array([True, False, True]))
    polyak_update_masked(b, src, 0.1, torch.tensor([True, False, True]))
    torch.testing.assert_close(b.flat, a.flat)
    assert (b.params[0][1] == 0).all()


def test_static_update_equals_the_default_update_within_rounding():
    default, static = SAC(O, A, [0, 1, 2], SACConfig()), SAC(O, A, [0, 1, 2], SACConfig())
    static.use_static_update()
    m_default, m_static = _train(default), _train(static)
    for a, b in zip(m_default, m_static):
        for k in a:
            torch.testing.assert_close(b[k], a[k], rtol=1e-4, atol=1e-5, msg=k)
    pa, pb = _params(default), _params(static)
    for k in pa:
        torch.testing.assert_close(pb[k], pa[k], rtol=1e-4, atol=1e-5, msg=k)
    assert torch.equal(pb["actor_steps"], pa["actor_steps"])  # the masks counted the same steps


def test_static_update_leaves_masked_out_members_bitwise_unchanged():
    agent = SAC(O, A, [0, 1, 2], SACConfig())
    agent.use_static_update()
    _train(agent, 2)
    before = _params(agent)
    agent.update(_batch(99), mask=np.array([True, False, True]))
    after = _params(agent)
    checked = 0
    for k, v in before.items():
        if v.dim() and v.shape[0] % E == 0 and k not in ("critic_m", "critic_v"):
            rows = v.shape[0] // E  # replicas per member (the critic's two heads)
            assert torch.equal(after[k][rows : 2 * rows], v[rows : 2 * rows]), k  # member 1: masked out
            checked += 1
    assert checked > 20
    assert not torch.equal(after["actor.mlp.layers.0.weight"][0], before["actor.mlp.layers.0.weight"][0])
    assert not torch.equal(after["critic_m"], before["critic_m"])


@pytest.mark.slow  # compiling takes ~1 min on a 2-core CPU; scripts/gpu_check.sh runs it, on CUDA too
@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_compiled_static_update_equals_the_uncompiled_one(device):
    """torch.compile of the static path: inductor on the CPU; on CUDA with mode="reduce-overhead" (CUDA graphs)."""
    if device == "cuda" and not torch.cuda.is_available():
        pytest.skip("needs a CUDA device")
    eager, compiled = SAC(O, A, [0, 1, 2], SACConfig(), device), SAC(O, A, [0, 1, 2], SACConfig(), device)
    eager.use_static_update()
    compiled.use_static_update(compile=True)
    for a, b in zip(_train(eager, 6), _train(compiled, 6)):
        for k in a:
            torch.testing.assert_close(b[k], a[k], rtol=1e-4, atol=1e-5, msg=k)
    pa, pb = _params(eager), _params(compiled)
    for k in pa:
        torch.testing.assert_close(pb[k], pa[k], rtol=1e-4, atol=1e-5, msg=k)


@requires_data
@pytest.mark.parametrize("update, switch", [("static", "use_static_update"), ("autograd", "use_autograd_update")])
def test_harness_run_with_other_updates(tmp_path, monkeypatch, update, switch):
    """``update=static`` / ``update=autograd`` reaches every SAC agent of the run (MEDAL: forward and backward) and is
    recorded; the curve agrees with the default update's until the updates start (bitwise), and within rounding
    after."""
    words = ["algo=medal", "env=tabletop_manipulation", "steps=300", "eval_every=100", "eval_episodes=1",
             "medal.seed_steps=100", "medal.batch_size=16"]
    switched = []
    real = getattr(SAC, switch)
    monkeypatch.setattr(SAC, switch, lambda self, *a, **k: (switched.append(self), real(self, *a, **k))[1])
    tables = {}
    for mode in ("default", update):
        (spec,) = plan_words([*words, f"update={mode}", f"results={tmp_path / mode}"]).groups
        assert spec.update == mode and run_group(spec, "test") is None
        run = spec.member_dirs()[0]
        assert yaml.safe_load((run / "run.yaml").read_text())["update"] == mode
        tables[mode] = pd.read_parquet(run / "evals.parquet").query("metric == 'deployed_return'")
    assert len(switched) == 2  # MEDAL's forward and backward agents
    assert all(agent.static if update == "static" else agent._update_fn == agent._update_autograd for agent in switched)
    a, b = (tables[u].set_index("step").value for u in ("default", update))
    assert a.loc[0] == b.loc[0] and a.loc[100] == b.loc[100]  # no update before step 100
    np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=1e-3, atol=1e-3)


def test_use_static_updates_finds_every_agent():
    class TwoAgents:
        def __init__(self):
            self.forward, self.backward, self.other = SAC(O, A, [0]), SAC(O, A, [0]), object()

    algo = TwoAgents()
    assert use_static_updates(algo) == 2 and algo.forward.static and algo.backward.static


@requires_data
@pytest.mark.parametrize("algo", ["naive", "oracle", "fbrl", "r3l", "medal", "gail_naive", "risc", "vaprl", "bc"])
def test_use_static_updates_reaches_the_agents_of_registered_methods(algo):
    from algorithms.api import DemoSet
    from harness.data import load_demos
    from harness.envs import get_spec
    from harness.registry import ALGORITHMS

    cls, env = ALGORITHMS[algo], "tabletop_manipulation"
    agent = cls(get_spec(env), DemoSet(load_demos(env, "forward"), load_demos(env, "reverse")), cls.Config(), [0],
                torch.device("cpu"))
    want = {"bc": 0, "fbrl": 2, "r3l": 2, "medal": 2}.get(algo, 1)  # bc has no SAC agent
    assert use_static_updates(agent) == want
