"""The E member envs of a run group, stepped in this process or in worker processes (``env_workers=N``).

A group of E seeds steps E independent simulators at every protocol step. In this process that is a loop of E steps;
with many members (a GPU process training 32-128 seeds) the loop would serialise on one core, so
:class:`WorkerEnvs` splits the members into N contiguous slices, one per worker process, and steps the slices in
parallel (a pipe per worker; the arrays are a few hundred bytes per member). Each member's env is the same
deterministic simulator, seeded the same way, wherever it runs, so the results are identical to :class:`LocalEnvs`
(``tests/test_env_pool.py`` asserts it bit for bit, through a checkpoint and resume). Checkpoints hold each env's
simulator and wrapper state in the same format either way.

Both kinds offer one interface: ``reset(indices, seeds)``, ``step(actions)`` -> (obs, reward, truncated, success),
``interventions()``, ``get_states()`` / ``set_states()`` and ``close()``. ``kind`` is ``train`` (EARL's persistent
env, truncating every H_T steps) or ``eval`` (the bare env; the evaluation loop counts H_E itself).
"""

from __future__ import annotations

import multiprocessing as mp
from typing import Any, Sequence

import numpy as np


def make_member_env(env: str, kind: str):
    """One member's env: ``train`` (EARL's persistent env) or ``eval`` (the bare env)."""
    from harness.envs import make_env, make_train_env

    return make_train_env(env) if kind == "train" else make_env(env)


class LocalEnvs:
    """The member envs in this process."""

    def __init__(self, env: str, n: int, kind: str = "train", envs: list | None = None):
        self.envs = envs if envs is not None else [make_member_env(env, kind) for _ in range(n)]
        self.kind = kind
        self.spec_ = self.envs[0].unwrapped.spec_  # the EnvSpec (horizons, goals)

    def __len__(self) -> int:
        return len(self.envs)

    def reset(self, indices: Sequence[int], seeds: Sequence[int | None] | None = None) -> np.ndarray:
        seeds = seeds if seeds is not None else [None] * len(indices)
        return np.stack([self.envs[i].reset(seed=s)[0] for i, s in zip(indices, seeds)])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        E = len(self.envs)
        obs, rew = [None] * E, np.zeros(E)
        trunc, succ = np.zeros(E, dtype=bool), np.zeros(E, dtype=bool)
        for i, env in enumerate(self.envs):
            obs[i], rew[i], _, trunc[i], info = env.step(actions[i])
            succ[i] = info["success"]
        return np.stack(obs), rew, trunc, succ

    def interventions(self) -> np.ndarray:
        return np.array([env.interventions for env in self.envs], dtype=np.float64)

    def get_states(self) -> list[dict[str, Any]]:
        return [{"sim": env.unwrapped.get_sim_state(),
                 **({"wrapper": env.get_wrapper_state()} if self.kind == "train" else {})} for env in self.envs]

    def set_states(self, states: list[dict[str, Any]]) -> None:
        for env, st in zip(self.envs, states):
            env.unwrapped.set_sim_state(st["sim"])
            if "wrapper" in st:
                env.set_wrapper_state(st["wrapper"])

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _worker(conn, env: str, n: int, kind: str, data_dir: str | None) -> None:
    """A worker process: ``n`` member envs, commands from the pipe until ``close`` (or the parent is gone)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it closes the workers
    from harness import data as data_mod

    data_mod.set_data_dir(data_dir)
    local = LocalEnvs(env, n, kind)
    try:
        while True:
            cmd, arg = conn.recv()
            if cmd == "close":
                break
            try:
                conn.send(("ok", getattr(local, cmd)(*arg)))
            except Exception as e:  # noqa: BLE001 - raised again in the parent, naming the worker
                conn.send(("error", f"{type(e).__name__}: {e}"))
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        local.close()


class WorkerEnvs:
    """The member envs split over ``workers`` processes (contiguous slices, sizes differing by at most one)."""

    def __init__(self, env: str, n: int, workers: int, kind: str = "train"):
        from harness import data as data_mod
        from harness.envs import get_spec

        self.spec_ = get_spec(env)
        workers = max(1, min(workers, n))
        sizes = [n // workers + (w < n % workers) for w in range(workers)]
        self.bounds = np.cumsum([0, *sizes])
        self.kind, self.n = kind, n
        ctx = mp.get_context("spawn")
        self.conns, self.procs = [], []
        data_dir = getattr(data_mod, "_explicit_default", None)
        for size in sizes:
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(child, env, size, kind, data_dir), daemon=True)
            p.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(p)

    def __len__(self) -> int:
        return self.n

    def _call(self, per_worker: list[tuple[str, tuple]]) -> list[Any]:
        for conn, msg in zip(self.conns, per_worker):
            conn.send(msg)
        replies = [conn.recv() for conn in self.conns]  # every reply, so that the pipes stay in step after an error
        for w, (status, value) in enumerate(replies):
            if status == "error":
                raise RuntimeError(f"env worker {w}: {value}")
        return [value for _, value in replies]

    def _slices(self) -> list[slice]:
        return [slice(a, b) for a, b in zip(self.bounds[:-1], self.bounds[1:])]

    def reset(self, indices: Sequence[int], seeds: Sequence[int | None] | None = None) -> np.ndarray:
        seeds = list(seeds) if seeds is not None else [None] * len(indices)
        asks: list[tuple[list[int], list]] = [([], []) for _ in self.conns]
        where = []
        for i, s in zip(indices, seeds):
            w = int(np.searchsorted(self.bounds, i, side="right")) - 1
            where.append((w, len(asks[w][0])))
            asks[w][0].append(int(i - self.bounds[w]))
            asks[w][1].append(s)
        busy = [w for w, (idx, _) in enumerate(asks) if idx]
        for w in busy:
            self.conns[w].send(("reset", asks[w]))
        got = {w: self.conns[w].recv() for w in busy}
        for w, (status, value) in got.items():
            if status == "error":
                raise RuntimeError(f"env worker {w}: {value}")
        got = {w: value for w, (_, value) in got.items()}
        return np.stack([got[w][k] for w, k in where])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        parts = self._call([("step", (actions[s],)) for s in self._slices()])
        return tuple(np.concatenate([p[k] for p in parts]) for k in range(4))  # type: ignore[return-value]

    def interventions(self) -> np.ndarray:
        return np.concatenate(self._call([("interventions", ())] * len(self.conns)))

    def get_states(self) -> list[dict[str, Any]]:
        return [st for part in self._call([("get_states", ())] * len(self.conns)) for st in part]

    def set_states(self, states: list[dict[str, Any]]) -> None:
        self._call([("set_states", (states[s],)) for s in self._slices()])

    def close(self) -> None:
        for conn in self.conns:
            try:
                conn.send(("close", ()))
            except (BrokenPipeError, OSError):
                pass
        for p in self.procs:
            p.join(timeout=5)
            if p.is_alive():
                p.terminate()
        self.conns, self.procs = [], []


def make_envs(env: str, n: int, workers: int = 0, kind: str = "train") -> LocalEnvs | WorkerEnvs:
    """The ``n`` member envs of a group: in this process (``workers`` 0 or 1) or over ``workers`` processes."""
    return WorkerEnvs(env, n, workers, kind) if workers > 1 and n > 1 else LocalEnvs(env, n, kind)
