"""Execution backends: where the run groups of a plan (and tuning's workers) run.

- ``backend=local`` (default): the groups run in this process (``workers=1``) or in a pool of
  ``workers`` spawned processes on this machine, each with one torch thread on a CPU (``cores // workers`` on a GPU).
- ``backend=ray``: each group is one Ray remote task (one CPU and one torch thread, and one GPU
  when the device is CUDA). ``ray_address=auto`` (or ``HOST:PORT``) joins a running cluster; without it a local Ray
  instance with ``workers`` CPUs is started (or the one this process already initialised is used).
  Every task writes into the shared results path. A task whose worker dies (node lost, OOM kill,
  SIGKILL) or that raises is retried up to ``RAY_MAX_RETRIES`` times; a retry resumes from the
  group's checkpoint because the work function (:func:`harness.runner.run_group`) always resumes. Ctrl-C cancels the
  outstanding tasks (``ray.cancel(force=True)``) and the command exits with code 130.

Both backends run the work function they are given (``harness run`` passes :func:`harness.runner.run_group`; this
module imports neither the runner nor the tuner), so the same suite gives the same deterministic rows on either
(timing metrics aside). :func:`ray_session` is the one place that starts and stops Ray.
"""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager
from typing import Any, Callable

from harness.plan import Plan, RunSpec
from harness.words import ConfigError

RAY_MAX_RETRIES = 3
#: environment variables a Ray worker needs to see as the driver does
FORWARDED_ENV = ("MUJOCO_GL", "HARNESS_DATA_DIR", "HARNESS_CACHE_DIR", "HARNESS_STATE_DIR", "OMP_NUM_THREADS",
                 "PYTHONHASHSEED")
#: test hook: if set (to a marker path), a Ray task SIGKILLs its own worker process once, right after
#: its group's first checkpoint appears, to check that Ray's retry resumes the group
TEST_KILL_ENV = "HARNESS_TEST_RAY_KILL_ONCE"


#: the work of one group: (group, command, progress queue, torch threads) -> an error line or None
Work = Callable[..., "str | None"]


def run_plan(plan: Plan, command: str, work: Work) -> list[str]:
    """Run ``work`` on every group of ``plan`` on its backend; returns the error lines (one per failed group)."""
    if plan.backend == "local":
        return run_local(plan, command, work)
    if plan.backend == "ray":
        return run_ray(plan, command, work, plan.ray_address)
    raise ConfigError(f"unknown backend {plan.backend!r}; known backends: local, ray")


def _report(err: str | None, errors: list[str]) -> None:
    if err:
        print(f"harness: run failed: {err}", file=sys.stderr)
        errors.append(err)


# ---------------------------------------------------------------------------------------- local


class Interrupted(Exception):
    """The plan stopped on SIGINT/SIGTERM; ``runs`` groups were stopped at their last checkpoint."""

    def __init__(self, runs: int):
        super().__init__(f"{runs} run group(s) stopped")
        self.runs = runs


def _skip_locked(e: Exception, plan: Plan, skipped: list[str]) -> None:
    """A group another process is training: an input error when it is the plan's only group, else skipped."""
    if len(plan.groups) == 1:
        raise e
    print(f"harness: skipping {e}", file=sys.stderr, flush=True)
    skipped.append(str(e))


