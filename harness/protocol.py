"""The EARL protocol loop: reset-free training, deployed-policy evaluation, results, checkpoints.

One call of :func:`train` runs one *group*: E members (seeds) of the same (suite, env, algo,
config) in lockstep, each with its own train env, eval env and results directory.

Protocol (docs/algorithms.md 1.2-1.3):

- the train env is EARL's persistent-state env; it is reset only when H_T steps have elapsed
  since its last reset (a hard reset, counted as an intervention) or when the algorithm asks
  (episodic baselines such as oracle RL; also counted);
- deployed evaluation at step 0 and every ``eval_every`` steps: ``eval_episodes`` episodes of
  H_E steps in a separate eval env, s0 ~ rho0 (and a random task goal), the deterministic forward
  policy; an episode is a success if any of its steps succeeds; eval data never reaches the
  learner. Evaluation episodes are seeded from (member seed, step) (:func:`eval_seed`: never the same
  seed twice in a run, for any ``eval_every``), so they do not depend on when a run was checkpointed or resumed;
- the continuing metric is the cumulative reward of the train env (its own task goal).

Checkpoints are taken at evaluation steps that are multiples of ``checkpoint_every`` and at the
end (those at multiples of ``keep_every`` are also kept, as ``checkpoint-<step>.pt``, to probe the policy at
that step later); they hold the algorithm's full state (networks, optimizers, buffers, RNGs, phase), the train
envs' simulator and wrapper state, the current observations and the counters. Re-running the same
run resumes from the checkpoint and truncates each results table to that step, so the results
equal an uninterrupted run's (timing metrics aside).

Non-finite actions (in training or evaluation) raise :class:`DivergedError` naming the member and step
before they reach an env or a buffer; the check reads the host action array, so it costs no device sync.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from algorithms.api import AFTER_ACT, AFTER_STORE, Algorithm
from harness.data import disk_full
from harness.env_pool import LocalEnvs, WorkerEnvs, make_envs
from harness.plan import RunSpec
from harness.results import TRAIN_FILE, RunResults, kept_checkpoint_path, write_status


@dataclass
class Progress:
    """What the live display shows for a group."""

    step: int
    total: int
    steps_per_s: float
    eta_s: float
    success: list[float]
    resumed: bool = False  # the run just resumed from its checkpoint at ``step``


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read; the message names the file and the fix."""


def load_checkpoint(path: Path, device: str = "cpu") -> dict[str, Any]:
    """A group's checkpoint with its tensors on ``device`` (a CUDA checkpoint resumes on any GPU of the node). Its
    random streams belong to the kind of device that wrote it (CPU and CUDA generators differ), so a checkpoint
    resumes on that kind only; loading its tensors elsewhere (``map_location``) works for inspection."""
    try:
        ck = torch.load(path, weights_only=False, map_location=device)
        if not isinstance(ck, dict) or not {"step", "wall_s", "last_success", "algo", "interaction"} <= set(ck):
            raise ValueError("not a harness checkpoint")
    except Exception as e:  # noqa: BLE001 - torch.load raises many kinds on a truncated or foreign file
        raise CheckpointError(
            f"checkpoint {path} is unreadable ({type(e).__name__}: {' '.join(str(e).split())[:120]}): delete it to "
            "restart these runs from step 0 (their results are rewritten), or restore it from a copy") from None
    written_on = torch.device(ck.get("device", "cpu")).type
    if written_on != torch.device(device).type:
        raise CheckpointError(f"checkpoint {path} was written on {written_on} and its random streams are {written_on} "
                              f"generators: resume it with device={written_on}, or delete it to restart on "
                              f"{torch.device(device).type} from step 0")
    return ck


class DivergedError(RuntimeError):
    """The algorithm returned non-finite actions: a NaN or inf loss has reached its policy."""


def check_actions(actions: np.ndarray, seeds: list[int], when: str) -> None:
    """Raise :class:`DivergedError` naming the members whose ``actions`` (E, act_dim) hold NaN or inf, before
    they reach an env or a buffer (so the last checkpoint and the results written so far stay good)."""
    ok = np.isfinite(actions).all(axis=-1)
    if not ok.all():
        bad = ", ".join(str(s) for s, good in zip(seeds, ok) if not good)
        raise DivergedError(f"non-finite actions (NaN/inf) from seed {bad} {when}: the networks diverged "
                            "(a NaN or inf loss); lower the learning rates or check the rewards")


