"""How a suite is laid onto a machine (harness.packing): CPU packing as it always was, GPU nodes packed by seeds per
process, processes per GPU and env workers, explicit values winning."""

from __future__ import annotations

import pytest

from harness.backends import ray_options
from harness.packing import GPU_MAX_MEMBERS, GiB, Machine, Work, member_bytes, pack, split
from harness.planning import build_plan
from harness.request import RunRequest

from .conftest import requires_data

CPU2 = Machine(cores=2, memory=24 * GiB)
H200 = Machine(cores=16, memory=128 * GiB, gpus=1, gpu_memory=139 * GiB, gpu_name="H200")
NODE8 = Machine(cores=64, memory=512 * GiB, gpus=8, gpu_memory=80 * GiB, gpu_name="H100")
TABLE1 = [Work(5, steps, 14, 4) for steps in (3_000_000, 5_000_000, 8_000_000) for _ in range(6)]  # 18 cells x 5


def test_cpu_packing_is_one_process_per_core_and_the_suites_members():
    p = pack(TABLE1, "cpu", CPU2)
    assert p.members == (1,) * 18 and p.workers == 2 and p.env_workers == 0 and p.devices == ("cpu",)
    cells = pack([Work(3, 1000, 12, 3, cpu_members=3), Work(2, 1000, 12, 3, members=1, cpu_members=2)], "cpu", CPU2)
    assert cells.members == (3, 1)  # a cell's seeds by default; its own members= wins


def test_table1_on_one_gpu_is_one_process_per_cell_and_core():
    p = pack(TABLE1, "cuda", H200)
    assert p.members == (5,) * 18  # every seed of a cell in one process
    assert p.workers == 16 and p.per_device == 16 and p.devices == ("cuda",)  # cores bound the processes
    assert p.env_workers == 0  # no core left over


