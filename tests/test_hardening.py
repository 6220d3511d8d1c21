"""What a user can do wrong, and what the machine can do to a run: malformed command lines and suite files (a
property-based fuzz test), Ctrl-C with several workers, two processes on one run, broken result stores, an explicit
data directory, and --help.

Every bad input must give exit code 2, exactly one line on stderr, no traceback, and nothing written."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from harness.cli import main
from harness.registry import ALGORITHMS
from harness.results import load, read_status

from .conftest import requires_data

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
TINY = ["all.seed_steps=100", "all.batch_size=16", "eval_episodes=1"]
FUZZ = {"tried": 0}


def one_error_line(capsys, argv: list[str], results: Path) -> str:
    """Run the CLI in-process with ``argv``; assert the bad-input contract and return the error line."""
    rc = main(argv)
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (argv, out, err)
    assert len(lines) == 1 and lines[0].startswith("harness: error: "), (argv, err)
    assert "Traceback" not in out + err
    assert not results.exists() or not any(results.rglob("*")), (argv, sorted(results.rglob("*")))
    FUZZ["tried"] += 1
    return lines[0]


# -- fuzzing: values that break a declared rule of some algorithm setting ------------------------------------------
def _bad_values(cls, key: str, default) -> list[str]:
    from algorithms.api import declaration

    d = declaration(cls, key)
    if isinstance(default, bool):
        return ["maybe", "2", "", "tru"]
    if isinstance(default, int):
        out = ["x", "1.5", "", "1e400", "9" * 40]
        out += [str(d["ge"] - 1)] if d.get("ge") is not None else []
        out += [str(int(d["le"]) + 1)] if d.get("le") is not None else []
        return out
    if isinstance(default, float):
        out = ["nan", "abc", "", "1e400" if not math.isinf(default) else "nan"]
        out += [str(d["ge"] - 1.0)] if d.get("ge") is not None else []
        out += [str(d["gt"])] if d.get("gt") is not None else []
        out += [str(d["le"] * 2 + 1)] if d.get("le") is not None else []
        out += [str(d["lt"])] if d.get("lt") is not None else []
        return out
    if isinstance(default, str):
        return ["banana", "", default.upper() + "_"] if d.get("choices") else []
    return []


BAD_SETTINGS = sorted({(name, key, v) for name, cls in ALGORITHMS.items() for key, default, _ in cls.Config.describe()
                       for v in _bad_values(cls.Config, key, default)})
BAD_RUN_WORDS = [
    ["steps=0"], ["steps=-5"], ["steps=1e20"], ["steps=" + "9" * 32], ["steps=abc"], ["steps=1.5"],
    ["seeds=0"], ["seeds=100000000"], ["seeds=1,1"], ["seeds=a,b"], ["seeds=1,99999999999"],
    ["seeds=[]"], ["seeds=,"], ["seeds=[1,1]"], ["seeds=3,,"],
    ["members=0"], ["members=5000"], ["eval_every=0"], ["eval_episodes=0"], ["eval_episodes=1e9"],
    ["checkpoint_every=300", "eval_every=200"], ["workers=0"], ["workers=1e6"], ["device=tpu9"],
    ["backend=mpi"], ["ray_address=auto"], ["colour=red"], ["steps=100", "steps=200"], ["naive.lr=0.1"],
    ["nope.lr=1"], ["all.nope=1"], ["justaword"], ["=5"], ["algo=medal,medal"], ["env=sawyer_door,sawyer_door"],
    ["env=kitchen"], ["suite=../../etc/evil"], ["suite=/nonexistent/suite.yaml"], ["algo=naive", "algos=medal"],
]


@requires_data
@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(case=st.sampled_from(BAD_SETTINGS), extra=st.sampled_from([[], ["seeds=2"], ["members=2", "seeds=2"]]))
def test_fuzz_bad_algorithm_settings(capsys, tmp_path_factory, case, extra):
    algo, key, value = case
    res = tmp_path_factory.mktemp("r") / "results"
    line = one_error_line(capsys, ["run", f"algo={algo}", "env=sawyer_door", f"{algo}.{key}={value}", *extra,
                                   f"results={res}", "--dry-run"], res)
    assert key in line


@requires_data
@settings(max_examples=120, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(words=st.sampled_from(BAD_RUN_WORDS), flag_first=st.booleans())
def test_fuzz_bad_run_words(capsys, tmp_path_factory, words, flag_first):
    res = tmp_path_factory.mktemp("r") / "results"
    base = ["algo=medal", "env=sawyer_door"] if not any(w.startswith(("algo", "env", "suite")) for w in words) \
        else (["env=sawyer_door"] if any(w.startswith("algo") for w in words) else
              ["algo=medal"] if any(w.startswith("env") for w in words) else [])
    argv = ["run", "--dry-run", *base, *words, f"results={res}"] if flag_first else \
        ["run", *base, *words, f"results={res}", "--dry-run"]
    one_error_line(capsys, argv, res)


@st.composite
def valid_schedules(draw):
    """Protocol words inside every declared bound (harness.request.RUN_KEYS) and every rule between them:
    checkpoint_every a multiple of eval_every, keep_every of checkpoint_every, log_every a divisor of eval_every."""
    from harness.request import RUN_KEYS

    eval_every = draw(st.integers(1, 2_000_000))
    divisors = [d for d in range(1, min(eval_every, 5000) + 1) if eval_every % d == 0]
    ckpt = eval_every * draw(st.integers(1, max(1, RUN_KEYS["checkpoint_every"].hi // eval_every // 1000)))
    words = {"eval_every": eval_every, "steps": draw(st.integers(1, RUN_KEYS["steps"].hi)),
             "eval_episodes": draw(st.integers(1, RUN_KEYS["eval_episodes"].hi))}
    if draw(st.booleans()):
        words["checkpoint_every"] = ckpt
        if draw(st.booleans()):
            words["keep_every"] = ckpt * draw(st.integers(0, 100))
    if draw(st.booleans()):
        words["log_every"] = draw(st.sampled_from(divisors))
    seeds = draw(st.integers(1, 64))
    words["seeds"] = seeds
    if draw(st.booleans()):
        words["members"] = draw(st.integers(1, seeds))
    style = draw(st.sampled_from(["plain", "underscores", "exponent"]))
    def spell(v: int) -> str:  # noqa: E306 - the spellings the parser accepts for one integer
        if style == "underscores":
            return f"{v:_}"
        if style == "exponent" and v % 1000 == 0 and v:
            return f"{v // 1000}e3"
        return str(v)
    return [f"{k}={spell(v) if k != 'seeds' else v}" for k, v in words.items()]


@requires_data
@settings(max_examples=80, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(words=valid_schedules(), algo=st.sampled_from(sorted(ALGORITHMS)))
def test_no_valid_schedule_is_refused(tmp_path_factory, words, algo):
    """Generated commands inside the declared bounds always plan, and the plan holds what they asked for."""
    from harness.planning import plan_words

    res = tmp_path_factory.mktemp("r") / "results"
    plan = plan_words([f"algo={algo}", "env=tabletop_manipulation", *words, f"results={res}"])
    asked = dict(w.split("=", 1) for w in words)
    g = plan.groups[0]
    assert g.eval_every == int(float(asked["eval_every"].replace("_", "")))
    assert sum(len(x.seeds) for x in plan.groups) == int(asked["seeds"])
    assert g.checkpoint_every % g.eval_every == 0 and g.eval_every % g.log_every == 0
    assert not res.exists() or not any(res.rglob("*"))  # planning writes nothing


@st.composite
def run_words(draw):
    """A ``harness run`` command drawn from the declared key table (harness.request.RUN_KEYS), not a fixed list: a
    few keys, each with a value inside its bounds (three times in five), at or past a bound, or arbitrary text; an
    algorithm and env are added where the drawn keys name neither (nor a suite)."""
    from harness.request import RUN_KEYS

    names = sorted(set(RUN_KEYS) - {"results", "calibrate", "ray_address", "backend"})
    words = {}
    for key in draw(st.lists(st.sampled_from(names), min_size=1, max_size=5, unique=True)):
        k = RUN_KEYS[key]
        kind = draw(st.sampled_from(["valid", "valid", "valid", "bound", "text"]))
        if kind == "text":
            value = draw(st.text(alphabet="abc019_,.-[]e ", max_size=8))
        elif k.lo is not None:
            value = str(draw(st.integers(k.lo, min(k.hi, 10**5))) if kind == "valid" else
                        draw(st.sampled_from([k.lo - 1, k.hi + 1])))
        elif key in ("algo", "algos"):
            value = draw(st.sampled_from(sorted(ALGORITHMS)))
        elif key in ("env", "envs"):
            value = draw(st.sampled_from(["tabletop_manipulation", "sawyer_door", "sawyer_peg", "kitchen"]))
        elif key == "suite":
            value = draw(st.sampled_from(["smoke", "reproduction", "table1", "vaprl_ablation"]))
        else:
            value = str(k.default) if kind == "valid" else draw(st.sampled_from(["", "x", "-1"]))
        words[key] = value
    if not {"suite", "algo", "algos"} & set(words):
        words["algo"] = draw(st.sampled_from(sorted(ALGORITHMS)))
    if not {"suite", "env", "envs"} & set(words):
        words["env"] = "tabletop_manipulation"
    return [f"{k}={v}" for k, v in words.items()]


GENERATED = {0: 0, 2: 0}


@requires_data
@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(words=run_words())
def test_generated_commands_plan_or_say_one_line(capsys, tmp_path_factory, words):
    """Every generated command either plans (exit 0) or gets one error line and exit 2, and on 2 nothing is written."""
    res = tmp_path_factory.mktemp("r") / "results"
    argv = ["run", *words, f"results={res}", "calibrate=false", "--dry-run"]
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc in (0, 2) and "Traceback" not in out + err, (argv, rc, err)
    if rc == 2:
        assert len([ln for ln in err.splitlines() if ln.strip()]) == 1 and err.startswith("harness: error: "), err
    assert not res.exists() or not any(res.rglob("*")), argv  # a dry run writes nothing either way
    GENERATED[rc] += 1


BAD_SUITES = [
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: {medal: 5}\n",
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: {medal: [1, 2]}\n",
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: 7\n",
    "algos: [medal]\nenvs: [sawyer_door]\nsteps: 10\nsteps: 20\n",
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: {medal: {lr: 1, lr: 2}}\n",
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: {medal: {lr: banana}}\n",
    "algos: [medal]\nenvs: [sawyer_door]\nconfig: {medal: {reward_form: 3}}\n",
    "algos: [medal]\nenvs: [sawyer_door]\ncolour: red\n",
    "algos: [medal\n",
    "- a\n- b\n",
    "",
    "algos: [medal]\nenvs: [sawyer_door]\nseeds: -1\n",
    "algos: [medal, medal]\nenvs: [sawyer_door]\n",
    "algos: [medal]\nenvs: [sawyer_door]\nsteps: {tabletop_manipulation: 10}\n",
    "cells: 5\n",
    "cells: [{algo: medal, env: sawyer_door}]\n",
    "cells: [{algo: medal, env: sawyer_door, steps: 10, seeds: 0}]\n",
    "algos: [medal]\ncells: [{algo: medal, env: sawyer_door, steps: 10}]\n",
    "\x00\x01binary",
]


@requires_data
@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(text=st.sampled_from(BAD_SUITES), name=st.sampled_from(["bad", "bad_suite-2"]))
def test_fuzz_bad_suite_files(capsys, tmp_path_factory, text, name):
    d = tmp_path_factory.mktemp("s")
    (d / f"{name}.yaml").write_text(text)
    res = d / "results"
    one_error_line(capsys, ["run", f"suite={d / f'{name}.yaml'}", f"results={res}", "--dry-run"], res)


def test_zz_fuzz_count():
    """How many malformed inputs the fuzz tests above tried (all gave a clean error), for the closing note."""
    print(f"\nfuzz: {FUZZ['tried']} malformed inputs, each exit 2 with one line and nothing written")
    assert FUZZ["tried"] == 0 or FUZZ["tried"] >= 100


# -- two processes, one run ------------------------------------------------------------------------------------
def _start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "harness.cli", *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _wait_for(pred, timeout: float = 300.0) -> None:
    t = time.time()
    while not pred():
        assert time.time() - t < timeout, "timed out"
        time.sleep(0.2)


def _state(path: Path) -> str | None:
    return (read_status(path) or {}).get("state")


@requires_data
def test_second_process_on_a_running_group_exits_2_naming_the_first(tmp_path):
    run = ["run", "algo=naive", "env=tabletop_manipulation", "steps=100000", "eval_every=200",
           "checkpoint_every=200", *TINY, f"results={tmp_path}"]
    first = _start(run)
    d = tmp_path / "adhoc" / "tabletop_manipulation" / "naive" / "seed=0"
    try:
        _wait_for(lambda: _state(d) in ("running", "resumed"))
        second = subprocess.run([sys.executable, "-m", "harness.cli", *run], env=ENV, capture_output=True,
                                text=True, timeout=300)
        assert second.returncode == 2, second.stdout + second.stderr
        err = [ln for ln in second.stderr.splitlines() if ln.strip()]
        assert len(err) == 1 and f"being trained by process {first.pid}" in err[0], second.stderr
        assert "Traceback" not in second.stdout + second.stderr
        # in a suite of two groups the held one is skipped and the other runs
        both = subprocess.run([sys.executable, "-m", "harness.cli", "run", "algo=naive,oracle",
                               "env=tabletop_manipulation", "steps=200", "eval_every=200", *TINY,
                               f"results={tmp_path}", "workers=1"], env=ENV, capture_output=True, text=True,
                              timeout=600)
        assert "harness: skipping" in both.stderr and f"process {first.pid}" in both.stderr
        assert _state(tmp_path / "adhoc" / "tabletop_manipulation" / "oracle" / "seed=0") == "done"
    finally:
        first.kill()
        first.wait()
    # kill -9 leaves no stale lock: the next process takes the run over
    again = _start(["steps=400" if w.startswith("steps=") else w for w in run])
    assert again.wait(timeout=600) == 0, again.stdout.read()


# -- Ctrl-C ----------------------------------------------------------------------------------------------------
@requires_data
def test_sigint_with_two_workers_stops_marks_interrupted_and_resumes_to_the_same_rows(tmp_path):
    words = ["algo=naive", "env=tabletop_manipulation", "seeds=2", "workers=2", "steps=1200", "eval_every=200",
             "checkpoint_every=200", *TINY]
    p = _start(["run", *words, f"results={tmp_path / 'a'}"])
    dirs = [tmp_path / "a" / "adhoc" / "tabletop_manipulation" / "naive" / f"seed={s}" for s in (0, 1)]
    _wait_for(lambda: all((read_status(d) or {}).get("step", 0) >= 400 for d in dirs))
    assert p.poll() is None, "the run finished before it could be interrupted"
    t = time.time()
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 130, out
    assert time.time() - t < 30
    assert "Traceback" not in out and "Error" not in out.replace("harness: interrupted", "")
    assert "run the same command again to resume" in out
    assert {_state(d) for d in dirs} == {"interrupted"}
    again = subprocess.run([sys.executable, "-m", "harness.cli", "run", *words, f"results={tmp_path / 'a'}"],
                           env=ENV, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "resuming from the checkpoint at step" in again.stdout
    ref = subprocess.run([sys.executable, "-m", "harness.cli", "run", *words, f"results={tmp_path / 'b'}"],
                         env=ENV, capture_output=True, text=True, timeout=900)
    assert ref.returncode == 0, ref.stdout + ref.stderr
    deterministic = ["deployed_success", "deployed_return", "continuing_reward", "interventions"]

    def rows(root):
        df = load(root)
        return df[df.metric.isin(deterministic)].sort_values(["seed", "step", "metric"])[
            ["seed", "step", "metric", "value"]].reset_index(drop=True)

    a, b = rows(tmp_path / "a"), rows(tmp_path / "b")
    assert len(a) == 2 * 7 * 4  # steps 0..1200 every 200, 4 metrics, 2 seeds: nothing lost or duplicated
    assert a.equals(b)


# -- broken result stores ------------------------------------------------------------------------------------------
@requires_data
def test_corrupt_checkpoint_stale_temp_files_and_strict_status_json(tmp_path, capsys):
    words = ["run", "algo=naive", "env=tabletop_manipulation", "steps=400", "eval_every=200", "checkpoint_every=200",
             *TINY, f"results={tmp_path}", "workers=1"]
    assert main(["steps=200" if w.startswith("steps=") else w for w in words]) == 0
    d = tmp_path / "adhoc" / "tabletop_manipulation" / "naive" / "seed=0"
    ckpt = next((tmp_path / "adhoc" / "tabletop_manipulation" / "naive" / "checkpoints").rglob("checkpoint.pt"))
    stale = [ckpt.parent / ".ckpt.abc123.tmp", d / ".evals.parquet.xyz.tmp"]
    for s in stale:
        s.write_bytes(b"")
    good = ckpt.read_bytes()
    ckpt.write_bytes(good[: len(good) // 3])  # truncated by a full disk, say
    capsys.readouterr()
    assert main(words) == 1
    err = capsys.readouterr().err
    assert f"checkpoint {ckpt} is unreadable" in err and "delete it to restart" in err and "Traceback" not in err
    assert not any(s.exists() for s in stale)  # removed when the run started
    status = (d / "status.json").read_text()
    assert json.loads(status, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))["state"] == "failed"
    ckpt.write_bytes(good)
    assert main(words) == 0 and _state(d) == "done"
    rec = yaml.safe_load((d / "run.yaml").read_text())
    assert rec["demos_sha256"] and Path(rec["data_dir"]).is_dir()


@requires_data
def test_a_checkpoint_resumes_only_on_the_kind_of_device_that_wrote_it(tmp_path, capsys):
    """Random streams are per device kind (CPU mt19937, CUDA Philox): a CUDA checkpoint met on the CPU is one line."""
    words = ["run", "algo=naive", "env=tabletop_manipulation", "steps=400", "eval_every=200", "checkpoint_every=200",
             *TINY, f"results={tmp_path}", "workers=1"]
    assert main(["steps=200" if w.startswith("steps=") else w for w in words]) == 0
    ckpt = next(tmp_path.rglob("checkpoint.pt"))
    ck = torch.load(ckpt, weights_only=False)
    assert ck["device"] == "cpu"
    torch.save({**ck, "device": "cuda:1"}, ckpt)  # as a GPU run writes it
    capsys.readouterr()
    assert main(words) == 1
    err = capsys.readouterr().err
    assert "was written on cuda" in err and "resume it with device=cuda" in err and "Traceback" not in err


@requires_data
@pytest.mark.parametrize("content, says", [("- a\n", "a YAML list, not a run record"), ("", "is empty"),
                                            ("a: [\n", "malformed YAML in")])
def test_broken_run_yaml_is_one_line_naming_the_file(tmp_path, capsys, content, says):
    words = ["run", "algo=naive", "env=tabletop_manipulation", "steps=200", "eval_every=200", *TINY,
             f"results={tmp_path}", "workers=1"]
    assert main(words) == 0
    f = tmp_path / "adhoc" / "tabletop_manipulation" / "naive" / "seed=0" / "run.yaml"
    f.write_text(content)
    capsys.readouterr()
    assert main(words + ["--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(f) in err[0] and says in err[0] and "delete it" in err[0]


@requires_data
def test_a_run_resumes_in_the_update_mode_it_ran_with_unless_told_otherwise(tmp_path, capsys):
    """Without ``update=``, a run goes on in the mode it last ran with (the same command resumes it bitwise); an
    explicit other mode goes on within rounding, not bitwise, and one note names both modes. A finished run does
    not train again, so it gets no note."""
    from harness.planning import plan_words

    words = ["run", "algo=naive", "env=tabletop_manipulation", "steps=200", "eval_every=200", *TINY,
             f"results={tmp_path}", "workers=1", "update=static"]
    assert main(words) == 0
    capsys.readouterr()
    longer = [w.replace("steps=200", "steps=400") for w in words if w != "update=static"]
    assert [g.update for g in plan_words(longer[1:]).groups] == ["static"]
    assert plan_words([w for w in longer[1:] if w != f"results={tmp_path}"] + [f"results={tmp_path}/new"]
                      ).groups[0].update == "default"
    for finished_or_not in (words, [w for w in words if w != "update=static"] + ["update=default"], longer):
        assert main(finished_or_not + ["--dry-run", "calibrate=false"]) == 0
        assert "update=" not in capsys.readouterr().err
    assert main(longer + ["update=default", "--dry-run", "calibrate=false"]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "update=" in line]
    assert len(notes) == 1 and "last ran with update=static, now update=default" in notes[0]
    assert main(longer + ["--dry-run", "calibrate=false"]) == 0
    assert "update=static" in capsys.readouterr().out  # the plan shows the mode it inherited
    # without its checkpoint the run starts from 0: in the default mode, with nothing to note
    plan_words(longer[1:]).groups[0].checkpoint_path().unlink()
    assert [g.update for g in plan_words(longer[1:]).groups] == ["default"]
    assert main(longer + ["update=default", "--dry-run", "calibrate=false"]) == 0
    assert "update=" not in capsys.readouterr().err


def test_unwritable_results_directory_is_an_input_error(tmp_path, capsys, monkeypatch):
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(tmp_path) else real(p, mode))
    res = tmp_path / "results"
    line = one_error_line(capsys, ["run", "algo=naive", "env=sawyer_door", f"results={res}"], res)
    assert f"results directory {tmp_path} is not writable" in line


# -- the data directory ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["missing", "empty"])
def test_explicit_data_dir_is_honoured(tmp_path, capsys, kind):
    d = tmp_path / "data"
    if kind == "empty":
        d.mkdir()
    res = tmp_path / "results"
    line = one_error_line(capsys, ["--data-dir", str(d), "run", "algo=naive", "env=sawyer_door", f"results={res}"],
                          res)
    assert str(d) in line and ("does not exist" if kind == "missing" else "has no 'demos/sawyer_door/forward.npz'") in line


# -- help -------------------------------------------------------------------------------------------------------------
def test_help_lists_every_key_with_default(capsys):
    from harness.request import RUN_KEYS
    from harness.tune.setup import TUNE_KEY_HELP

    for cmd, keys in (("run", RUN_KEYS), ("tune", TUNE_KEY_HELP)):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        out = capsys.readouterr().out
        for k in keys:
            assert f"\n  {k} " in out
        assert "[default: 10000]" in out and "medal:" in out and "disc_lr" in out and "reward_form" in out


@requires_data
@pytest.mark.parametrize("argv", [
    ["run", "algo=vaprl", "env=tabletop_manipulation", "vaprl.goal_coords=0,1,99", "--dry-run"],  # checked at plan time
    ["run", "algo=naive", "env=tabletop_manipulation", "results=", "--dry-run"],
    ["run", "algo=naive", "env=tabletop_manipulation", "suite=", "--dry-run"],
    ["report", "results=", "out=x"],
    ["report", "out="],
])
def test_late_or_empty_values_are_one_line_before_anything_is_written(capsys, tmp_path, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)  # an empty results= or out= must not write into the current directory
    res = tmp_path / "results"
    one_error_line(capsys, [*argv] if "results=" in argv else [*argv, f"results={res}"], res)
    assert not list(tmp_path.iterdir())


@requires_data
def test_report_step_past_every_run_is_one_line(capsys, tmp_path):
    from tests.fixtures_results import write_fixture

    root = write_fixture(tmp_path / "results", failed=False)
    assert main(["report", f"results={root}", "step=99999999", f"out={tmp_path / 'out'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "past every run" in err and not (tmp_path / "out").exists()
