"""The EARL protocol loop: evaluation schedule and semantics, hard resets, results, exact resume."""

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

from algorithms.api import AFTER_STORE, AlgoConfig, Algorithm
from harness.envs import get_spec, make_env
from harness.protocol import RunSpec, eval_seed, evaluate, train
from harness.results import load, load_train

from .conftest import requires_data


@dataclass
class _Cfg(AlgoConfig):
    reset_every: int = 0


class Scripted(Algorithm):
    """A test algorithm: the scripted tabletop expert; records what the loop tells it."""

    Config = _Cfg

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        from harness.envs.experts import tabletop_expert

        self.expert = tabletop_expert
        self.resets: list[tuple[int, np.ndarray]] = []
        self.hard: list[int] = []
        self.t = 0
        self.observed = 0  # steps this process saw (not checkpointed, unlike t)

    def on_reset(self, obs, mask):
        self.resets.append((self.t, mask.copy()))

    def act(self, obs):
        return np.stack([self.expert(o) for o in obs])

    def observe(self, next_obs, hard_reset):
        self.t += 1
        self.observed += 1
        if hard_reset.any():
            self.hard.append(self.t)
        want = np.zeros(self.E, dtype=bool)
        if self.cfg.reset_every and self.t % self.cfg.reset_every == 0:
            want[0] = True
        return want

    def eval_act(self, obs):
        return np.stack([self.expert(o) for o in obs])

    def state_dict(self):
        return {"t": self.t}

    def load_state_dict(self, state):
        self.t = state["t"]


def _spec(tmp_path, **kw):
    base = dict(suite="t", env="tabletop_manipulation", algo="scripted", seeds=[0, 1], steps=1000, eval_every=250,
                eval_episodes=3, checkpoint_every=500, results=str(tmp_path))
    return RunSpec(**{**base, **kw})


def _algo(seeds, **cfg):
    return Scripted(get_spec("tabletop_manipulation"), None, _Cfg(**cfg), seeds, "cpu")


def test_eval_schedule_metrics_and_layout(tmp_path):
    spec = _spec(tmp_path)
    train(spec, _algo(spec.seeds))
    df = load(tmp_path)
    assert sorted(df["step"].unique()) == [0, 250, 500, 750, 1000]  # step 0, then every eval_every
    assert set(df["metric"]) == {"deployed_success", "deployed_return", "continuing_reward", "interventions",
                                 "steps_per_s", "wall_s"}
    for s in (0, 1):
        d = tmp_path / "t" / "tabletop_manipulation" / "scripted" / f"seed={s}"
        assert (d / "evals.parquet").exists() and (d / "status.json").exists()
    succ = df[df.metric == "deployed_success"]
    assert (succ.value == 1.0).all()  # the scripted expert solves every eval episode
    assert (df[df.metric == "interventions"].value == 0).all()  # H_T = 200k never reached


def test_status_stays_live_between_evaluations(tmp_path, monkeypatch):
    """`harness status` and the dashboard read status.json: a run rewrites it about every 10 s of training, not only
    at its evaluations (minutes apart on a slow env), with the step reached and the training rate."""
    import harness.protocol as protocol
    from harness.results import read_status

    clock = iter(np.arange(0.0, 1e9, 11.0))  # the loop reads the clock every 1,000 steps: each read 11 s later
    monkeypatch.setattr(protocol.time, "perf_counter", lambda: next(clock))
    seen = []
    real = protocol.write_status
    monkeypatch.setattr(protocol, "write_status", lambda d, **f: (seen.append(f), real(d, **f)))
    spec = _spec(tmp_path, steps=4000, eval_every=4000, seeds=[0])
    train(spec, _algo(spec.seeds))
    between = [f for f in seen if 0 < f["step"] < 4000]
    assert [f["step"] for f in between] == [1000, 2000, 3000]
    assert all(f["state"] == "running" and f["total"] == 4000 and f["steps_per_s"] > 0 for f in between)
    assert read_status(tmp_path / "t" / "tabletop_manipulation" / "scripted" / "seed=0")["state"] == "done"


def test_hard_reset_every_train_horizon_counts_interventions(tmp_path, monkeypatch):
    import harness.env_pool as env_pool
    from harness.envs import make_env, make_train_env

    monkeypatch.setattr(env_pool, "make_member_env",
                        lambda name, kind: make_train_env(name, horizon=300) if kind == "train" else make_env(name))
    spec = _spec(tmp_path, steps=1000, seeds=[0])
    algo = _algo(spec.seeds)
    train(spec, algo)
    assert algo.hard == [300, 600, 900]  # the env reports H_T as truncation; the loop resets it
    assert [t for t, _ in algo.resets] == [0, 300, 600, 900]
    inter = load(tmp_path).query("metric == 'interventions'").set_index("step")["value"]
    assert inter[250] == 0 and inter[500] == 1 and inter[750] == 2 and inter[1000] == 3


