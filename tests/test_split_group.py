"""scripts/split_group.py: a group's checkpoint split into single-seed checkpoints resumes each seed as the group
would have gone on (to float rounding, as two single-seed runs equal one two-member run), and one process per seed."""

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness.cli import main

from .conftest import requires_data

WORDS = ["algo=medal", "env=tabletop_manipulation", "seeds=2", "eval_every=100", "checkpoint_every=100",
         "eval_episodes=1", "all.seed_steps=50", "all.batch_size=16", "workers=1"]
KEY = ["step", "metric"]


def _script():
    spec = importlib.util.spec_from_file_location("split_group", Path(__file__).parents[1] / "scripts" / "split_group.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rows(results: Path, seed: int, table: str) -> pd.DataFrame:
    df = pd.read_parquet(results / f"adhoc/tabletop_manipulation/medal/seed={seed}/{table}.parquet")
    return df[~df.metric.isin(["steps_per_s", "wall_s", "eta_s"])][[*KEY, "value"]]


@requires_data
def test_split_seeds_resume_as_the_group_goes_on(tmp_path):
    group, split = tmp_path / "group", tmp_path / "split"
    assert main(["run", *WORDS, "steps=200", "members=2", f"results={group}"]) == 0
    import shutil

    shutil.copytree(group, split)
    ckpt = split / "adhoc/tabletop_manipulation/medal/checkpoints/seeds=0-1/checkpoint.pt"
    written = _script().split(ckpt)
    assert [p.parent.name for p in written] == ["seeds=0", "seeds=1"] and not ckpt.exists()
    assert (ckpt.parent.with_name("seeds=0-1.split") / "checkpoint.pt").exists()
    with pytest.raises(SystemExit, match="a group of one seed"):
        _script().split(written[0])

    assert main(["run", *WORDS, "steps=400", "members=2", f"results={group}"]) == 0
    assert main(["run", *WORDS, "steps=400", f"results={split}"]) == 0  # one group per seed, each from step 200
    for seed in (0, 1):
        for table in ("evals", "train"):
            a, b = _rows(group, seed, table), _rows(split, seed, table)
            m = a.merge(b, on=KEY, suffixes=("_group", "_split"))
            assert len(m) == len(a) == len(b) and m.step.max() == 400
            np.testing.assert_allclose(m.value_split, m.value_group, rtol=1e-5, atol=1e-6, err_msg=f"{table} {seed}")


def test_an_unknown_layout_is_refused_not_guessed():
    import torch

    member_state = _script().member_state
    with pytest.raises(ValueError, match="not a multiple of 2 members"):
        member_state({"x": torch.zeros(3)}, 2, 0)
    with pytest.raises(ValueError, match="no 'actor' beside it"):
        member_state({"actor_opt": {"exp_avg": torch.zeros(4), "exp_avg_sq": torch.zeros(4), "step": torch.zeros(2)}},
                     2, 0)
    with pytest.raises(ValueError, match="does not know how to split"):
        member_state({"pairs": [(1, 2)]}, 2, 0)
