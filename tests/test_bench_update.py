"""``harness bench update``: the matmul ceiling replays exactly the products of one SAC update, and the split inside
the update accounts for its time. Speeds are measured by the bench, never asserted here."""

import pytest
import torch

from algorithms.core import SAC, SACConfig
from harness.backends import keep_freed_memory, use_allocator
from harness.bench.update import RECORD_HEADER, measure_update, record_row
from harness.words import ConfigError

from .conftest import requires_data


@pytest.mark.parametrize("use_trunk, products", [(True, 37), (False, 28)])
@pytest.mark.parametrize("update", ["default", "static", "autograd"])
def test_ceiling_replays_the_update_s_own_products(use_trunk, products, update):
    """Counted by hand from sac.SAC._update: forwards of the actor on [o'; o] (4 with the trunk), the target critic
    (4), the critic (4), the critic at pi's action (4), the actor for the temperature (4); backwards of the critic (3
    weight, 3 input, 1 trunk weight), of dQ/da (3 input) and of the actor (3 weight, 3 input, 1 trunk weight). Without
    the trunk: 5 forward and 2 trunk-weight products fewer, and neither network's input gradient (2 more). The split exists for the manual eager paths only."""
    agent = SAC(5, 2, [0, 1], SACConfig(hidden_dim=16, feature_dim=8, use_trunk=use_trunk, batch_size=8))
    r = measure_update(agent, update, repeats=1, n=2)
    assert r["products"] == products
    assert r["update_ms"] > 0 and r["ceiling_ms"] > 0 and r["ratio"] > 0
    if update == "autograd":
        assert r["split_ms"] == {} and agent._update_fn == agent._update_autograd
    else:
        assert set(r["split_ms"]) == {"products", "optimizer", "target", "sampling", "other"}
        assert all(v >= 0 for v in r["split_ms"].values())


def test_keep_freed_memory_leaves_results_unchanged():
    """The allocator setting of every training process changes where memory comes from, never a value."""
    def run():
        agent = SAC(5, 2, [3], SACConfig(hidden_dim=16, feature_dim=8, batch_size=8))
        g = torch.Generator().manual_seed(0)
        batch = {"obs": torch.randn(1, 8, 5, generator=g), "next_obs": torch.randn(1, 8, 5, generator=g),
                 "action": torch.rand(1, 8, 2, generator=g) * 2 - 1, "reward": torch.rand(1, 8, generator=g),
                 "terminal": torch.zeros(1, 8, dtype=torch.bool), "truncated": torch.zeros(1, 8, dtype=torch.bool)}
        for _ in range(5):
            agent.update(batch)
        return agent.state_dict()["actor"]

    before = run()
    assert keep_freed_memory() in (True, False)  # False where the C library is not glibc
    after = run()
    assert all(torch.equal(before[k], after[k]) for k in before)
    with pytest.raises(ConfigError, match="unknown allocator 'tcmalloc'; known: keep, glibc"):
        use_allocator("tcmalloc")


def test_record_appends_rows_under_one_header(tmp_path):
    """``record=`` keeps the prose of the file, adds the table's header once and a row per measurement, each with
    its date, commit and CPU."""
    path = tmp_path / "performance.md"
    path.write_text("# Performance\n\nSome prose.\n")
    r = {"cpu": "Test CPU (AVX2)", "threads": 1, "update_ms": 12.345, "ceiling_ms": 9.0, "ratio": 0.729}
    record_row(path, r, "medal", "sawyer_door", 1, "default", "keep")
    record_row(path, {**r, "update_ms": 9.5, "ratio": 0.947}, "medal", "sawyer_door", 1, "compiled", "keep")
    text = path.read_text()
    assert text.startswith("# Performance\n\nSome prose.\n") and text.count(RECORD_HEADER) == 1
    rows = text.split(RECORD_HEADER)[1].splitlines()
    assert len(rows) == 2 and "| Test CPU (AVX2) |" in rows[0]
    assert rows[0].endswith("| default | keep | 12.35 | 9.00 | 0.73 |")
    assert rows[1].endswith("| compiled | keep | 9.50 | 9.00 | 0.95 |")


@requires_data
def test_bench_train_from_a_checkpoint_trains_on_from_its_state(tmp_path):
    """``harness bench train checkpoint=``: the run's own algo, env, seeds and config (run.yaml), its saved state, and
    the same digest from the same checkpoint; a missing one is one line."""
    from pathlib import Path

    from harness.bench.train import bench_train_from
    from harness.cli import main
    from harness.words import UsageError

    assert main(["run", "algo=medal", "env=tabletop_manipulation", "seeds=2", "members=2", "steps=300",
                 "eval_every=100", "checkpoint_every=100", "eval_episodes=1", "all.seed_steps=100",
                 "all.batch_size=32", f"results={tmp_path}", "workers=1"]) == 0
    ckpt = next(Path(tmp_path).glob("**/checkpoints/seeds=0-1/checkpoint.pt"))
    lines: list[str] = []
    first = bench_train_from(ckpt, steps=5, device="cpu", repeats=1, log=lines.append)
    again = bench_train_from(ckpt, steps=5, device="cpu", repeats=1, log=lambda _: None)
    assert "at step 300" in lines[0] and "members=2" in lines[1] and "update=default" in lines[1]
    assert first["digest"] == again["digest"] and len(first["digest"]) == 16
    with pytest.raises(UsageError, match="not found"):
        bench_train_from(ckpt.parent / "nope.pt", steps=5, device="cpu")