def process_threads(plan: Plan) -> int:
    """Torch threads of each training process: one on a CPU, whatever the number of workers (the networks are small:
    a second intra-op thread buys little on an idle machine and stalls the step for seconds when another process
    holds the other core, as on a 2-core machine beside one other run); on a GPU, the cores shared out."""
    if all(str(g.device).startswith("cpu") for g in plan.groups):
        return 1
    return max(1, (os.cpu_count() or 1) // plan.workers)


#: freed heap that glibc keeps for reuse in a training process (:func:`keep_freed_memory`)
KEEP_FREED_BYTES = 256 << 20


def keep_freed_memory(limit: int = KEEP_FREED_BYTES) -> bool:
    """Let glibc's malloc keep up to ``limit`` bytes of freed heap for reuse instead of handing it back to the OS.

    A CPU training step allocates its activations afresh and frees them at its end. With glibc's default trim threshold
    (128 KiB, raised only as large blocks are freed) the heap shrinks after each update and the next one page-faults
    the memory back in, a fresh page at a time: a ReLU's gradient takes 100-200 us inside the update against 15 on its
    own, and one MEDAL update about 1.3x as long (``harness bench update allocator=glibc`` against the default, in
    docs/performance.md). Results are the same bit for bit. Returns False where the C library has no ``mallopt`` (not
    glibc), which leaves the allocator as it is."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        return bool(libc.mallopt(-1, int(limit)))  # -1: M_TRIM_THRESHOLD
    except (OSError, AttributeError, TypeError):
        return False


#: ``allocator=`` of the benches: keep (as training processes run), glibc (its defaults, for comparison)
ALLOCATORS = ("keep", "glibc")


def use_allocator(name: str) -> None:
    if name not in ALLOCATORS:
        raise ConfigError(f"unknown allocator {name!r}; known: {', '.join(ALLOCATORS)}")
    if name == "keep":
        keep_freed_memory()


def run_local(plan: Plan, command: str, work: Work) -> list[str]:
    from harness.interrupts import RunInterrupted, RunLocked, sigterm_as_interrupt

    if plan.workers > 1:
        return run_pool(plan, command, work)
    errors: list[str] = []
    skipped: list[str] = []
    with sigterm_as_interrupt():
        for g in plan.groups:
            try:
                _report(work(g, command, None, process_threads(plan)), errors)
            except RunLocked as e:
                _skip_locked(e, plan, skipped)
            except RunInterrupted:
                raise Interrupted(1) from None
    return errors


def _pool_init(data_dir: str | None, queue=None) -> None:
    from harness import data as data_mod
    from harness.interrupts import init_worker

    init_worker(queue)
    data_mod.set_data_dir(data_dir)


def _data_dir() -> str | None:
    from harness import data as data_mod

    return getattr(data_mod, "_explicit_default", None)


def _drain(q) -> None:
    import queue as queue_mod

    while True:
        try:
            print(q.get_nowait(), flush=True)
        except (queue_mod.Empty, OSError, EOFError):
            return


def run_pool(plan: Plan, command: str, work: Work) -> list[str]:
    """The groups in a pool of ``plan.workers`` spawned processes; progress lines through a queue. Ctrl-C or SIGTERM:
    no new group starts, the running ones stop at once (statuses ``interrupted``) and :class:`Interrupted` is
    raised; a second signal kills the workers (see :mod:`harness.interrupts`)."""
    import multiprocessing as mp
    import queue as queue_mod
    from concurrent.futures import ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from harness.interrupts import RunInterrupted, RunLocked, sigterm_as_interrupt, stop_children

    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    threads = process_threads(plan)
    errors: list[str] = []
    skipped: list[str] = []
    stopped = 0
    pool = ProcessPoolExecutor(max_workers=plan.workers, mp_context=ctx, initializer=_pool_init,
                               initargs=(_data_dir(), q))
    futures = []
    try:
        with sigterm_as_interrupt():
            futures = [pool.submit(work, g, command, None, threads) for g in plan.groups]
            pending = set(futures)
            while pending:
                try:
                    print(q.get(timeout=0.5), flush=True)
                except queue_mod.Empty:
                    pass
                for f in [f for f in pending if f.done()]:
                    pending.discard(f)
                    try:
                        _report(f.result(), errors)
                    except RunLocked as e:
                        _skip_locked(e, plan, skipped)
    except KeyboardInterrupt:
        for f in futures:
            f.cancel()
        stop_children(lambda: wait(futures))
        for f in futures:
            if f.done() and not f.cancelled():
                try:
                    f.result()
                except (RunInterrupted, BrokenProcessPool):
                    stopped += 1
                except Exception:  # noqa: BLE001 - finished or failed before the interrupt: reported by its status
                    pass
        pool.shutdown(wait=True, cancel_futures=True)
        _drain(q)
        raise Interrupted(stopped) from None
    pool.shutdown(wait=True)
    _drain(q)
    return errors


def run_local_tasks(fn: Callable[..., Any], args_list: list[tuple], workers: int) -> list[Any]:
    """``fn(*args)`` for each args tuple: in this process when there is one, else one spawned process
    each (tuning's workers). Returns the results in order. Ctrl-C / SIGTERM stop the workers (as in
    :func:`run_pool`) and raise :class:`Interrupted`."""
    from harness.interrupts import sigterm_as_interrupt, stop_children

    if len(args_list) == 1 or workers <= 1:
        with sigterm_as_interrupt():
            return [fn(*a) for a in args_list]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, wait

    ctx = mp.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=len(args_list), mp_context=ctx, initializer=_pool_init,
                               initargs=(_data_dir(),))
    futures = []
    try:
        with sigterm_as_interrupt():
            futures = [pool.submit(fn, *a) for a in args_list]
            out = [f.result() for f in futures]
    except KeyboardInterrupt:
        stop_children(lambda: wait(futures), "tuning worker(s)")
        pool.shutdown(wait=True, cancel_futures=True)
        raise Interrupted(len(futures)) from None
    pool.shutdown(wait=True)
    return out


# ------------------------------------------------------------------------------------------ ray


class GroupFailed(RuntimeError):
    """A group's run raised; raised inside the Ray task so that Ray retries it."""


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ConfigError("backend=ray needs Ray: pip install 'ray>=2.9'") from None
    return ray


def ray_env() -> dict[str, str]:
    """The environment variables a Ray worker needs to see as the driver does."""
    env = {k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}
    if os.environ.get(TEST_KILL_ENV):
        env[TEST_KILL_ENV] = os.environ[TEST_KILL_ENV]
    return env


@contextmanager
def ray_session(address: str | None, num_cpus: int):
    """The ray module, initialised for the block: joins ``address``, reuses an initialised Ray, or starts a local
    instance with ``num_cpus`` CPUs (shut down again at the end of the block)."""
    ray = _import_ray()
    if ray.is_initialized():
        yield ray
        return
    kw: dict[str, Any] = {"log_to_driver": True, "include_dashboard": False}
    if address:
        kw["address"] = address
    else:
        kw["num_cpus"] = num_cpus
    try:
        ray.init(**kw)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise ConfigError(f"cannot connect to Ray at {address or 'a new local instance'}: {' '.join(str(e).split())}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _kill_after_first_checkpoint(group: RunSpec) -> None:
    """The test hook of :data:`TEST_KILL_ENV`: a thread that SIGKILLs this worker process once."""
    marker = os.environ.get(TEST_KILL_ENV)
    if not marker or os.path.exists(marker):
        return
    import signal
    import time

    ckpt = group.checkpoint_path()

    def watch() -> None:
        while not ckpt.exists():
            time.sleep(0.02)
        with open(marker, "w") as f:
            f.write(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, daemon=True).start()


def _ray_group(work: Work, group: RunSpec, command: str, threads: int, data_dir: str | None,
               env: dict[str, str]) -> None:
    """The body of one Ray task: run (or resume) the group; raise on failure so Ray retries it."""
    os.environ.update(env)
    from harness import data as data_mod

    data_mod.set_data_dir(data_dir)
    _kill_after_first_checkpoint(group)
    err = work(group, command, None, threads)
    if err:
        raise GroupFailed(err)


def _ray_error_line(e: BaseException) -> str:
    cause = getattr(e, "cause", None)
    if isinstance(cause, GroupFailed):
        return str(cause)
    return f"{type(e).__name__}: {' '.join(str(e).split())[:500]}"


def run_ray_tasks(ray, fn: Callable[..., Any], args_list: list[tuple], labels: list[str], options: dict[str, Any],
                  on_error: Callable[[str, str], None]) -> list[Any]:
    """Submit ``fn(*args)`` as Ray tasks and wait for all; Ctrl-C cancels the outstanding ones.
    ``on_error(label, line)`` is called for each task that failed after its retries."""
    remote = ray.remote(fn).options(**options)
    refs = [remote.remote(*a) for a in args_list]
    index = {ref: i for i, ref in enumerate(refs)}
    out: list[Any] = [None] * len(refs)
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1, timeout=1.0)
            for ref in done:
                i = index[ref]
                try:
                    out[i] = ray.get(ref)
                except ray.exceptions.RayError as e:
                    on_error(labels[i], _ray_error_line(e))
    except KeyboardInterrupt:
        print(f"harness: interrupted: cancelling {len(pending)} Ray task(s)", file=sys.stderr, flush=True)
        for ref in pending:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - already finished or gone
                pass
        raise
    return out


def _mark_interrupted(plan: Plan) -> int:
    """After cancelling Ray tasks: the runs that were training say ``interrupted``; returns the number of groups."""
    from harness.results import read_status, update_status

    n = 0
    for g in plan.groups:
        running = [d for d in g.member_dirs() if (read_status(d) or {}).get("state") in ("running", "resumed")]
        for d in running:
            update_status(d, state="interrupted", steps_per_s=0.0)
        n += bool(running)
    return n


def ray_options(device: str, num_cpus: float, per_gpu: int = 1) -> dict[str, Any]:
    """A group's Ray resources: ``num_cpus``, and on CUDA 1/``per_gpu`` of a GPU (the plan's processes per GPU)."""
    opts: dict[str, Any] = {"num_cpus": num_cpus, "max_retries": RAY_MAX_RETRIES, "retry_exceptions": True}
    if str(device).startswith("cuda"):
        opts["num_gpus"] = 1.0 / max(per_gpu, 1)
    return opts


def run_ray(plan: Plan, command: str, work: Work, address: str | None = None) -> list[str]:
    """Each group one Ray task; returns the error lines of the groups that failed after retries."""
    threads = 1  # each task reserves one CPU (num_cpus=1): one torch thread
    errors: list[str] = []
    env, data_dir = ray_env(), _data_dir()
    with ray_session(address, plan.workers) as ray:
        labels = [g.label for g in plan.groups]

        def on_error(label: str, line: str) -> None:
            _report(line if line.startswith(label) else f"{label}: {line}", errors)

        try:
            run_ray_tasks(ray, _ray_group, [(work, g, command, threads, data_dir, env) for g in plan.groups],
                          labels, ray_options(plan.groups[0].device, 1, plan.per_device), on_error)
        except KeyboardInterrupt:
            raise Interrupted(_mark_interrupted(plan)) from None
    return errors
