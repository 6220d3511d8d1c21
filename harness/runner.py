"""``harness run``: execute a plan (:mod:`harness.planning`), one group at a time or through a backend
(:mod:`harness.backends`): print the plan and its time estimate, write each run's record, train, report progress.

Re-running the same command resumes every unfinished run from its checkpoint and skips finished ones.
"""

from __future__ import annotations

import math
import os
import shlex
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from harness.backends import keep_freed_memory
from harness.envs import load_env_demos
from harness.plan import Plan, RunSpec
from harness.planning import finished, plan_words, steps_done
from harness.provenance import run_record
from harness.run_status import format_duration


def run_group(spec: RunSpec, command: str, queue=None, threads: int | None = None, should_stop=None) -> str | None:
    """Run one group to completion (resuming if a checkpoint exists). Returns an error line or None.

    Holds the run directories' locks while it trains: raises :class:`~harness.interrupts.RunLocked` if another
    process holds one, and :class:`~harness.interrupts.RunInterrupted` after SIGINT/SIGTERM stopped it (statuses
    ``interrupted``; the last checkpoint is the resume point). ``should_stop`` (no arguments, called after every
    evaluation) ends the run early (tuning's pruner)."""
    import torch  # here: planning and its one-line errors come before torch loads

    from harness import interrupts
    from harness.envs import ENVS
    from harness.interrupts import RunInterrupted, RunLocked, in_group, remove_stale_temp, run_locks
    from harness.registry import ALGORITHMS
    from harness.results import update_status

    for kind, name, known in (("algorithm", spec.algo_class, ALGORITHMS), ("env", spec.env, ENVS)):
        if name not in known:  # registered at run time where this (spawned) process did not run the registration
            return (f"{spec.label}: {kind} {name!r} is not registered in this worker process: a registration made at "
                    "run time reaches spawned workers only from the top level of the script (not under `if __name__ "
                    "== '__main__':`); move it there, register it in the project's registry, or run with workers=1")
    if threads:
        torch.set_num_threads(threads)
    keep_freed_memory()  # same results, fewer page faults per update
    dirs = spec.member_dirs()
    queue = queue if queue is not None else interrupts.progress_queue

    def say(msg: str) -> None:
        if queue is not None:
            queue.put(msg)
        else:
            print(msg, flush=True)

    try:
        with run_locks(dirs, spec.label), in_group():
            remove_stale_temp([*dirs, spec.checkpoint_path().parent])
            _train_group(spec, command, say, should_stop)
        return None
    except KeyboardInterrupt:
        for d in dirs:
            _try_status(update_status, d, state="interrupted", steps_per_s=0.0, eta_s=math.inf)
        raise RunInterrupted(spec.label) from None
    except RunLocked:
        raise
    except Exception as e:  # noqa: BLE001 - recorded per run, the suite goes on
        err = f"{type(e).__name__}: {' '.join(str(e).split())}"
        for d in dirs:
            _try_status(update_status, d, state="failed", steps_per_s=0.0, eta_s=math.inf, error=err,
                        traceback=traceback.format_exc())
        return f"{spec.label}: {err}"


def _try_status(write, d: Path, **fields: Any) -> None:
    """A status write that must not hide the error being reported (e.g. a read-only results directory)."""
    try:
        write(d, **fields)
    except OSError:
        pass


def _train_group(spec: RunSpec, command: str, say, should_stop) -> None:
    import torch

    from algorithms.api import DemoSet
    from algorithms.core.sac import set_update_mode
    from harness.data import atomic_write_bytes
    from harness.envs import get_spec
    from harness.protocol import train
    from harness.registry import ALGORITHMS
    from harness.results import RUN_FILE, read_status

    meta = run_record(spec, command)
    # a finished run keeps the record of its run (unless it has none: a deleted run.yaml is written anew)
    if not all(finished(d, spec.steps) and (d / RUN_FILE).exists() for d in spec.member_dirs()):
        for d, s in zip(spec.member_dirs(), spec.seeds):
            atomic_write_bytes(d / RUN_FILE, yaml.safe_dump({**meta, "seed": s}, sort_keys=False).encode())
    elif spec.steps < (reached := min(int(read_status(d)["step"]) for d in spec.member_dirs())):
        say(f"[{spec.label}] done: trained to step {reached:,} already (steps={spec.steps:,}); nothing rewritten")
        return  # a run further than asked stays as it is (status, rows)
    cls = ALGORITHMS[spec.algo_class]
    demos = DemoSet(load_env_demos(spec.env, "forward"), load_env_demos(spec.env, "reverse"))
    algo = cls(get_spec(spec.env), demos, cls.Config.from_dict(spec.config), list(spec.seeds), torch.device(spec.device))
    set_update_mode(algo, spec.update)
    train(spec, algo, lambda p: say(progress_line(spec.label, p)), should_stop)