def test_algorithm_requested_resets_are_interventions(tmp_path):
    spec = _spec(tmp_path, seeds=[0, 1], steps=500)
    algo = _algo(spec.seeds, reset_every=100)
    train(spec, algo)
    inter = load(tmp_path).query("metric == 'interventions' and step == 500").set_index("seed")["value"]
    assert inter[0] == 5 and inter[1] == 0  # only member 0 asked


@dataclass
class _NanCfg(_Cfg):
    nan_from: int = 300  # member 1 acts NaN from this many steps on (protocol step nan_from + 1)
    in_eval: bool = False  # or its deployed policy does, from the first evaluation


class Diverging(Scripted):
    """The scripted expert until its member 1 returns NaN actions, as a diverged network would."""

    Config = _NanCfg

    def act(self, obs):
        a = super().act(obs)
        if self.t >= self.cfg.nan_from:
            a[1] = np.nan
        return a

    def eval_act(self, obs):
        a = super().eval_act(obs)
        if self.cfg.in_eval:
            a[1] = np.inf
        return a


@requires_data
@pytest.mark.parametrize("in_eval, where, steps_logged", [
    (False, "from seed 1 in training at step 301:", [0, 200]),
    (True, "from seed 1 in the evaluation at step 0:", []),
])
def test_nan_actions_stop_the_run_with_one_line_and_keep_what_was_written(in_eval, where, steps_logged, tmp_path,
                                                                          monkeypatch, capsys):
    """A diverged member (NaN/inf actions) ends the run before the action reaches an env or buffer: one error line
    naming the seed and step, exit 1, results and status kept as of the last evaluation, status ``failed``."""
    from harness.cli import main
    from harness.registry import ALGORITHMS
    from harness.results import read_status

    monkeypatch.setitem(ALGORITHMS, "diverging", Diverging)
    code = main(["run", "algo=diverging", "env=tabletop_manipulation", "seeds=2", "members=2", "steps=600",
                 "eval_every=200", "checkpoint_every=200", "eval_episodes=1", "workers=1", f"results={tmp_path}",
                 f"diverging.in_eval={in_eval}"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 1 and len(err) == 1, err
    assert "DivergedError: non-finite actions (NaN/inf) " + where in err[0]
    df = load(tmp_path)
    assert sorted(df["step"].unique()) == steps_logged
    for seed in (0, 1):
        st = read_status(tmp_path / "adhoc" / "tabletop_manipulation" / "diverging" / f"seed={seed}")
        assert st["state"] == "failed" and "DivergedError" in st["error"]
        # the status is written before the step-0 evaluation, so one that fails there says step 0 of 600
        assert st.get("step") == (steps_logged[-1] if steps_logged else 0) and st.get("total") == 600


def test_evaluate_any_step_success_and_deterministic_seeding():
    class Still(Scripted):
        def eval_act(self, obs):
            return np.zeros((len(obs), 3), np.float32)

    envs = [make_env("tabletop_manipulation") for _ in range(2)]
    succ, ret = evaluate(Still(get_spec("tabletop_manipulation"), None, _Cfg(), [0, 1], "cpu"), envs, [0, 1], 0, 4)
    assert (succ == 0).all() and (ret == 0).all()
    algo = _algo([0, 1])
    a = evaluate(algo, envs, [0, 1], 10_000, 4)
    b = evaluate(algo, [make_env("tabletop_manipulation") for _ in range(2)], [0, 1], 10_000, 4)
    np.testing.assert_array_equal(a[0], b[0])
    assert (a[0] == 1).all() and (a[1] > 0).all()


def _harness(args, results, **popen):
    cmd = [sys.executable, "-m", "harness.cli", "run", *args, f"results={results}", "workers=1"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen)


RESUME_ARGS = ["algo=medal", "env=tabletop_manipulation", "seeds=1", "steps=1200", "eval_every=100",
               "checkpoint_every=200", "eval_episodes=2", "all.seed_steps=100", "all.batch_size=32",
               "all.buffer_capacity=20000", "medal.switch_every=40", "medal.disc_batch=32"]


def _comparable(df: pd.DataFrame) -> pd.DataFrame:
    df = df[~df.metric.isin(["steps_per_s", "wall_s"])]
    return df.sort_values(["seed", "step", "metric"]).reset_index(drop=True)[["seed", "step", "metric", "value"]]


@pytest.mark.parametrize("eval_every", [1, 100, 250, 999, 1000, 10_000])
def test_evaluation_seeds_never_repeat_for_any_schedule(eval_every):
    """Every evaluation of a run (seeds 0-9, 3M steps) starts from its own env seed, including across member seeds, and
    EARL's schedules (multiples of 1000) keep the seeds the shipped results were evaluated with."""
    steps = range(0, 3_000_001 if eval_every >= 100 else 20_001, eval_every)
    seeds = [eval_seed(s, t) for s in range(10) for t in steps]
    assert len(set(seeds)) == len(seeds)
    assert eval_seed(3, 250_000) == (3 * 1_000_003 + 250) % (2**31 - 1)


def test_keep_every_keeps_earlier_checkpoints_and_restores_one_lost_to_a_kill(tmp_path):
    """keep_every=500: the checkpoints at 500 and 1000 stay beside checkpoint.pt, each holding its own step. A run
    stopped between writing the 500 checkpoint and keeping it (simulated: the kept file removed) keeps it on resume;
    keep_every=0 keeps nothing extra."""
    import torch

    def kept(spec):
        return sorted(p.name for p in spec.checkpoint_path().parent.iterdir())

    spec = _spec(tmp_path, eval_every=250, checkpoint_every=250, keep_every=500)
    train(spec, _algo(spec.seeds), should_stop=lambda: True)  # stops after its first evaluation past step 0: 250
    train(spec, _algo(spec.seeds), should_stop=lambda: True)  # 500: checkpoint, then kept
    assert kept(spec) == ["checkpoint-500.pt", "checkpoint.pt"]
    (spec.checkpoint_path().parent / "checkpoint-500.pt").unlink()
    train(spec, _algo(spec.seeds))
    assert kept(spec) == ["checkpoint-1000.pt", "checkpoint-500.pt", "checkpoint.pt"]  # no temporary file left
    for name, step in (("checkpoint-500.pt", 500), ("checkpoint-1000.pt", 1000), ("checkpoint.pt", 1000)):
        assert torch.load(spec.checkpoint_path().parent / name, weights_only=False)["step"] == step
    plain = _spec(tmp_path / "plain", eval_every=250, checkpoint_every=250)
    train(plain, _algo(plain.seeds))
    assert kept(plain) == ["checkpoint.pt"]


def test_a_raised_budget_continues_a_finished_run(tmp_path):
    """A run finished at steps=500, then run with steps=1000, goes on from its final checkpoint (nothing redone, no
    row twice) and its results equal a run straight to 1000."""
    def run(where, steps):
        spec = _spec(where, steps=steps)
        algo = _algo(spec.seeds, reset_every=300)
        train(spec, algo)
        return algo

    run(tmp_path / "raised", 500)
    again = run(tmp_path / "raised", 1000)
    assert (again.t, again.observed) == (1000, 500)  # resumed at 500
    run(tmp_path / "straight", 1000)
    a, b = (_comparable(load(tmp_path / w)) for w in ("raised", "straight"))
    assert len(a) == 2 * 5 * 4 and a[a.metric == "interventions"].value.max() > 0
    pd.testing.assert_frame_equal(a, b)


@requires_data
def test_resume_after_sigkill_equals_uninterrupted_run(tmp_path):
    ref = _harness(RESUME_ARGS, tmp_path / "ref")
    out, _ = ref.communicate(timeout=600)
    assert ref.returncode == 0, out
    # a second run, killed at a random point after its first checkpoint, then re-run
    ckpt = next((tmp_path / "ref").rglob("checkpoint.pt")).relative_to(tmp_path / "ref")
    p = _harness(RESUME_ARGS, tmp_path / "killed")
    deadline = time.time() + 600
    while not (tmp_path / "killed" / ckpt).exists() and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(np.random.default_rng().uniform(0.0, 1.5))
    p.send_signal(signal.SIGKILL)
    p.wait()
    again = _harness(RESUME_ARGS, tmp_path / "killed")
    out, _ = again.communicate(timeout=600)
    assert again.returncode == 0, out
    a, b = _comparable(load(tmp_path / "ref")), _comparable(load(tmp_path / "killed"))
    assert len(a) == len(b) == 13 * 4  # steps 0..1200 every 100, 4 deterministic metrics: no loss, no duplicate
    pd.testing.assert_frame_equal(a, b)
    # the training diagnostics (train.parquet, every log_every = 100 steps) resume exactly too
    ta, tb = (_comparable(load_train(tmp_path / w)) for w in ("ref", "killed"))
    assert sorted(set(ta["step"])) == list(range(100, 1201, 100))
    assert {"forward/critic_loss", "backward/batch_reward", "discriminator/accuracy", "phase/backward"} <= set(ta.metric)
    pd.testing.assert_frame_equal(ta, tb)


def test_results_are_joinable_with_published_curves(tmp_path):
    from harness.results import load_published

    spec = _spec(tmp_path, steps=250, seeds=[0])
    train(spec, _algo(spec.seeds))
    ours = load(tmp_path)
    try:
        pub = load_published()
    except Exception as e:  # data dir missing
        pytest.skip(str(e))
    both = pd.concat([ours, pub], ignore_index=True)
    assert {"harness", "earl_benchmark", "risc_paper"} <= set(both["source"])
    assert "deployed_success" in set(pub["metric"]) and "algo" in pub.columns


@requires_data
def test_a_full_disk_is_named_and_the_run_resumes_to_the_same_rows(tmp_path, monkeypatch):
    """A checkpoint write that fails on a full disk (torch's own message, with the disk reported nearly full) stops the
    run with one line naming the disk and the way on; the last checkpoint stays, and the same command then writes
    the rows an uninterrupted run writes."""
    import shutil

    import torch

    from harness import protocol
    from harness.planning import plan_words
    from harness.runner import run_group

    words = ["algo=naive", "env=tabletop_manipulation", "steps=300", "eval_every=100", "checkpoint_every=100",
             "eval_episodes=1", "naive.seed_steps=50", "naive.batch_size=16"]
    (ref,) = plan_words([*words, f"results={tmp_path / 'ref'}"]).groups
    assert run_group(ref, "test") is None
    (spec,) = plan_words([*words, f"results={tmp_path / 'full'}"]).groups
    real_save, calls = torch.save, []

    def save(obj, f, *a, **k):
        calls.append(f)
        if len(calls) == 2:  # the checkpoint at step 200
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 64 vs 0")
        return real_save(obj, f, *a, **k)

    monkeypatch.setattr(protocol.torch, "save", save)
    real_usage = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda p: real_usage(p)._replace(free=1 << 20))
    err = run_group(spec, "test")
    assert err is not None and "is full (1 MiB free) while writing checkpoint.pt" in err and "resume" in err
    assert "enforce fail" not in err
    monkeypatch.undo()
    assert run_group(spec, "test") is None  # resumed from the checkpoint at 100
    pd.testing.assert_frame_equal(_comparable(load(tmp_path / "ref")), _comparable(load(tmp_path / "full")))
    pd.testing.assert_frame_equal(_comparable(load_train(tmp_path / "ref")), _comparable(load_train(tmp_path / "full")))


class HookOrder(Scripted):
    """Records the hooks the loop calls, in order."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.calls: list[str] = []

    def on_reset(self, obs, mask):
        self.calls.append("on_reset")
        super().on_reset(obs, mask)

    def act(self, obs):
        self.calls.append("act")
        return super().act(obs)

    def update(self):
        self.calls.append("update")

    def store(self, next_obs, hard_reset):
        self.calls.append("store")

    def observe(self, next_obs, hard_reset):
        self.calls.append("observe")
        return super().observe(next_obs, hard_reset)


class HookOrderAfterStore(HookOrder):
    update_at = AFTER_STORE


@pytest.mark.parametrize("cls, order", [(HookOrder, ["act", "update", "store", "observe"]),
                                        (HookOrderAfterStore, ["act", "store", "update", "observe"])])
def test_the_loop_calls_update_where_the_algorithm_says_and_tests_step_the_same(tmp_path, cls, order):
    """Issue 54: the update is the loop's call, once per training step, after act (MEDAL's order: before the env moves)
    or after store (RISC's order: before observe picks goals); tests/stepping.py's take_step keeps the loop's order."""
    from tests.stepping import take_step

    spec = _spec(tmp_path, seeds=[0], steps=20, eval_every=10, checkpoint_every=10)
    algo = cls(get_spec("tabletop_manipulation"), None, _Cfg(), spec.seeds, "cpu")
    train(spec, algo)
    steps = [c for c in algo.calls if c != "on_reset"]
    assert steps == order * 20 and algo.calls[0] == "on_reset"
    algo.calls.clear()
    obs = make_env("tabletop_manipulation").reset(seed=0)[0][None].astype(np.float32)
    take_step(algo, obs, obs, np.zeros(1, bool))
    assert algo.calls == order
