"""Member envs stepped in worker processes (``env_workers``) give the same results as in the group's process: bit
for bit, through hard resets, algorithm-requested resets, evaluation, and a checkpoint taken in one kind of pool and
loaded into the other."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from harness.env_pool import LocalEnvs, WorkerEnvs, make_envs
from harness.protocol import Interaction, evaluate

from .conftest import requires_data
from .test_protocol import Scripted, _Cfg

pytestmark = requires_data
ENVS = ("tabletop_manipulation", "sawyer_door")


class Jittery(Scripted):
    """Seeded random actions in training, the scripted tabletop expert in evaluation; asks for a reset of member 0
    every 37 steps (``reset_every``): exercises every path of a step."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.rng = np.random.default_rng(0)

    def act(self, obs):
        return self.rng.uniform(-1, 1, (len(obs), self.task.act_dim))


def _roll(env, workers, steps, state=None):
    from harness.envs import get_spec

    seeds = [3, 1, 4]
    algo = Jittery(get_spec(env), None, _Cfg(reset_every=37), seeds, "cpu")
    inter = Interaction(env, seeds, workers)
    try:
        if state is None:
            inter.start(algo)
        else:
            inter.load_state_dict(state)
        trace = []
        for _ in range(steps):
            inter.step(algo)
            trace.append(inter.obs.copy())
        return np.stack(trace), inter.cum_reward.copy(), inter.interventions(), inter.state_dict()
    finally:
        inter.close()


@pytest.mark.parametrize("env", ENVS)
def test_worker_envs_step_exactly_as_local_ones_through_a_checkpoint(env):
    assert isinstance(make_envs(env, 3, 0), LocalEnvs)
    local = _roll(env, 0, 120)
    workers = _roll(env, 2, 120)  # slices of 2 and 1 members
    for a, b in zip(local[:3], workers[:3]):
        np.testing.assert_array_equal(a, b)
    assert local[2].sum() > 0  # the algorithm's resets count as interventions
    # a checkpoint of the worker pool resumes in a local pool and the other way round, continuing identically
    cont_local = _roll(env, 0, 60, workers[3])
    cont_workers = _roll(env, 3, 60, local[3])
    for a, b in zip(cont_local[:3], cont_workers[:3]):
        np.testing.assert_array_equal(a, b)


def test_evaluation_in_worker_envs_equals_local():
    from harness.envs import get_spec

    env = "tabletop_manipulation"
    algo = Jittery(get_spec(env), None, _Cfg(), [0, 1, 2], "cpu")
    local = make_envs(env, 3, 0, "eval")
    pool = make_envs(env, 3, 2, "eval")
    try:
        assert isinstance(pool, WorkerEnvs)
        a = evaluate(algo, local, [0, 1, 2], 20_000, 2)
        b = evaluate(algo, pool, [0, 1, 2], 20_000, 2)
    finally:
        pool.close()
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_a_run_with_env_workers_writes_the_same_results(tmp_path):
    from harness.planning import plan_words
    from harness.runner import run_group

    base = ["algo=medal", "env=tabletop_manipulation", "seeds=2", "members=2", "steps=200", "eval_every=100",
            "checkpoint_every=100", "eval_episodes=2", "medal.seed_steps=50", "medal.batch_size=16"]
    tables = []
    for workers in (0, 2):
        (spec,) = plan_words([*base, f"env_workers={workers}", f"results={tmp_path / str(workers)}"]).groups
        assert run_group(spec, "test") is None
        df = pd.concat(pd.read_parquet(d / "evals.parquet") for d in spec.member_dirs())
        tables.append(df[~df.metric.isin(["steps_per_s", "wall_s"])].reset_index(drop=True)[["seed", "step", "metric",
                                                                                             "value"]])
    pd.testing.assert_frame_equal(tables[0], tables[1])


def test_a_failing_worker_names_itself():
    pool = WorkerEnvs("tabletop_manipulation", 2, 2)
    try:
        with pytest.raises(RuntimeError, match=r"env worker 0: ValueError"):
            pool.step(np.zeros((2, 1)))  # wrong action size for the tabletop arm
        obs, *_ = pool.step(np.zeros((2, 3)))  # the pipes are still in step: the next command works
        assert obs.shape[0] == 2
    finally:
        pool.close()
