"""`harness run` end to end: the smoke suite over the whole registry, seed batching, resume after
SIGKILL for every registered algorithm, and bad input (one line, exit 2, nothing written)."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness.cli import main
from harness.registry import ALGORITHMS
from harness.results import load, read_status

from .conftest import requires_data

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}


def harness(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "harness.cli", *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, **kw)


def finished(*args, timeout=1500):
    p = harness(*args)
    out, _ = p.communicate(timeout=timeout)
    assert p.returncode == 0, out
    return out


#: what runs on EARL's kitchen and minitaur (no demonstrations there, and EARL's dense reward to learn from)
RETURN_ENV_ALGOS = ("naive", "oracle", "fbrl", "r3l", "risc", "risc_no_tab")


@requires_data
def test_smoke_suite_every_algorithm_every_env(tmp_path):
    out = finished("run", "suite=smoke", f"results={tmp_path}", "workers=2")
    df = load(tmp_path)
    envs = ("tabletop_manipulation", "sawyer_door", "sawyer_peg", "kitchen", "minitaur")
    assert set(zip(df.algo, df.env)) == {(a, e) for a in ALGORITHMS for e in envs
                                         if e not in ("kitchen", "minitaur") or a in RETURN_ENV_ALGOS}, out
    for algo in ALGORITHMS:
        for env in envs if algo in RETURN_ENV_ALGOS else envs[:3]:
            d = df[(df.algo == algo) & (df.env == env) & (df.metric == "deployed_success")]
            assert sorted(d.step) == [0, 200, 400], (algo, env, out)
            st = read_status(tmp_path / "smoke" / env / algo / "seed=0")
            assert st["state"] == "done" and st["step"] == 400
    assert (df.source == "harness").all() and df.git_sha.notna().all() and (df.members == 1).all()


@requires_data
def test_seed_batched_members(tmp_path):
    finished("run", "suite=smoke", "members=2", "seeds=2", "envs=tabletop_manipulation", f"results={tmp_path}",
             "workers=1")
    df = load(tmp_path)
    for algo in ALGORITHMS:
        d = df[(df.algo == algo) & (df.metric == "deployed_success")]
        assert sorted(d.seed.unique()) == [0, 1] and (df[df.algo == algo].members == 2).all(), algo
        assert len(d) == 6


def _deterministic(df):
    df = df[~df.metric.isin(["steps_per_s", "wall_s"])]
    return df.sort_values(["seed", "step", "metric"]).reset_index(drop=True)[["seed", "step", "metric", "value"]]


@requires_data
@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_resume_after_sigkill(algo, tmp_path):
    args = ["run", f"algo={algo}", "env=tabletop_manipulation", "seeds=1", "steps=400", "eval_every=100",
            "checkpoint_every=100", "eval_episodes=1", "all.batch_size=32", "workers=1"]
    if "seed_steps" in ALGORITHMS[algo].Config.keys():  # BC has no seed phase
        args.append("all.seed_steps=100")
    finished(*args, f"results={tmp_path / 'ref'}")
    p = harness(*args, f"results={tmp_path / 'killed'}")
    deadline = time.time() + 600
    while not list((tmp_path / "killed").rglob("checkpoint.pt")) and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(np.random.default_rng().uniform(0.0, 1.0))
    p.send_signal(signal.SIGKILL)
    p.wait()
    finished(*args, f"results={tmp_path / 'killed'}")
    a, b = _deterministic(load(tmp_path / "ref")), _deterministic(load(tmp_path / "killed"))
    assert len(a) == 5 * 4  # steps 0..400 every 100, 4 deterministic metrics: none lost, none duplicated
    pd.testing.assert_frame_equal(a, b)


def test_dry_run_prints_plan(tmp_path, capsys):
    """Both cases on purpose: no calibration on record (each test has an empty state directory, whatever dry runs
    the user made before), then one this test writes itself."""
    from harness import calibration
    from harness.data import state_dir
    from harness.planning import plan_words
    from harness.run_status import format_duration

    words = ["run", "suite=earl_sparse", f"results={tmp_path}"]
    assert main([*words, "--dry-run", "calibrate=false"]) == 0
    out = capsys.readouterr()
    assert "estimated time: not measured yet on this machine" in out.out and "sawyer_peg" in out.out
    assert not list(tmp_path.iterdir()) and not (state_dir() / "calibration.json").exists()

    plan = plan_words(words[1:])
    threads = calibration.worker_threads(plan.workers)
    cache = {calibration.key(g, threads): 100.0 for g in plan.groups}  # 100 steps/s per seed, every group
    (state_dir() / "calibration.json").parent.mkdir(parents=True)
    (state_dir() / "calibration.json").write_text(json.dumps(cache))
    assert main([*words, "--dry-run", "calibrate=false"]) == 0
    out = capsys.readouterr().out
    assert "not measured yet" not in out and out.count("100.0 steps/s per seed") == len(plan.groups)
    # steps per member of each group, none done, its first seed_steps (no updates) not timed; an entry without an
    # evaluation cost adds the usual share
    work = [(g.steps, g.steps / ((g.steps - g.config["seed_steps"]) / 100.0 * (1 + calibration.EVAL_SHARE)))
            for g in plan.groups]
    assert f"estimated time: {format_duration(calibration.estimate(work, plan.workers))} on" in out
    assert "(evaluations add ~3% where not measured;" in out
    assert not list(tmp_path.iterdir())
    # a group within seed_steps whose evaluation cost is not on record: no update to time, nothing to divide by zero
    words = ["run", "algo=naive", "env=sawyer_door", "steps=5000", f"results={tmp_path}"]
    (g,) = plan_words(words[1:]).groups
    (state_dir() / "calibration.json").write_text(json.dumps({**cache, calibration.key(g, threads): 100.0}))
    assert main([*words, "--dry-run", "calibrate=false"]) == 0
    assert "estimated time: 0m00s" in capsys.readouterr().out
    (state_dir() / "calibration.json").write_text(json.dumps(cache))
    # short groups (the smoke suite's 400 steps) are not measured: that would take as long as running them
    assert main(["run", "suite=smoke", f"results={tmp_path}", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "calibrating" not in out and "estimated time: not measured: every group is short (at most 2,000" in out
    assert json.loads((state_dir() / "calibration.json").read_text()) == cache


def test_the_estimate_counts_each_envs_evaluations_as_measured():
    """An evaluation costs eval_episodes x H_E steps every eval_every: 10 x 1000 on minitaur (as many env steps as the
    training between two evaluations), 10 x 200 on peg."""
    from harness import calibration
    from harness.plan import RunSpec

    minitaur = RunSpec(suite="s", env="minitaur", algo="risc", algo_class="risc", seeds=(0, 1), steps=2_000_000)
    peg = RunSpec(suite="s", env="sawyer_peg", algo="risc", algo_class="risc", seeds=(0, 1), steps=2_000_000)
    # 20 steps/s per member: 100,000 s of training; 200 evaluations of 10 episodes at 4 ms per evaluation step
    assert calibration.group_seconds(minitaur, 2_000_000, 20.0, 0.004) == pytest.approx(100_000 + 200 * 10 * 1000 * 0.004)
    assert calibration.group_seconds(peg, 2_000_000, 20.0, 0.004) == pytest.approx(100_000 + 200 * 10 * 200 * 0.004)
    assert calibration.group_seconds(peg, 2_000_000, 20.0, None) == pytest.approx(103_000)  # not measured: + 3%
    assert calibration.group_seconds(peg, 15_000, 20.0, 0.004) == pytest.approx(750 + 2 * 10 * 200 * 0.004)
    # the first seed_steps (random actions, no update) are not timed at the measured rate of updating steps
    seeded = RunSpec(suite="s", env="sawyer_peg", algo="risc", algo_class="risc", seeds=(0,), steps=15_000,
                     config={"seed_steps": 10_000}, eval_every=100_000)
    assert calibration.group_seconds(seeded, 15_000, 20.0, 0.0) == pytest.approx(250)  # 5,000 updating steps
    assert calibration.group_seconds(seeded, 3_000, 20.0, 0.0) == pytest.approx(150)  # resumed at 12,000


@requires_data
def test_a_long_plan_offers_ways_forward(tmp_path, capsys):
    """Over a day on this machine, the dry run says what would shorten it, each with its time from the same speeds."""
    from harness import calibration
    from harness.data import state_dir
    from harness.planning import plan_words

    words = ["algo=naive", "env=tabletop_manipulation", "seeds=5", "steps=10000000", "workers=2",
             f"results={tmp_path}", "calibrate=false"]
    plan = plan_words(words)
    cache = {calibration.key(g, calibration.worker_threads(plan.workers)): {"steps_per_s": 100.0, "eval_s_per_step": 0.0}
             for g in plan.groups}  # evaluations measured as free: the times below are training alone
    (state_dir() / "calibration.json").parent.mkdir(parents=True, exist_ok=True)
    (state_dir() / "calibration.json").write_text(json.dumps(cache))
    assert main(["run", *words, "--dry-run"]) == 0
    out = capsys.readouterr().out
    # 5 one-seed groups of 10M steps, the first 10k without updates (not timed), at 100 steps/s (27h45m each), 3 on
    # one of 2 workers: 83h15m; 16 workers: one group each, 27h45m; 2 seeds of 5: 33h18m
    assert "estimated time: 83h15m" in out and "a Ray cluster of 8 machines like it" in out
    assert "ray_address=auto: about 27h45m" in out and "seeds=2 (about 33h18m)" in out
    words[3] = "steps=100000"  # 1h23m: nothing to add
    assert main(["run", *words, "--dry-run"]) == 0 and "ways forward" not in capsys.readouterr().out


@requires_data
def test_dry_run_time_comes_from_speeds_measured_here(tmp_path, capsys, monkeypatch):
    """--dry-run measures each kind of group once (cached per machine, threads and config) and packs the groups
    onto the workers longest first."""
    from harness import calibration
    from harness.planning import plan_words

    monkeypatch.setenv("HARNESS_CACHE_DIR", str(tmp_path / "cache"))
    args = ["run", "algo=naive,oracle", "env=tabletop_manipulation", "seeds=2", "steps=5000", "workers=2",
            "all.batch_size=16", f"results={tmp_path / 'r'}", "--dry-run"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert out.count("calibrating") == 2 and "steps/s per seed" in out and "estimated time:" in out
    cache = calibration.read_cache()
    assert len(cache) == 2 and all(v > 0 for v in cache.values())
    assert all(c > 0 for c in calibration.eval_costs(plan_words(args[1:-1]).groups, 1))
    assert "(evaluations included, as measured;" in out
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "calibrating" not in out  # cached, and the estimate says when and under what load it was measured
    today = datetime.now(timezone.utc).date().isoformat()
    assert f"from speeds measured on this machine on {today} (load " in out
    assert main([*args, "calibrate=refresh"]) == 0  # measured again, each kind once
    assert capsys.readouterr().out.count("calibrating") == 2 and len(calibration.read_cache()) == 2
    assert not (tmp_path / "r").exists()
    # another update mode is another speed: measured on its own, with the agent switched to it
    from algorithms.core.sac import SAC

    switched = []
    real = SAC.use_static_update
    monkeypatch.setattr(SAC, "use_static_update", lambda self, compile=False: (switched.append(compile),
                                                                                real(self, compile))[1])
    assert main([a.replace("naive,oracle", "naive") for a in args] + ["update=static"]) == 0
    assert capsys.readouterr().out.count("calibrating") == 1 and switched == [False]
    assert len(calibration.read_cache()) == 3
    # longest first onto the least loaded worker: 3 jobs of 100 s, 60 s, 50 s on 2 workers -> 110 s
    assert calibration.estimate([(1000, 10.0), (600, 10.0), (500, 10.0)], 2) == pytest.approx(110.0)
    assert calibration.estimate([(1000, 10.0), (0, 1.0)], 1) == pytest.approx(100.0)


def test_dry_run_counts_only_steps_left_to_run(tmp_path, capsys):
    """A resumed suite's plan and time estimate count what is left: finished runs not at all, unfinished
    ones from their last checkpoint (a multiple of checkpoint_every), not from their last progress line."""
    from harness.results import checkpoint_path, run_dir, write_status

    where = (tmp_path, "adhoc", "sawyer_door", "medal")
    write_status(run_dir(*where, 0), state="done", step=1000)
    write_status(run_dir(*where, 1), state="running", step=650)
    args = ["run", "algo=medal", "env=sawyer_door", "seeds=2", "steps=1000", "eval_every=100",
            "checkpoint_every=200", "members=2", "workers=1", f"results={tmp_path}", "--dry-run", "calibrate=false"]
    assert main(args) == 0
    assert "2,000 env steps in all (1,000 left to run;" in capsys.readouterr().out  # no checkpoint: seed 1 redone
    checkpoint_path(*where, [0, 1]).parent.mkdir(parents=True)
    checkpoint_path(*where, [0, 1]).touch()
    assert main(args) == 0
    assert "2,000 env steps in all (400 left to run;" in capsys.readouterr().out  # 1000 - 600 of seed 1
    # a raised budget: the finished seed goes on from its final checkpoint (1000), seed 1 from 600
    assert main([a.replace("steps=1000", "steps=2000") for a in args]) == 0
    out = capsys.readouterr().out
    assert "4,000 env steps in all (2,400 left to run;" in out and "1,600 of 4,000 steps done" in out


def test_plan_runs_work_in_flight_first(tmp_path, capsys):
    """Groups that resume from a checkpoint run first, then the other groups of begun cells, then the rest, each
    in suite order; the dry run lists them in that order with what each has done."""
    from harness.planning import plan_words
    from harness.results import checkpoint_path, run_dir, write_status

    args = ["run", "algo=naive,oracle,fbrl", "env=sawyer_door", "seeds=2", "steps=1000", "eval_every=100",
            "checkpoint_every=200", "members=1", "workers=1", f"results={tmp_path}"]
    fresh = [(g.algo, g.seeds[0]) for g in plan_words(args[1:]).groups]
    assert fresh == [(a, s) for a in ("naive", "oracle", "fbrl") for s in (0, 1)]  # nothing begun: suite order
    oracle = (tmp_path, "adhoc", "sawyer_door", "oracle")
    write_status(run_dir(*oracle, 1), state="interrupted", step=650)
    checkpoint_path(*oracle, [1]).parent.mkdir(parents=True)
    checkpoint_path(*oracle, [1]).touch()
    write_status(run_dir(tmp_path, "adhoc", "sawyer_door", "fbrl", 0), state="done", step=1000)
    order = [(g.algo, g.seeds[0]) for g in plan_words(args[1:]).groups]
    assert order == [("oracle", 1), ("oracle", 0), ("fbrl", 0), ("fbrl", 1), ("naive", 0), ("naive", 1)]
    assert main([*args, "--dry-run", "calibrate=false"]) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if "config " in x]
    assert [x.split()[1] for x in lines] == [a for a, _ in order]
    assert lines[0].endswith("600 of 1,000 steps done") and lines[2].endswith("done")
    assert not any(x.endswith("done") for x in (lines[1], *lines[3:]))


def test_git_sha_marks_uncommitted_changes(tmp_path):
    from harness.provenance import git_sha

    assert git_sha(tmp_path) == "unknown"  # not a checkout
    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "a.py").write_text("x = 1\n")
    subprocess.run([*git, "add", "a.py"], check=True)
    subprocess.run([*git, "commit", "-qm", "a"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    (tmp_path / "notes.txt").write_text("untracked files do not count\n")
    assert git_sha(tmp_path) == head
    (tmp_path / "perf.md").write_text("rows\n")
    subprocess.run([*git, "add", "perf.md"], check=True)
    subprocess.run([*git, "commit", "-qm", "b"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    (tmp_path / "perf.md").write_text("rows\nand a new one\n")  # a bench recording into a tracked file
    assert git_sha(tmp_path) == head + "-dirty" and git_sha(tmp_path, ignore=tmp_path / "perf.md") == head
    (tmp_path / "a.py").write_text("x = 2\n")
    assert git_sha(tmp_path) == git_sha(tmp_path, ignore=tmp_path / "perf.md") == head + "-dirty"


def test_seed_lists():
    """A count, a comma list, and one explicit seed (``7,`` or ``[7]``: ``seeds=7`` is the count 0..6)."""
    from harness.request import parse_seeds

    assert parse_seeds("3") == [0, 1, 2] and parse_seeds(3) == [0, 1, 2]
    assert parse_seeds("0,3,7") == parse_seeds("[0,3,7]") == parse_seeds([0, 3, 7]) == [0, 3, 7]
    assert parse_seeds("7,") == parse_seeds("[7]") == [7]


def test_bare_harness_shows_the_commands_and_first_steps(capsys):
    assert main([]) == 0 and main(["help"]) == 0
    out = capsys.readouterr().out
    assert out.count("first steps:") == 2 and "harness run suite=smoke" in out and "{list,run," in out


def test_names_and_step_counts_as_people_write_them():
    """What the docs and plans write works as a word: a suite, algorithm or env in any case, a suite as its file name
    (from any folder), an env's gymnasium id, and step counts in the shorthand (300k, 1.5M, 3e5), read exactly in
    decimal; a count that is no integer stays an error."""
    from algorithms.api import parse_int
    from harness.request import RunRequest
    from harness.suites import load_suite

    assert load_suite("Table1")[0] == load_suite("table1.yaml")[0] == load_suite("suites/table1.yaml")[0] == "table1"
    req = RunRequest.from_words(["algo=MEDAL,Oracle", "env=earl/SawyerDoor-v0,Sawyer_Peg", "steps=1.5M",
                                 "eval_every=10k", "checkpoint_every=50_000"])
    assert (req.algos, req.envs) == (("medal", "oracle"), ("sawyer_door", "sawyer_peg"))
    assert (req.steps, req.eval_every, req.checkpoint_every) == (1_500_000, 10_000, 50_000)
    assert [parse_int("n", v) for v in ("500k", "8m", "1.1M", "2.5B", ".5M", "3e5")] == \
        [500_000, 8_000_000, 1_100_000, 2_500_000_000, 500_000, 300_000]
    for bad in ("1.2345k", "M", "1e6k", "1,5M", "3,00", "30,00,000"):
        with pytest.raises(ValueError, match="must be an integer"):
            parse_int("n", bad)


@requires_data
def test_gnu_flags_dashes_short_names_and_seed_forms():
    """What people type from other tools: ``--steps 3000`` / ``--steps=3000`` (any key as a flag), dashes for
    underscores in keys and names, an env by a part of its name alone or its gymnasium id without namespace or version,
    ``steps=3,000`` as plans print it, ``seed=7`` for one seed, seed ranges and spaces; and the Python API takes the
    same env names as the command line."""
    from harness.cli import flag_words
    from harness.envs import get_spec, load_env_demos, make_env
    from harness.request import RunRequest, parse_seeds

    words = flag_words(["run", "--algo", "medal-logc", "--env=door", "--eval-every", "1000", "--dry-run", "--steps",
                        "3,000", "--seed", "7", "x=1", "--data-dir", "/d"])
    assert words == ["--data-dir", "/d", "run", "algo=medal-logc", "env=door", "eval-every=1000", "--dry-run",
                     "steps=3,000", "seed=7", "x=1"]
    req = RunRequest.from_words([w for w in words[3:] if w.count("=") == 1 and not w.startswith(("--", "x="))])
    assert (req.algos, req.envs, req.eval_every, req.steps, req.seeds) == (("medal_logc",), ("sawyer_door",), 1000,
                                                                           3000, (7,))
    for word, name in [("Sawyer-Door", "sawyer_door"), ("SawyerDoor-v0", "sawyer_door"), ("SawyerPeg", "sawyer_peg"),
                       ("tabletop", "tabletop_manipulation"), ("peg", "sawyer_peg"), ("MINITAUR", "minitaur")]:
        assert RunRequest.from_words(["algo=naive", f"env={word}"]).envs == (name,), word
    assert RunRequest.from_words(["algos=RISC-no-TAB", "env=door"]).algos == ("risc_no_tab",)
    assert [parse_seeds(v) for v in ("0-2", "0-1,7", "0 3", "[4]", "2")] == [[0, 1, 2], [0, 1, 7], [0, 3], [4], [0, 1]]
    assert get_spec("Sawyer_Door") is get_spec("earl/SawyerDoor-v0") is get_spec("door")
    assert make_env("SawyerDoor-v0").spec_.name == "sawyer_door"
    assert len(load_env_demos("door").observations) == len(load_env_demos("sawyer_door").observations) > 0
    # flags only after the command (and a bench/data command's own word), never a command or another flag as a value,
    # negative numbers as values, nothing after a bare --
    assert flag_words(["--foo", "list"]) == ["--foo", "list"]
    assert flag_words(["bench", "--x", "train"]) == ["bench", "--x", "train"]
    assert flag_words(["bench", "train", "--members", "2"]) == ["bench", "train", "members=2"]
    assert flag_words(["run", "--medal.target-entropy", "-3", "--", "--x", "y"]) == \
        ["run", "medal.target-entropy=-3", "--", "--x", "y"]
    # an algorithm's override in any case or with dashes, as its name; seed=[7]
    req = RunRequest.from_words(["algo=risc_no_tab,medal", "env=door", "RISC-NO-TAB.lr=0.001", "MEDAL.lr=0.002",
                                 "seed=[7]"])
    assert req.config == {"risc_no_tab": {"lr": "0.001"}, "medal": {"lr": "0.002"}} and req.seeds == (7,)
    # a path word keeps its ~ where no shell expands it (a quoted word, zsh, a notebook): the home directory
    assert RunRequest.from_words(["algo=naive", "env=door", "results=~/r"]).results == str(Path.home() / "r")


@requires_data
def test_an_algorithm_registered_at_run_time_reaches_the_workers_or_runs_in_this_process(monkeypatch):
    """A registration at a script's top level reaches spawned workers (the script runs again there): the plan keeps
    its workers. One made in a notebook, `python -c` or a REPL does not: the plan trains in this process (a packing
    reason says why), and an explicit workers=2, env_workers or Ray is refused with one line. A worker that lacks the
    name says so in one line."""
    import types

    from harness.packing import Machine
    from harness.plan import RunSpec
    from harness.planning import build_plan
    from harness.request import RunRequest
    from harness.runner import run_group
    from harness.words import ConfigError

    class MyNaive(ALGORITHMS["naive"]):
        pass

    monkeypatch.setattr(Machine, "detect", classmethod(lambda cls: Machine(cores=4, memory=16 << 30)))
    monkeypatch.setitem(ALGORITHMS, "my_naive", MyNaive)
    words = ["algo=my_naive", "env=door", "seeds=2", "members=1", "steps=100", "eval_every=100"]
    assert build_plan(RunRequest.from_words(words)).workers == 2  # pytest's __main__ is a script
    monkeypatch.setitem(sys.modules, "__main__", types.ModuleType("__main__"))  # a notebook's: no file
    plan = build_plan(RunRequest.from_words(words))
    assert plan.workers == 1 and {g.env_workers for g in plan.groups} == {0} and {g.algo for g in plan.groups} == {
        "my_naive"}
    assert plan.packing[-1] == ("workers=1, env_workers=0: algorithm 'my_naive' registered at run time in this process "
                                "(a notebook, `python -c` or a REPL), which worker processes would not hold")
    for extra in (["workers=2"], ["env_workers=2"], ["backend=ray"]):
        with pytest.raises(ConfigError, match="algorithm 'my_naive' registered at run time in this"):
            build_plan(RunRequest.from_words(words + extra))
    # a built-in replaced at run time is just as unknown to the workers
    monkeypatch.setitem(ALGORITHMS, "naive", MyNaive)
    with pytest.raises(ConfigError, match="algorithm 'naive' registered at run time"):
        build_plan(RunRequest.from_words(["algo=naive", "env=door", "seeds=2", "steps=100", "workers=2"]))
    # a worker process without the registration (one made under a script's `if __name__ == "__main__":`)
    err = run_group(RunSpec(suite="s", env="sawyer_door", algo="not_here", seeds=(0,), steps=100), "cmd")
    assert err.startswith("sawyer_door/not_here seeds=0: algorithm 'not_here' is not registered in this worker process")


def test_a_budget_within_the_seed_phase_is_named():
    from harness.plan import RunSpec

    g = RunSpec(suite="s", env="sawyer_door", algo="v", algo_class="naive", seeds=(0,), steps=100,
                config={"seed_steps": 100})
    assert g.seed_phase_note() == ("sawyer_door/v: steps=100 is within seed_steps=100 (random actions before the first "
                                   "update): these runs never update their networks; raise steps= or lower "
                                   "naive.seed_steps=")
    assert RunSpec(suite="s", env="sawyer_door", algo="naive", seeds=(0,), steps=101,
                   config={"seed_steps": 100}).seed_phase_note() is None


def test_first_answers_without_argparse_words(capsys):
    """``--version``; a mistyped command named with its closest; ``harness data`` / ``bench`` alone show their help;
    ``harness list envs`` one part (with the gymnasium ids); ``data fetch dest=`` as a word."""
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("harness ")
    with pytest.raises(SystemExit) as e:
        main(["lst"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and err.startswith("harness: error: unknown command 'lst' (did you mean list?); known:")
    for cmd in ("data", "bench"):
        with pytest.raises(SystemExit) as e:
            main([cmd])
        assert e.value.code == 0 and f"usage: harness {cmd}" in capsys.readouterr().out
    assert main(["list", "envs"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("envs:") and "earl/SawyerDoor-v0" in out and "algorithms:" not in out and "suites:" not in out
    assert main(["list", "algos"]) == 0 and "medal_logc" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, needle",
    [
        (["algo=medal", "env=sawyer_door", "seeds=[]"], "seeds is an empty list"),
        (["algo=medal,MEDAL", "env=sawyer_door"], "algo lists medal more than once"),
        (["algo=medal", "env=sawyer_door", "steps=1.25k5"], "steps must be an integer"),
        (["algo=medal", "env=sawyer_door", "seeds=2,2"], "seeds must be distinct"),
        (["algo=medal", "env=sawyer_door", "seeds=[x]"], "seeds must be a count (seeds=3: seeds 0, 1, 2) or a list"),
        (["algo=medal", "env=sawyer_door", "seeds=0"], "for seed 0 alone write seed=0 or seeds=[0]"),
        (["algo=medal", "env=sawyer_door", "--best"], "unknown flag(s) --best (--best is not a flag of `harness run`)"),
        (["algo=medal", "env=sawyer_door", "seed=1", "seeds=2"], "give seed= or seeds=, not both"),
        (["colour=red", "algo=medal", "env=sawyer_door"], "unknown key 'colour'"),
        (["algo=nope", "env=sawyer_door"], "unknown algorithm"),
        (["algo=medl", "env=sawyer_door"], "unknown algorithm(s) ['medl'] (did you mean medal?)"),
        (["algo=medal", "env=nope"], "unknown env 'nope'"),
        (["algo=medal", "env=sawyer_dor"], "unknown env 'sawyer_dor' (did you mean sawyer_door?)"),
        (["algo=medal", "env=sawyer"], "unknown env 'sawyer'"),  # a part of two names: neither
        (["algo=medal", "env=sawyer_door", "stepz=3"], "unknown key 'stepz' (did you mean steps?)"),
        (["algo=naive", "env=sawyer_door", "seed_steps=5"],
         "seed_steps is an algorithm setting: give it as all.seed_steps=5 (every algorithm that has it) or "
         "<algo>.seed_steps=5"),
        (["suite=nope"], "unknown suite 'nope'"),
        (["suite=tabel1"], "unknown suite 'tabel1' (did you mean table1?)"),
        (["algo=medal", "env=sawyer_door", "seeds=-1"], "seeds must be >= 0"),
        (["algo=medal", "env=sawyer_door", "steps=lots"], "steps must be an integer"),
        (["algo=medal", "env=sawyer_door", "medal.nope=3"], "unknown config key"),
        (["algo=medal", "env=sawyer_door", "medal.switch_every=x"], "switch_every must be an integer"),
        (["algo=medal", "env=sawyer_door", "eval_every=300", "checkpoint_every=1000"], "multiple of eval_every"),
        (["algo=medal", "env=sawyer_door", "checkpoint_every=20000", "keep_every=30000"],
         "keep_every (30000) must be a multiple of checkpoint_every (20000)"),
        (["algo=medal", "env=sawyer_door", "keep_every=-1"], "keep_every must be >= 0"),
        (["algo=medal"], "give suite=NAME, or algo=... and env=..."),
        (["algo=medal", "env=sawyer_door", "--dryrun"],
         "unknown flag(s) --dryrun (did you mean --dry-run?) (see `harness run --help`)"),
        (["algo=medal", "env=sawyer_door", "--stepz", "3"], "unknown key 'stepz' (did you mean steps?)"),
        (["suite=reproduction", "algo=medal", "env=sawyer_peg"],
         "no cell of the suite matches algo=medal env=sawyer_peg"),
    ],
)
def test_bad_input_one_line_exit_2(args, needle, tmp_path, capsys):
    assert main(["run", *args, f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("harness: error:") and needle in err, err
    assert not (tmp_path / "r").exists()


def test_malformed_yaml_suite(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("algos: [medal\nenvs: sawyer_door\n")
    assert main(["run", f"suite={bad}", f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "malformed YAML" in err and "bad.yaml" in err
    assert not (tmp_path / "r").exists()


def test_list_shows_registry(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in [*ALGORITHMS, "sawyer_peg", "earl_sparse", "smoke"]:
        assert name in out


def _scalars(run_dir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tensorboard"), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


@requires_data
def test_logger_tensorboard_writes_the_same_rows_once_across_a_resume(tmp_path):
    """Stopped after the evaluation at 300 with its checkpoint at 200, the run resumes at 200 and redoes 300: the
    events of the first 300 are purged, so TensorBoard holds each step once with the values the tables hold."""
    pytest.importorskip("tensorboard")
    from harness.planning import plan_words
    from harness.runner import run_group

    words = ["algo=medal", "env=tabletop_manipulation", "steps=400", "eval_every=100", "checkpoint_every=200",
             "log_every=50", "eval_episodes=1", "medal.seed_steps=50", "medal.batch_size=16", "logger=tensorboard",
             f"results={tmp_path}"]
    (spec,) = plan_words(words).groups
    run = spec.member_dirs()[0]
    evals_at = lambda: sorted(pd.read_parquet(run / "evals.parquet").step.unique())  # noqa: E731
    assert run_group(spec, "test", should_stop=lambda: evals_at()[-1] == 300) is None
    assert evals_at() == [0, 100, 200, 300] and read_status(run)["state"] != "done"
    first = _scalars(run)["eval/deployed_return"]
    assert run_group(spec, "test") is None
    tb = _scalars(run)
    evals, train = pd.read_parquet(run / "evals.parquet"), pd.read_parquet(run / "train.parquet")
    for prefix, table in (("eval", evals), ("train", train)):
        for metric, rows in table.groupby("metric"):
            got = tb[f"{prefix}/{metric}"]
            assert [s for s, _ in got] == rows.step.tolist(), metric  # each step once, in order
            np.testing.assert_allclose([v for _, v in got], rows.value.to_numpy(), rtol=1e-6)
    assert evals_at() == [0, 100, 200, 300, 400] and "train/forward/critic_loss" in tb
    assert [s for s, _ in first] == [0, 100, 200, 300]


def test_logger_must_be_known(capsys):
    assert main(["run", "algo=medal", "env=tabletop_manipulation", "logger=wandb", "--dry-run"]) == 2
    assert "unknown logger 'wandb'; known: parquet, tensorboard" in capsys.readouterr().err


def test_every_command_lists_its_keys_in_its_help(capsys):
    """``report``, ``ship``, each ``bench`` and ``data scripted`` --help print each key they accept, with its default
    (a bench its own keys only)."""
    from harness import command_keys as keys

    for words, table in ((["report"], keys.REPORT), (["ship"], keys.SHIP), (["data", "scripted"], keys.SCRIPTED),
                         *((["bench", what], t) for what, t in keys.BENCH.items())):
        with pytest.raises(SystemExit) as e:
            main([*words, "--help"])
        out = capsys.readouterr().out
        assert e.value.code == 0
        for key, (default, _) in table.items():
            assert re.search(rf"^  {key} +.*\[default: {re.escape(default)}\]$", out, re.M), (words, key)
        if words[0] == "bench":
            others = {k for t in keys.BENCH.values() for k in t} - set(table)
            assert not [k for k in others if re.search(rf"^  {k} ", out, re.M)], words
    with pytest.raises(SystemExit) as e:
        main(["bench", "nope"])
    assert e.value.code == 2 and capsys.readouterr().err.startswith("harness: error: unknown benchmark 'nope'; known: env,")



def test_defaults_follow_the_users_eval_every(tmp_path):
    """A key the user never set cannot reject one they did (issue 58): log_every defaults to the largest divisor of
    eval_every up to 1000, checkpoint_every to the first multiple of eval_every from 50k on; the usual values stay."""
    from harness.planning import plan_words

    def spec(*words):
        return plan_words(["algo=naive", "env=tabletop_manipulation", f"results={tmp_path}", *words]).groups[0]

    s = spec("eval_every=2500", "checkpoint_every=2500")
    assert (s.eval_every, s.checkpoint_every, s.log_every) == (2500, 2500, 625)
    s = spec("eval_every=3000")
    assert (s.checkpoint_every, s.log_every) == (51_000, 1000)
    s = spec("eval_every=7")
    assert (s.checkpoint_every, s.log_every) == (50_001, 7)
    s = spec("eval_every=1009")  # a prime: one diagnostics row per evaluation, not one per step
    assert s.log_every == 1009
    s = spec()
    assert (s.eval_every, s.checkpoint_every, s.log_every) == (10_000, 50_000, 1000)
    with pytest.raises(Exception, match="must divide"):  # a value the user gave is still checked
        spec("eval_every=2500", "log_every=1000")


def test_list_reads_the_registry_without_importing_it():
    """``harness list`` names every registered algorithm with its class's first docstring line, read from the source
    (harness.catalogue), so the answer needs no torch."""
    from harness.catalogue import algorithm_summaries
    from harness.registry import ALGORITHMS

    assert algorithm_summaries() == {n: (c.__doc__ or "").strip().splitlines()[0] for n, c in ALGORITHMS.items()}
    code = ("import sys\nfrom harness.catalogue import algorithm_labels\nprint(repr(algorithm_labels()))\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert eval(out[0]) == {n: c.label for n, c in ALGORITHMS.items()} and out[1] == "False"  # labels from the source


@pytest.mark.parametrize("argv", [["--help"], ["list"], ["run", "--bad-flag"], ["bench", "--help"], ["data", "--help"],
                                  ["run", "algo=nope", "env=sawyer_door"], ["run", "algo=medal", "env=nope"],
                                  ["run", "algo=medal", "env=sawyer_door", "steps=0"], ["run", "suite=nope"],
                                  ["run", "nope.lr=1", "algo=medal", "env=sawyer_door"], ["report", "results=nope"],
                                  ["status", "results=nope"], ["list", "envs"], ["--version"]])
def test_quick_answers_never_load_torch(argv):
    """The first commands a new user types, and the usage errors of a run, answer without importing torch (seconds on a
    loaded machine)."""
    code = ("import contextlib, io, sys\nfrom harness.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
            f"    try:\n        main({argv!r})\n    except SystemExit:\n        pass\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@requires_data
def test_runnable_only_leaves_out_what_cannot_run_and_says_why(tmp_path, capsys, monkeypatch):
    """A suite with runnable_only leaves out the pairs that cannot run (with the reason); without it the first such pair
    is the usual one-line error; a suite where nothing is left is an error too."""
    from harness.planning import plan_words
    from harness.suites import ConfigError

    suite = tmp_path / "mixed.yaml"
    body = "algos: [naive, medal, fbrl_vice]\nenvs: [tabletop_manipulation, kitchen]\nsteps: 400\n"
    suite.write_text(body)
    with pytest.raises(ConfigError, match="algo=medal needs demonstrations and env=kitchen has none"):
        plan_words([f"suite={suite}", f"results={tmp_path / 'r'}"])
    suite.write_text(body + "runnable_only: true\n")
    plan = plan_words([f"suite={suite}", f"results={tmp_path / 'r'}"])
    assert sorted((g.algo, g.env) for g in plan.groups) == [
        ("fbrl_vice", "tabletop_manipulation"), ("medal", "tabletop_manipulation"), ("naive", "kitchen"),
        ("naive", "tabletop_manipulation")]
    assert plan.left_out == ("medal on kitchen: needs demonstrations and env=kitchen has none (EARL ships none for it)",
                             "fbrl_vice on kitchen: learns from 1[success] and env=kitchen's reward is dense (EARL "
                             "trained on it)")
    assert main(["run", f"suite={suite}", f"results={tmp_path / 'r'}", "--dry-run", "calibrate=false"]) == 0
    out = capsys.readouterr().out
    assert "left out (2: they cannot run there):\n  medal on kitchen: needs demonstrations" in out
    assert not (tmp_path / "r").exists()
    with pytest.raises(ConfigError, match=r"nothing to run: every selected algorithm is left out \(medal on kitchen"):
        plan_words([f"suite={suite}", "algo=medal", "env=kitchen", f"results={tmp_path / 'r'}"])
    suite.write_text(body + "runnable_only: yes please\n")
    assert main(["run", f"suite={suite}", f"results={tmp_path / 'r'}", "--dry-run"]) == 2
    assert "runnable_only must be true or false" in capsys.readouterr().err
    # a setting that does not fit an env is an error even so: runnable_only leaves out only what cannot run there
    suite.write_text("algos: [vaprl]\nenvs: [tabletop_manipulation]\nsteps: 400\nrunnable_only: true\n")
    with pytest.raises(ConfigError, match="goal_coords"):
        plan_words([f"suite={suite}", "vaprl.goal_coords=0,1,99", f"results={tmp_path / 'r'}"])
    # an env whose simulator is not installed here is left out too, with its reason
    from harness.envs import ENVS

    monkeypatch.setattr(type(ENVS["minitaur"]), "unavailable",
                        lambda self: "env minitaur needs pybullet, which is not installed" if self.name == "minitaur"
                        else None)
    suite.write_text("algos: [naive]\nenvs: [tabletop_manipulation, minitaur]\nsteps: 400\nrunnable_only: true\n")
    plan = plan_words([f"suite={suite}", f"results={tmp_path / 'r'}"])
    assert [g.env for g in plan.groups] == ["tabletop_manipulation"]
    assert plan.left_out == ("every algorithm on minitaur: env minitaur needs pybullet, which is not installed",)
    monkeypatch.undo()
    # all of EARL: 14 methods on the three Sawyer/tabletop tasks; on kitchen and minitaur the 6 that need no
    # demonstrations and learn from the env's dense reward
    plan = plan_words(["suite=earl_all", f"results={tmp_path / 'r'}"])
    pairs = {(g.algo, g.env) for g in plan.groups}
    assert len(pairs) == 14 * 3 + 2 * len(RETURN_ENV_ALGOS) and len(plan.left_out) == 16
    assert {a for a, e in pairs if e in ("kitchen", "minitaur")} == set(RETURN_ENV_ALGOS)


@requires_data
def test_a_run_further_than_asked_stays_and_a_changed_config_names_its_keys(tmp_path, capsys):
    """Run again with a smaller steps= than a run reached, the run is done and nothing of it is rewritten (its status
    still says how far it got); a changed setting on an existing run is refused naming what changed; a budget within
    seed_steps is told it never updates."""
    words = ["run", "algo=naive", "env=tabletop", "eval_every=100", "eval_episodes=1", "naive.seed_steps=100",
             "naive.batch_size=8", f"results={tmp_path}"]
    assert main([*words, "steps=300"]) == 0
    run = tmp_path / "adhoc" / "tabletop_manipulation" / "naive" / "seed=0"
    before = ((run / "status.json").read_text(), (run / "evals.parquet").read_bytes())
    capsys.readouterr()
    assert main([*words, "steps=200"]) == 0
    assert "done: trained to step 300 already (steps=200); nothing rewritten" in capsys.readouterr().out
    assert ((run / "status.json").read_text(), (run / "evals.parquet").read_bytes()) == before
    assert main([*[w.replace("eval_every=100", "eval_every=150") for w in words], "steps=300", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "holds a run with another config (eval_every 100 -> 150)" in err, err
    assert main([*[w.replace("seed_steps=100", "seed_steps=50") for w in words], "steps=300", "--dry-run"]) == 2
    assert "(naive.seed_steps 100 -> 50)" in capsys.readouterr().err
    assert main([*words[:-1], "steps=100", f"results={tmp_path / 'other'}", "--dry-run", "calibrate=false"]) == 0
    assert "steps=100 is within seed_steps=100" in capsys.readouterr().err


def test_a_suite_of_checks_is_reported_before_any_results_dir_exists(tmp_path, monkeypatch, capsys):
    """`harness report suite=earl_returns` from a folder without results/: its checks, every one "not started"."""
    from harness.report import report_cli
    from harness.words import ConfigError

    monkeypatch.chdir(tmp_path)
    assert report_cli(["suite=earl_returns", f"out={tmp_path / 'out'}"]) == 0
    assert "not started" in (tmp_path / "out" / "reproduction.md").read_text()
    assert "no results directory" not in capsys.readouterr().err  # the note says it, once
    with pytest.raises(ConfigError, match="results directory not found"):
        report_cli(["suite=smoke"])  # no checks to show: the results are needed


def test_a_suite_file_names_envs_as_the_command_line_does(tmp_path, capsys):
    """A suite's envs, its cells' env and a per-env steps mapping read names as `env=` does (any case, a gymnasium id,
    a part of one name): the runs are planned under the registry name, with that env's own algorithm settings and
    config hash, exactly as the same run asked on the command line."""
    from harness.planning import plan_words

    suite = tmp_path / "mixed_names.yaml"
    suite.write_text("algos: [risc]\nenvs: [Kitchen, door]\nsteps: {KITCHEN: 1000, SawyerDoor-v0: 2000}\n")
    g = {x.env: x for x in plan_words([f"suite={suite}", f"results={tmp_path}"]).groups}
    adhoc = {x.env: x for x in plan_words(["algo=risc", "env=kitchen,sawyer_door", "steps=1000",
                                            f"results={tmp_path}"]).groups}
    assert set(g) == {"kitchen", "sawyer_door"} and (g["kitchen"].steps, g["sawyer_door"].steps) == (1000, 2000)
    assert g["kitchen"].config == adhoc["kitchen"].config and g["kitchen"].config["phase_step_limit"] == 400
    cells = tmp_path / "cells_names.yaml"
    cells.write_text("cells:\n  - {algo: risc, env: Kitchen, steps: 1000}\n")
    (c,) = plan_words([f"suite={cells}", f"results={tmp_path}"]).groups
    assert c.env == "kitchen" and c.config == adhoc["kitchen"].config


def test_run_help_lists_the_settings_and_answers_at_once_the_next_time(capsys):
    """`harness run --help` lists every algorithm's settings (which imports every algorithm and torch: seconds); the
    text is kept per source of algorithms/, so the next `--help` prints the same without importing torch."""
    from harness.data import state_dir

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    first = capsys.readouterr().out
    assert "medal.switch_every" not in first and "  medal:" in first and "    disc_mixup" in first
    assert len(list(state_dir().glob("settings_help-*.txt"))) == 1
    code = ("import contextlib, io, sys\nfrom harness.cli import main\nbuf = io.StringIO()\n"
            "with contextlib.redirect_stdout(buf):\n    try:\n        main(['run', '--help'])\n    except SystemExit:\n"
            "        pass\nprint(buf.getvalue() + repr('torch' in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.rstrip().endswith("False") and out[: len(first)] == first