def test_many_seeds_split_evenly_and_spare_cores_step_envs_on_a_multi_gpu_node():
    assert split(300, GPU_MAX_MEMBERS) == 100 and split(128, GPU_MAX_MEMBERS) == 128 and split(5, 128) == 5
    p = pack([Work(300, 1_000_000, 14, 4), Work(128, 1_000_000, 14, 4)], "cuda", NODE8)
    assert p.members == (100, 128)
    assert p.workers == 4  # 3 + 1 groups
    assert p.devices == tuple(f"cuda:{i}" for i in range(8)) and p.device_of(9) == "cuda:1"
    assert p.env_workers == min(128, (64 - 4) // 4)
    assert pack([Work(300, 1000, 14, 4)], "cuda:3", NODE8).devices == ("cuda:3",)  # a pinned GPU stays pinned


def test_gpu_memory_bounds_the_processes_per_gpu():
    big = Work(64, 8_000_000, 14, 4)
    need = member_bytes(big) * 64
    small = Machine(cores=32, memory=256 * GiB, gpus=1, gpu_memory=int(2.5 * need))
    p = pack([big] * 6, "cuda", small)
    assert p.per_device == 2 and p.workers == 2


def test_given_values_win():
    p = pack(TABLE1, "cuda", H200, members=2, workers=3, env_workers=0)
    assert p.members == (2,) * 18 and p.workers == 3 and p.env_workers == 0
    assert any("given" in r for r in p.reasons)
    assert pack(TABLE1, "cpu", CPU2, workers=500).workers == 90  # never more processes than groups (18 x 5 seeds)


def test_ray_reserves_a_share_of_a_gpu():
    assert ray_options("cuda", 1, per_gpu=4)["num_gpus"] == 0.25
    assert "num_gpus" not in ray_options("cpu", 1)


@requires_data
def test_a_plan_for_a_gpu_node_spreads_the_cells_over_its_gpus(monkeypatch):
    monkeypatch.setattr(Machine, "detect", classmethod(lambda cls: NODE8.__class__(
        cores=32, memory=256 * GiB, gpus=2, gpu_memory=80 * GiB, gpu_name="H100")))
    plan = build_plan(RunRequest(suite="earl_sparse", device="cuda"))
    assert len(plan.groups) == 18 and {len(g.seeds) for g in plan.groups} == {5}
    assert [g.device for g in plan.groups[:4]] == ["cuda:0", "cuda:1", "cuda:0", "cuda:1"]
    # 80 GiB holds any 7 groups at once (6 peg groups of ~11.7 GiB and a door one, upper bounds): 7 per GPU
    assert plan.per_device == 7 and plan.workers == 14 and "2 x H100" in plan.machine
    assert {g.env_workers for g in plan.groups} == {0}  # 32 cores, 14 processes: 1 spare core each, not worth it


@requires_data
@pytest.mark.parametrize("words, members, workers", [((), 1, 2), (("members=5",), 5, 2), (("workers=1",), 1, 1)])
def test_cpu_plans_are_unchanged(words, members, workers, monkeypatch):
    monkeypatch.setattr(Machine, "detect", classmethod(lambda cls: CPU2))
    plan = build_plan(RunRequest.from_words(["suite=earl_sparse", *words]))
    assert {len(g.seeds) for g in plan.groups} == {members} and plan.workers == workers
    assert {g.device for g in plan.groups} == {"cpu"} and {g.env_workers for g in plan.groups} == {0}


def test_cpu_training_processes_get_one_torch_thread(tmp_path):
    """Issue 58: one group on a shared 2-core machine must not stall on a second intra-op thread."""
    from harness.backends import process_threads
    from harness.planning import plan_words

    for workers in ("1", "2"):
        plan = plan_words(["algo=naive", "env=tabletop_manipulation", "seeds=2", "members=1", f"workers={workers}",
                           f"results={tmp_path}"])
        assert process_threads(plan) == 1


@requires_data
def test_forward_backward_cells_train_one_seed_per_cpu_process_and_checkpointed_groups_stay(tmp_path, monkeypatch):
    """A step of MEDAL updates each seed's acting controller only: two seeds in different phases as members of one
    process would run both controllers' updates (Algorithm.phase_split_updates). A group that has a checkpoint keeps
    its seeds, so the run resumes instead of starting again."""
    monkeypatch.setattr(Machine, "detect", classmethod(lambda cls: CPU2))
    suite = tmp_path / "cells.yaml"
    suite.write_text("seeds: 2\ncells:\n  - {algo: medal, env: tabletop_manipulation, steps: 1000}\n"
                     "  - {algo: oracle, env: tabletop_manipulation, steps: 1000}\n")
    words = [f"suite={suite}", f"results={tmp_path / 'r'}"]
    plan = build_plan(RunRequest.from_words(words))
    assert sorted((g.algo, g.seeds) for g in plan.groups) == [("medal", (0,)), ("medal", (1,)), ("oracle", (0, 1))]
    assert any("one seed per process for medal" in r for r in plan.packing)
    assert {g.seeds for g in build_plan(RunRequest.from_words([*words, "members=2"])).groups} == {(0, 1)}

    ckpt = plan.groups[0].checkpoint_path().parent.parent / "seeds=0-1" / "checkpoint.pt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"")
    plan = build_plan(RunRequest.from_words(words))
    assert sorted((g.algo, g.seeds) for g in plan.groups) == [("medal", (0, 1)), ("oracle", (0, 1))]
    assert [g.seeds for g in build_plan(RunRequest.from_words([*words, "seeds=3"])).groups if g.algo == "medal"] == [
        (0, 1), (2,)]
    from harness.suites import ConfigError

    with pytest.raises(ConfigError, match=r"seed\(s\) 1 train in the group seeds=0-1 .* select all its seeds"):
        build_plan(RunRequest.from_words([*words, "seeds=1,"]))  # alone, seed 1 would start again from step 0
