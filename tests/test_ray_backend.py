"""`harness run backend=ray`: the same deterministic rows as the local backend, a task whose worker
is SIGKILLed is retried and resumes from its checkpoint, Ctrl-C exits 130, bad backends exit 2."""

import json
import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from harness.backends import TEST_KILL_ENV
from harness.cli import main
from harness.results import load
from harness.runner import run_cli

from .conftest import requires_data

ray = pytest.importorskip("ray", reason="Ray is not installed here (pip install ray); backend=ray is untested")

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", "RAY_AUTH_MODE": "disabled"}
SMALL = ["algo=medal", "env=tabletop_manipulation", "seeds=1", "steps=600", "eval_every=100", "checkpoint_every=200",
         "eval_episodes=1", "all.seed_steps=100", "all.batch_size=32"]


def _deterministic(df):
    df = df[~df.metric.isin(["steps_per_s", "wall_s"])]
    return df.sort_values(["algo", "seed", "step", "metric"]).reset_index(drop=True)[["algo", "seed", "step", "metric", "value"]]


@pytest.fixture(scope="module")
def local_ray():
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_unknown_backend_one_line_exit_2(tmp_path, capsys):
    assert main(["run", "algo=medal", "env=tabletop_manipulation", "backend=nope", f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown backend 'nope'" in err and not (tmp_path / "r").exists()
    assert main(["run", "algo=medal", "env=tabletop_manipulation", "ray_address=auto", f"results={tmp_path / 'r'}"]) == 2
    assert "only used with backend=ray" in capsys.readouterr().err


@requires_data
def test_ray_rows_equal_local_rows(local_ray, tmp_path):
    # the whole smoke suite (every registered algorithm) on tabletop, the cheapest env
    smoke = ["suite=smoke", "envs=tabletop_manipulation", "workers=2"]
    assert run_cli([*smoke, f"results={tmp_path / 'local'}"]) == 0
    assert run_cli([*smoke, "backend=ray", f"results={tmp_path / 'ray'}"]) == 0
    a, b = load(tmp_path / "local"), load(tmp_path / "ray")
    assert len(a) and set(a.suite) == {"smoke"}
    pd.testing.assert_frame_equal(_deterministic(a), _deterministic(b))


@requires_data
def test_killed_ray_task_is_retried_and_resumes(local_ray, tmp_path, monkeypatch):
    assert run_cli([*SMALL, "workers=1", f"results={tmp_path / 'ref'}"]) == 0
    marker = tmp_path / "killed.pid"
    monkeypatch.setenv(TEST_KILL_ENV, str(marker))  # the task SIGKILLs its worker after the first checkpoint
    assert run_cli([*SMALL, "backend=ray", f"results={tmp_path / 'killed'}"]) == 0
    assert marker.exists()  # the worker was killed once ...
    a, b = _deterministic(load(tmp_path / "ref")), _deterministic(load(tmp_path / "killed"))
    assert len(a) == 7 * 4
    pd.testing.assert_frame_equal(a, b)  # ... and Ray's retry resumed from the checkpoint


@requires_data
def test_ctrl_c_cancels_and_exits_130(tmp_path):
    words = ["steps=100000" if w.startswith("steps=") else w for w in SMALL]
    p = subprocess.Popen([sys.executable, "-m", "harness.cli", "run", *words, "backend=ray",
                          f"results={tmp_path}"], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 600  # Ray's start and the first evaluation take ~80 s on a loaded 2-core machine
    while not list(tmp_path.rglob("evals.parquet")) and time.time() < deadline:
        assert p.poll() is None, p.communicate()[0]
        time.sleep(0.1)
    if not list(tmp_path.rglob("evals.parquet")):  # fail on what happened, not on a missing status.json later
        p.kill()
        pytest.fail("no evaluation written within 600 s:\n" + p.communicate()[0])
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 130, out
    assert "cancelling 1 Ray task" in out and "run the same command again to resume" in out
    status = json.loads(next(tmp_path.rglob("status.json")).read_text())
    assert status["state"] == "interrupted"