class Interaction:
    """The E train envs and the current observations: one protocol step at a time. ``env_workers`` > 1 steps the
    envs in that many worker processes (:mod:`harness.env_pool`; same results); call :meth:`close` when done."""

    def __init__(self, env: str, seeds: list[int], env_workers: int = 0):
        self.envs = make_envs(env, len(seeds), env_workers, "train")
        self.seeds = seeds
        self.obs: np.ndarray | None = None
        self.cum_reward = np.zeros(len(seeds))
        self.env_seconds = 0.0
        self.timed = False

    def start(self, algo: Algorithm) -> None:
        self.obs = self.envs.reset(range(len(self.seeds)), self.seeds)
        algo.on_reset(self.obs, np.ones(len(self.envs), dtype=bool))

    def step(self, algo: Algorithm, step: int | None = None) -> None:
        """act -> (update) -> env step -> store -> (update) -> observe -> reset the members that hit H_T or asked
        for a reset; the update where the algorithm's ``update_at`` says (algorithms/api.py). ``step`` (the protocol
        step being taken) only names where a :class:`DivergedError` happened."""
        actions = algo.act(self.obs)
        check_actions(actions, self.seeds, "in training" + (f" at step {step:,}" if step is not None else ""))
        if algo.update_at == AFTER_ACT:
            algo.update()  # MEDAL's order: learn before the env moves
        t = time.perf_counter() if self.timed else 0.0
        next_obs, rewards, hard, _ = self.envs.step(actions)  # a fresh array each step: algorithms may keep it
        next_obs = next_obs.astype(self.obs.dtype, copy=False)
        if self.timed:
            self.env_seconds += time.perf_counter() - t
        self.cum_reward += rewards
        algo.store(next_obs, hard)
        if algo.update_at == AFTER_STORE:
            algo.update()  # RISC's order: learn from the transition just stored, then pick goals with the new critic
        reset = hard | algo.observe(next_obs, hard)
        if reset.any():
            idx = np.flatnonzero(reset)
            next_obs[idx] = self.envs.reset(idx)
            algo.on_reset(next_obs, reset)
        self.obs = next_obs

    def interventions(self) -> np.ndarray:
        return self.envs.interventions()

    def state_dict(self) -> dict[str, Any]:
        return {"envs": self.envs.get_states(), "obs": self.obs, "cum_reward": self.cum_reward}

    def load_state_dict(self, st: dict[str, Any]) -> None:
        self.envs.set_states(st["envs"])
        self.obs, self.cum_reward = st["obs"], st["cum_reward"]

    def close(self) -> None:
        self.envs.close()


