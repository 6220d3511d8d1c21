"""Stopping cleanly and running each group once: run locks, interrupts, stale temporary files.

- :func:`run_locks`: an exclusive ``fcntl`` lock per run directory, held while a process trains it. The kernel
  releases it when the process dies (kill -9 included), so no lock is ever stale; a second process that asks for a
  held run gets :class:`RunLocked` naming the holder's pid.
- Interrupts: the first SIGINT or SIGTERM stops a run at once (its last checkpoint is the resume point) and marks it
  ``interrupted``; :class:`RunInterrupted` carries that out of :func:`harness.runner.run_group`. Pool workers ignore
  SIGINT (the terminal sends Ctrl-C to the whole process group) and turn SIGTERM, which the parent forwards, into
  the same interrupt; the parent exits 130 after the workers have stopped, and a second signal kills them at once.
"""

from __future__ import annotations

import fcntl
import os
import signal
import sys
from contextlib import ExitStack, contextmanager
from pathlib import Path

from harness.suites import ConfigError

LOCK_FILE = ".lock"
#: temporary files a killed writer may leave behind (atomic writes of results and checkpoints)
STALE_TEMP = (".*.tmp",)


class RunLocked(ConfigError):
    """Another live process is training this run."""


class RunInterrupted(Exception):
    """A run group stopped on SIGINT/SIGTERM; its status says ``interrupted``."""


@contextmanager
def run_locks(dirs: list[Path], label: str):
    """Hold an exclusive lock on every run directory in ``dirs`` (all or none)."""
    with ExitStack() as stack:
        for d in sorted(dirs):
            d.mkdir(parents=True, exist_ok=True)
            fd = os.open(d / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
            stack.callback(os.close, fd)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "another process"
                raise RunLocked(f"{label}: {d.name} is being trained by process {holder} (lock {d / LOCK_FILE}); "
                                "not running it twice") from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield


def remove_stale_temp(dirs: list[Path]) -> list[Path]:
    """Delete temporary files left by a writer that was killed mid-write (only call while holding the locks)."""
    gone = []
    for d in dirs:
        if d.is_dir():
            for pattern in STALE_TEMP:
                for p in d.glob(pattern):
                    p.unlink(missing_ok=True)
                    gone.append(p)
    return gone


# ------------------------------------------------------------------------------------------------ workers
_in_group = False
#: in a pool worker: where progress lines go (the parent prints them); None elsewhere
progress_queue = None


def _worker_sigterm(signum, frame) -> None:
    if _in_group:
        raise KeyboardInterrupt  # caught by run_group: the run is marked interrupted
    os._exit(130)  # idle worker: nothing to save


def init_worker(queue=None) -> None:
    """In a pool worker: ignore the terminal's SIGINT, stop on the parent's SIGTERM (see the module docstring), send
    progress lines to ``queue``."""
    global progress_queue
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    progress_queue = queue


@contextmanager
def in_group():
    """Mark the worker as training (a SIGTERM then interrupts the run instead of ending the process)."""
    global _in_group
    _in_group = True
    try:
        yield
    finally:
        _in_group = False


# ------------------------------------------------------------------------------------------------ parent
@contextmanager
def sigterm_as_interrupt():
    """In the parent: SIGTERM behaves like Ctrl-C (KeyboardInterrupt) while the block runs."""
    def handler(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def stop_children(wait_for, what: str = "run(s)") -> None:
    """After a first interrupt in the parent: forward SIGTERM to the pool's workers and wait (``wait_for()``) until
    they have marked their runs interrupted; a second interrupt while waiting kills them at once and exits 130."""
    import multiprocessing as mp

    print(f"harness: interrupted: stopping the running {what} at their last checkpoint (Ctrl-C again: kill now)",
          file=sys.stderr, flush=True)
    children = mp.active_children()
    for p in children:
        try:
            os.kill(p.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    try:
        with sigterm_as_interrupt():
            wait_for()
    except KeyboardInterrupt:
        for p in children:
            try:
                os.kill(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        print("harness: killed", file=sys.stderr, flush=True)
        os._exit(130)
