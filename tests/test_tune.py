"""`harness tune`: the search space, bad input, a journal-file study killed and resumed, two workers
on one PostgreSQL database, and a killed worker's trial failed by the heartbeat and retried."""

import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import yaml

from harness.cli import main
from harness.results import load

from .conftest import requires_data

optuna = pytest.importorskip("optuna", reason="optuna is not installed (pip install -e '.[test]')")
from optuna.trial import TrialState  # noqa: E402

from harness.tune.setup import load_search_space  # noqa: E402

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
TINY = ["algo=medal", "env=tabletop_manipulation", "steps=300", "eval_every=100", "checkpoint_every=100",
        "eval_episodes=1", "all.seed_steps=100", "all.batch_size=32", "pruner=none", "sampler_seed=0"]
FINISHED = (TrialState.COMPLETE, TrialState.PRUNED)


def harness(*args):
    return subprocess.Popen([sys.executable, "-m", "harness.cli", *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def finished(*args, timeout=300):
    p = harness(*args)
    out, _ = p.communicate(timeout=timeout)
    assert p.returncode == 0, out
    return out


def kill_when(path_glob: str, p: subprocess.Popen, timeout=120) -> None:
    deadline = time.time() + timeout
    while not glob.glob(path_glob, recursive=True):
        assert p.poll() is None, p.communicate()[0]
        assert time.time() < deadline, "no checkpoint appeared"
        time.sleep(0.05)
    # a moment later the trial is training again (not holding the journal file's lock: a lock left by a
    # killed writer is only broken after Optuna's 30 s grace period)
    time.sleep(0.3)
    p.send_signal(signal.SIGKILL)
    p.communicate()


def journal_study(path: Path, name: str):
    from optuna.storages import JournalStorage

    try:
        from optuna.storages.journal import JournalFileBackend as backend
    except ImportError:
        from optuna.storages import JournalFileStorage as backend
    return optuna.load_study(study_name=name, storage=JournalStorage(backend(str(path))))


def test_search_space_is_data():
    space = load_search_space("medal")
    assert set(space) == {"disc_lr", "disc_hidden", "disc_batch", "disc_every", "disc_mixup", "reward_form"}
    assert space["disc_lr"] == {"type": "float", "low": 1e-5, "high": 1e-3, "log": True}


def test_a_study_goes_on_only_under_its_own_settings():
    from harness.suites import ConfigError
    from harness.tune.studies import check_protocol

    kept = {"steps": 300, "eval_every": 100, "seeds": [0], "config": {"lr": 0.001, "batch_size": 32},
            "space": {"disc_lr": {"type": "float", "low": 1e-5, "high": 1e-3, "log": True}}}
    check_protocol("s", kept, {**kept, "config": {**kept["config"], "new_key": 1}})  # a key gained: the same
    check_protocol("s", kept, {**kept, "later": 1})  # a setting this study did not keep: not compared
    with pytest.raises(ConfigError, match=r"\(steps 300 -> 200; batch_size 32 -> 64\)"):
        check_protocol("s", kept, {**kept, "steps": 200, "config": {"lr": 0.001, "batch_size": 64}})


@requires_data
def test_seed_words_mean_what_they_mean_in_harness_run(tmp_path):
    """``seed=3`` trains seed 3 (as ``harness run seed=3``); the sampler's seed is ``sampler_seed=``."""
    from harness.tune.setup import parse_setup

    base = ["algo=medal", "env=tabletop_manipulation", "trials=2", f"results={tmp_path / 'r'}"]
    one = parse_setup([*base, "seed=3", "sampler_seed=11"])
    assert one["protocol"]["seeds"] == [3] and one["sampler_seed"] == 11
    assert parse_setup([*base, "seeds=2"])["protocol"]["seeds"] == [0, 1]
    default = parse_setup(base)
    assert default["protocol"]["seeds"] == [0] and default["sampler_seed"] is None


@pytest.mark.parametrize(
    "args, needle",
    [
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "pruner=nope"], "unknown pruner 'nope'"),
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "sampler=nope"], "unknown sampler 'nope'"),
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "backend=nope"], "unknown backend 'nope'"),
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "colour=red"], "unknown key 'colour'"),
        (["algo=medal", "env=tabletop_manipulation"], "give trials=N"),
        (["algo=medal", "env=nope", "trials=2"], "unknown env 'nope'"),
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "medal.nope=1"], "unknown config key"),
        (["algo=medal", "env=tabletop_manipulation", "--best"], "no study 'medal_tabletop_manipulation'"),
        (["algo=medal", "env=tabletop_manipulation", "trials=2", "seed=1", "seeds=2"], "give seed= or seeds=, not both"),
    ],
)
def test_bad_input_one_line_exit_2(args, needle, tmp_path, capsys):
    assert main(["tune", *args, f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("harness: error:") and needle in err, err
    assert not (tmp_path / "r").exists()


@requires_data
def test_journal_study_killed_and_resumed(tmp_path):
    args = ["tune", *TINY, "trials=3", "study=j", f"results={tmp_path}"]
    p = harness(*args)
    # SIGKILL in the middle of the second trial, after its first checkpoint
    kill_when(str(tmp_path / "tuning" / "j" / "trial=1" / "**" / "checkpoint.pt"), p)
    journal = tmp_path / "tuning" / "j.journal"
    assert journal.exists()
    before = journal_study(journal, "j")
    assert [t.state for t in before.trials] == [TrialState.COMPLETE, TrialState.RUNNING]

    out = finished(*args)
    study = journal_study(journal, "j")
    states = [t.state for t in study.trials]
    assert sum(s in FINISHED for s in states) == 3 and len(states) >= 4, (states, out)
    assert study.trials[1].state == TrialState.FAIL  # the killed trial: its process is gone
    retry = [t for t in study.trials if t.system_attrs.get("failed_trial") == 1]
    assert len(retry) == 1 and retry[0].state == TrialState.COMPLETE and retry[0].params == study.trials[1].params

    df = load(tmp_path / "tuning" / "j")
    assert (df.suite == "tune_j").all() and (df.study == "j").all()
    assert sorted(df.trial.unique()) == [0, 1, 3]  # the retry resumed in trial 1's directory
    d = df[df.metric == "deployed_success"]
    for n in (0, 1, 3):
        assert sorted(d[d.trial == n].step) == [0, 100, 200, 300], n  # no row lost or duplicated by the kill

    # the study goes on only under the settings its trials were scored with; a change is named, nothing is run
    changed = [a for a in TINY if not a.startswith("steps=")] + ["steps=200", "trials=4", "study=j", f"results={tmp_path}"]
    p = harness("tune", *changed)
    out, _ = p.communicate(timeout=120)
    assert p.returncode == 2 and out.strip().count("\n") == 0 and "(steps 300 -> 200)" in out, out
    assert len(journal_study(journal, "j").trials) == len(study.trials)

    best = finished("tune", "algo=medal", "env=tabletop_manipulation", "study=j", f"results={tmp_path}", "--best")
    cfg = yaml.safe_load(best)["config"]
    assert set(cfg["medal"]) == set(load_search_space("medal")) and cfg["all"] == {"seed_steps": 100, "batch_size": 32}
    assert "harness run algo=medal env=tabletop_manipulation" in best and "medal.disc_lr=" in best


# ------------------------------------------------------------------------------------ PostgreSQL


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def postgres():
    """A private PostgreSQL cluster on 127.0.0.1 (initdb/pg_ctl as a non-root user) for this module."""
    pytest.importorskip("psycopg2", reason="psycopg2 is not installed (pip install psycopg2-binary)")
    bins = [shutil.which("initdb"), shutil.which("pg_ctl")]
    if not all(bins):
        found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
        bins = [found[-1], str(Path(found[-1]).parent / "pg_ctl")] if found else bins
    if not all(bins):
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not found: apt-get install -y postgresql")
    initdb, pg_ctl = bins
    prefix: list[str] = []
    root = tempfile.mkdtemp(prefix="harness-pg-")
    if os.geteuid() == 0:  # the server refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run the server as")
        os.chown(root, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    data, port = os.path.join(root, "data"), _free_port()
    env = {**os.environ, "LC_ALL": "C"}
    subprocess.run([*prefix, initdb, "-D", data, "-U", "postgres", "--auth=trust", "-E", "UTF8"], check=True,
                   capture_output=True, env=env, cwd=root)
    subprocess.run([*prefix, pg_ctl, "-D", data, "-l", os.path.join(root, "log"), "-w", "-t", "60",
                    "-o", f"-p {port} -h 127.0.0.1 -k {root} -c fsync=off", "start"], check=True,
                   capture_output=True, env=env, cwd=root)
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", data, "-m", "immediate", "stop"], capture_output=True, env=env, cwd=root)
        shutil.rmtree(root, ignore_errors=True)


def rdb_study(url: str, name: str):
    from harness.tune.studies import pg_driver as _pg_driver

    return optuna.load_study(study_name=name, storage=_pg_driver(url))


@requires_data
def test_two_workers_one_postgres_database(postgres, tmp_path):
    out = finished("tune", *[a for a in TINY if a != "steps=300"], "steps=200", "trials=4", "workers=2", "study=pg2", f"storage={postgres}", f"results={tmp_path}")
    study = rdb_study(postgres, "pg2")
    done = [t for t in study.trials if t.state in FINISHED]
    assert len(done) >= 4, (out, [t.state for t in study.trials])
    numbers = [t.number for t in study.trials]
    assert len(numbers) == len(set(numbers))
    assert len({t.user_attrs["worker"] for t in done}) == 2  # both workers ran trials
    # each trial number ran exactly once, with its own parameters, in its own directory
    for t in done:
        runs = list((tmp_path / "tuning" / "pg2" / f"trial={t.number}").rglob("run.yaml"))
        assert len(runs) == 1, t.number
        cfg = yaml.safe_load(runs[0].read_text())["config"]
        assert {k: cfg[k] for k in t.params} == t.params, t.number
    assert len({tuple(sorted(t.params.items())) for t in done}) == len(done)
    df = load(tmp_path / "tuning" / "pg2")
    assert sorted(df.trial.unique()) == sorted(t.number for t in done) and (df.study == "pg2").all()


@requires_data
def test_killed_worker_trial_fails_by_heartbeat_and_is_retried(postgres, tmp_path):
    args = ["tune", *TINY, "trials=2", "study=hb", f"storage={postgres}", f"results={tmp_path}",
            "heartbeat_interval=1", "grace_period=2"]
    p = harness(*args)
    kill_when(str(tmp_path / "tuning" / "hb" / "trial=0" / "**" / "checkpoint.pt"), p)
    assert rdb_study(postgres, "hb").trials[0].state == TrialState.RUNNING
    time.sleep(3)  # past the grace period: the dead worker's heartbeat is stale
    out = finished(*args)
    study = rdb_study(postgres, "hb")
    assert study.trials[0].state == TrialState.FAIL, out
    retry = [t for t in study.trials if t.system_attrs.get("failed_trial") == 0]
    assert len(retry) == 1 and retry[0].state == TrialState.COMPLETE and retry[0].params == study.trials[0].params
    assert sum(t.state in FINISHED for t in study.trials) == 2
    d = load(tmp_path / "tuning" / "hb")
    d = d[(d.metric == "deployed_success") & (d.trial == 0)]
    assert sorted(d.step) == [0, 100, 200, 300]  # resumed from the dead trial's checkpoint, nothing twice


def test_interrupted_retries_are_queued_once_down_a_chain_and_without_the_old_marks():
    """Trial 0 interrupted -> one retry (1); that retry interrupted too -> one retry of it (2); calling again queues
    nothing, and a queued retry carries neither the dead worker's pid nor the interrupted mark."""
    import optuna
    from optuna.trial import TrialState

    from harness.tune.studies import retried_numbers, retry_interrupted_trials

    study = optuna.create_study(direction="maximize")

    def run_and_interrupt() -> int:
        trial = study.ask({"x": optuna.distributions.FloatDistribution(0, 1)})
        assert "worker" not in trial.user_attrs and "interrupted" not in trial.user_attrs
        trial.set_user_attr("worker", "host:1")
        trial.set_user_attr("interrupted", True)
        study.tell(trial, state=TrialState.FAIL)
        return trial.number

    assert run_and_interrupt() == 0
    assert retry_interrupted_trials(study) == [0] and retry_interrupted_trials(study) == []
    assert run_and_interrupt() == 1  # the queued retry of 0, interrupted in its turn
    assert retry_interrupted_trials(study) == [1] and retry_interrupted_trials(study) == []
    trials = study.get_trials(deepcopy=False)
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.FAIL, TrialState.WAITING]
    assert trials[2].params == trials[0].params and retried_numbers(trials) == {0, 1}