def eval_seed(member_seed: int, step: int) -> int:
    """The seed of the first evaluation episode at ``step`` of the member seeded ``member_seed`` (>= 0): different for
    every (member seed, step) of a run, for any ``eval_every``. Steps at multiples of 1000 (every EARL schedule) keep
    the formula that all shipped results used; other steps map above 2**31, into one block of 2**34 steps per seed."""
    if step % 1000 == 0:
        return (member_seed * 1_000_003 + step // 1000) % (2**31 - 1)
    return 2**31 + member_seed * 2**34 + step


def evaluate(algo: Algorithm, envs: list | LocalEnvs | WorkerEnvs, seeds: list[int], step: int,
             episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Deployed-policy evaluation of all members (``envs``: a list of eval envs, or a pool of them); returns
    (success rate, mean return), each (E,)."""
    if isinstance(envs, list):
        envs = LocalEnvs("", len(envs), "eval", envs)
    E = len(envs)
    horizon = envs.spec_.eval_horizon
    successes = np.zeros(E)
    returns = np.zeros(E)
    for ep in range(episodes):
        obs = envs.reset(range(E), [eval_seed(s, step) for s in seeds] if ep == 0 else None)
        hit = np.zeros(E, dtype=bool)
        for _ in range(horizon):
            actions = algo.eval_act(obs)
            check_actions(actions, seeds, f"in the evaluation at step {step:,}")
            obs, r, _, succ = envs.step(actions)
            returns += r
            hit |= succ
        successes += hit
    return successes / episodes, returns / episodes


def _atomic_torch_save(obj: Any, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".ckpt.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)  # the last checkpoint stays as it was: the run resumes from it
        full = disk_full(path, e)
        if full is not None:
            raise full from None
        raise


def _keep(ckpt: Path, step: int) -> None:
    """The checkpoint at ``step`` (``ckpt``) is also kept as ``checkpoint-<step>.pt``: a hard link (a copy where links
    are not supported), made atomically and only once. The next checkpoint replaces ``ckpt``'s directory entry, not
    its data, so the kept one stays as it is (and from then on holds a full checkpoint's disk space)."""
    kept = kept_checkpoint_path(ckpt, step)
    if kept.exists():
        return
    tmp = kept.with_name(f".keep.{kept.name}.tmp")
    tmp.unlink(missing_ok=True)
    try:
        os.link(ckpt, tmp)
    except OSError:
        shutil.copy2(ckpt, tmp)
    os.replace(tmp, kept)


def train(
    spec: RunSpec,
    algo: Algorithm,
    on_progress: Callable[[Progress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> list[RunResults]:
    """Run (or resume) one group to ``spec.steps`` training steps. Returns the per-member results."""
    E = len(spec.seeds)
    inter = Interaction(spec.env, spec.seeds, spec.env_workers)
    eval_envs = make_envs(spec.env, E, spec.env_workers, "eval")
    closers: list = [inter, eval_envs]
    try:
        return TrainingRun(spec, algo, inter, eval_envs, on_progress, closers).run(should_stop)
    finally:
        for c in closers:
            c.close()


@dataclass(frozen=True)
class Every:
    """A schedule of the loop: due at every multiple of ``n`` and at the run's last step (``last``)."""

    n: int
    last: int

    def __call__(self, step: int) -> bool:
        return step % self.n == 0 or step == self.last


class TrainingRun:
    """One group's training under the EARL protocol: resume or start, then step, log, evaluate and checkpoint on
    their schedules until ``spec.steps``. Each training step is ``Interaction.step``: act, the update (MEDAL-family
    methods: here, before the env moves, as MEDAL's code does), env step, store, the update (goal-conditioned
    methods: here, before the next goal is picked, as RISC's code does), observe, resets."""

    def __init__(self, spec: RunSpec, algo: Algorithm, inter: Interaction, eval_envs: LocalEnvs | WorkerEnvs,
                 on_progress: Callable[[Progress], None] | None, closers: list):
        self.spec, self.algo, self.inter, self.eval_envs, self.on_progress = spec, algo, inter, eval_envs, on_progress
        E = len(spec.seeds)
        self.dirs = spec.member_dirs()
        meta = {**spec.meta, "members": E}
        ident = {"suite": spec.suite, "env": spec.env, "algo": spec.algo}
        self.results = [RunResults(d, {**ident, "seed": s}, meta) for d, s in zip(self.dirs, spec.seeds)]
        self.diagnostics = [RunResults(r.dir, r.ident, meta, TRAIN_FILE) for r in self.results]
        self.ckpt_path = spec.checkpoint_path()
        self.log_due, self.eval_due = Every(spec.log_every, spec.steps), Every(spec.eval_every, spec.steps)
        self.checkpoint_due = Every(spec.checkpoint_every, spec.steps)
        self.status = "running"
        self.step, self.wall, self.last_success = 0, 0.0, [float("nan")] * E
        if self.ckpt_path.exists():
            self._resume()
        else:
            inter.start(algo)
        if spec.tensorboard:
            from harness.tensorboard import TensorBoardRun

            for r, d in zip(self.results, self.diagnostics):
                tb = TensorBoardRun(r.dir, self.step if self.status == "resumed" else None)
                closers.append(tb)
                r.mirror_to(tb.tagged("eval"))
                d.mirror_to(tb.tagged("train"))

    def _resume(self) -> None:
        spec = self.spec
        ck = load_checkpoint(self.ckpt_path, spec.device)
        self.step, self.wall, self.last_success = ck["step"], ck["wall_s"], ck["last_success"]
        self.algo.load_state_dict(ck["algo"])
        self.inter.load_state_dict(ck["interaction"])
        if spec.keep_every and self.step % spec.keep_every == 0:  # killed between the checkpoint and keeping it
            _keep(self.ckpt_path, self.step)
        for r in self.results + self.diagnostics:
            r.resume(self.step)
        self.status = "resumed"
        if self.on_progress:
            self.on_progress(Progress(self.step, spec.steps, 0.0, math.inf, list(self.last_success), resumed=True))

    def checkpoint(self) -> None:
        state = {"step": self.step, "wall_s": self.wall, "last_success": self.last_success, "device": self.spec.device}
        _atomic_torch_save({**state, "algo": self.algo.state_dict(), "interaction": self.inter.state_dict()},
                           self.ckpt_path)
        if self.spec.keep_every and self.step % self.spec.keep_every == 0:
            _keep(self.ckpt_path, self.step)

    def report(self, rate: float, state: str) -> None:
        spec = self.spec
        eta = (spec.steps - self.step) / rate if rate > 0 else math.inf
        for d, succ in zip(self.dirs, self.last_success):
            write_status(d, state=state, step=self.step, total=spec.steps, steps_per_s=rate, eta_s=eta,
                         last_success=succ)
        if self.on_progress:
            self.on_progress(Progress(self.step, spec.steps, rate, eta, list(self.last_success)))

    def log_eval(self, rate: float) -> None:
        """Deployed evaluation of every member; its row with the continuing metrics; the diagnostics rows flushed."""
        succ, ret = evaluate(self.algo, self.eval_envs, self.spec.seeds, self.step, self.spec.eval_episodes)
        self.last_success = succ.tolist()
        n_inter = self.inter.interventions()
        for i, r in enumerate(self.results):
            r.append(self.step, {
                "deployed_success": succ[i], "deployed_return": ret[i], "continuing_reward": self.inter.cum_reward[i],
                "interventions": n_inter[i], "steps_per_s": rate, "wall_s": self.wall,
            })
        for d in self.diagnostics:
            d.flush()
        self.report(rate, self.status)

    def log_train(self) -> None:
        """Algorithm.metrics() (means since the last call), finite values only, written with the next evaluation."""
        m = self.algo.metrics()
        for i, d in enumerate(self.diagnostics):
            d.append(self.step, {k: float(v[i]) for k, v in m.items() if np.isfinite(v[i])}, flush=False)

    def run(self, should_stop: Callable[[], bool] | None) -> list[RunResults]:
        spec = self.spec
        self.report(0.0, self.status)  # before the first evaluation (seconds to minutes): a stopped run says so
        if self.step == 0 and not self.results[0].rows:
            self.log_eval(0.0)
        rate, t_mark, s_mark = 0.0, time.perf_counter(), self.step
        wall0, t_start, t_last_report = self.wall, t_mark, t_mark
        while self.step < spec.steps:
            self.inter.step(self.algo, self.step + 1)
            self.step += 1
            if self.log_due(self.step):
                self.log_train()
            if self.eval_due(self.step):
                now = time.perf_counter()
                rate = (self.step - s_mark) / max(now - t_mark, 1e-9)  # training steps/s, evaluation excluded
                self.wall = wall0 + now - t_start
                self.log_eval(rate)
                if self.checkpoint_due(self.step):
                    self.checkpoint()
                t_mark, s_mark = time.perf_counter(), self.step
                if should_stop and should_stop():
                    return self.results
            elif self.step % 1000 == 0 and time.perf_counter() - t_last_report > 10:
                t_last_report = time.perf_counter()  # status.json too: `harness status` and the dashboard stay live
                self.report((self.step - s_mark) / max(t_last_report - t_mark, 1e-9), self.status)
        for d, succ in zip(self.dirs, self.last_success):  # a checkpoint past the budget (steps= lowered): its step
            write_status(d, state="done", step=self.step, total=max(spec.steps, self.step), steps_per_s=rate, eta_s=0.0,
                         last_success=succ)
        return self.results