def progress_line(label: str, p) -> str:
    if p.resumed:
        return f"[{label}] resuming from the checkpoint at step {p.step:,} of {p.total:,}"
    succ = ",".join("-" if not np.isfinite(x) else f"{x:.2f}" for x in p.success)
    pct = 100.0 * p.step / max(p.total, 1)
    return (f"[{label}] {p.step:,}/{p.total:,} ({pct:.0f}%)  {p.steps_per_s:,.0f} steps/s  "
            f"ETA {format_duration(p.eta_s)}  success {succ}")


def print_plan(plan: Plan, calibrate: bool | str = False) -> None:
    """The plan, and its time on this machine from measured speeds (``calibrate``: measure what is not cached yet,
    a few seconds per kind of group; see :mod:`harness.calibration`)."""
    from harness import calibration

    total = [g.steps * len(g.seeds) for g in plan.groups]
    done = [steps_done(g) for g in plan.groups]
    steps, left = sum(total), sum(total) - sum(done)
    print(f"suite {plan.suite}: {len(plan.groups)} group(s), {sum(len(g.seeds) for g in plan.groups)} run(s), "
          f"{steps:,} env steps in all" + (f" ({left:,} left to run; the rest is done or checkpointed)" if left < steps else "")
          + f", {plan.workers} worker(s)")
    if plan.left_out:
        print(f"left out ({len(plan.left_out)}: they cannot run there):" + "".join(f"\n  {x}" for x in plan.left_out))
    if plan.machine:
        devices = sorted({g.device for g in plan.groups})
        print(f"packed for {plan.machine}: {plan.workers} process(es) at once on {', '.join(devices)}"
              + "".join(f"; {r}" for r in plan.packing))
    cores = os.cpu_count() or 1
    busy = min(plan.workers, len(plan.groups))
    if busy > cores and all(str(g.device).startswith("cpu") for g in plan.groups):
        print(f"harness: note: workers={plan.workers} starts {busy} processes on {cores} cores: they will share cores "
              f"and each run slower than one process per core (workers={cores})", file=sys.stderr)
    threads = calibration.worker_threads(plan.workers, str(plan.groups[0].device) if plan.groups else "cpu")
    todo = [i for i, (t, d) in enumerate(zip(total, done)) if d < t]
    short = [i for i in todo if plan.groups[i].steps <= calibration.SHORT_STEPS]  # measuring costs what running does
    todo = [i for i in todo if i not in short]
    rates = dict(zip(todo, calibration.rates([plan.groups[i] for i in todo], threads, calibrate)))
    aw = max([12, *(len(g.algo) for g in plan.groups)])
    sw = max([10, *(len(",".join(map(str, g.seeds))) for g in plan.groups)])
    for i, g in enumerate(plan.groups):
        speed = f"  {rates[i]:,.1f} steps/s per seed" if rates.get(i) else ""
        state = "  done" if done[i] == total[i] else f"  {done[i]:,} of {total[i]:,} steps done" if done[i] else ""
        mode = f"  update={g.update}" if g.update != "default" else ""
        print(f"  {g.env:<22} {g.algo:<{aw}} seeds={','.join(map(str, g.seeds)):<{sw}} steps={g.steps:,} "
              f"eval every {g.eval_every:,} x {g.eval_episodes}  config {g.config_hash}{mode}{speed}{state}")
    scripted = sorted({g.env for g in plan.groups if g.demo_source == "scripted"})
    if scripted:
        from harness.data import find_data_dir

        where = sorted({str(find_data_dir(f"demos/{e}/forward.npz")) for e in scripted})
        print(f"harness: note: the demonstrations of {', '.join(scripted)} are scripted (`harness data scripted`, in "
              f"{', '.join(where)}), not EARL's; results record demo_source=scripted", file=sys.stderr)
    for note in filter(None, (g.seed_phase_note() for g in plan.groups)):
        print(f"harness: note: {note}", file=sys.stderr)
    unmeasured = (f" (+ {len(short)} short group(s) of at most {calibration.SHORT_STEPS:,} steps per seed, not measured:"
                  " measuring one takes about as long as running it)") if short else ""
    if not todo and short:
        print(f"estimated time: not measured: every group is short (at most {calibration.SHORT_STEPS:,} steps per seed),"
              " and measuring one takes about as long as running it")
        return
    if any(rates[i] is None for i in todo):
        print("estimated time: not measured yet on this machine; `harness run ... --dry-run calibrate=true` (the "
              f"default) measures each kind of group for a few seconds (cached){unmeasured}")
        return
    evals = dict(zip(todo, calibration.eval_costs([plan.groups[i] for i in todo], threads)))
    work = []
    for i in todo:  # (steps left per member, its effective rate: evaluations included)
        left = max((total[i] - done[i]) // len(plan.groups[i].seeds), 1)
        seconds = calibration.group_seconds(plan.groups[i], left, rates[i], evals[i])  # 0: random steps only
        work.append((left, left / max(seconds, 1e-9)))
    est = calibration.estimate(work, plan.workers)
    when = calibration.when_measured([plan.groups[i] for i in todo], threads)
    measured = all(evals[i] is not None for i in todo)
    print(f"estimated time: {format_duration(est)} on {plan.workers} worker(s) x {threads} thread(s), from speeds measured "
          f"on this machine{when} (evaluations " + ("included, as measured" if measured else
                                                     f"add ~{calibration.EVAL_SHARE:.0%} where not measured")
          + "; other load on the machine slows it; calibrate=refresh measures again)" + unmeasured)
    if est > LONG_PLAN_S:
        print(ways_forward(plan, work, est))


#: a plan longer than this on the machine at hand gets the ways to shorten it (harness run --dry-run)
LONG_PLAN_S, CLUSTER_NODES = 24 * 3600, 8


def ways_forward(plan: Plan, work: list[tuple[int, float]], est: float) -> str:
    """What a user can do about a long plan: a Ray cluster of machines like this one, a GPU node, fewer seeds (with
    the time each would take, from the same measured speeds), or the shipped results."""
    from harness import calibration

    cluster = calibration.estimate(work, plan.workers * CLUSTER_NODES)
    seeds: dict[tuple[str, str], set[int]] = {}
    for g in plan.groups:
        seeds.setdefault((g.env, g.algo), set()).update(g.seeds)
    steps = {(g.env, g.algo): g.steps for g in plan.groups}
    share = sum(min(2, len(s)) * steps[c] for c, s in seeds.items()) / sum(len(s) * steps[c] for c, s in seeds.items())
    few = f"seeds=2 (about {format_duration(est * share)})" if share < 1 else ""
    return (f"that is long for this machine; ways forward: a Ray cluster of {CLUSTER_NODES} machines like it (backend=ray "
            f"ray_address=auto: about {format_duration(cluster)}); a GPU node (device=cuda trains a cell's seeds as members "
            "of one process, docs/performance.md)" + (f"; {few}" if few else "") + "; the tables shipped in results/ "
            "already hold what this project has run (streamlit run app.py, harness report)")


def run_cli(words: list[str], dry_run: bool = False) -> int:
    plan = plan_words(words)
    print_plan(plan, calibrate=dry_run and plan.calibrate)
    if dry_run or not plan.groups:
        return 0
    command = " ".join(["harness", "run", *map(shlex.quote, words)])
    t0 = time.time()
    from harness.backends import run_plan

    errors = run_plan(plan, command, run_group)
    print(f"done: {len(plan.groups) - len(errors)}/{len(plan.groups)} group(s) in {format_duration(time.time() - t0)}; "
          f"results in {plan.groups[0].results}")
    return 1 if errors else 0
