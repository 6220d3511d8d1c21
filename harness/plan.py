"""What ``harness run`` will do, as data: run groups (:class:`RunSpec`) and the :class:`Plan` that holds them.

:func:`harness.planning.build_plan` makes a plan from a :class:`harness.request.RunRequest`; :mod:`harness.backends`
executes its groups; :func:`harness.protocol.train` runs one group.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.request import RUN_KEYS
from harness.results import checkpoint_path, run_dir


@dataclass(frozen=True)
class RunSpec:
    """One run group: the seeds one process trains in lockstep, and everything that determines their results.

    :func:`harness.planning.build_plan` makes them; the backends, tuning and the protocol read them."""

    suite: str
    env: str
    algo: str  # the method's name in results (a suite cell's variant name, else the algorithm)
    seeds: tuple[int, ...]
    steps: int
    eval_every: int = RUN_KEYS["eval_every"].default
    eval_episodes: int = RUN_KEYS["eval_episodes"].default
    checkpoint_every: int = RUN_KEYS["checkpoint_every"].default
    keep_every: int = RUN_KEYS["keep_every"].default  # > 0: checkpoints at multiples of it are also kept
    log_every: int = RUN_KEYS["log_every"].default  # training diagnostics into train.parquet; divides eval_every
    device: str = RUN_KEYS["device"].default
    results: str = RUN_KEYS["results"].default
    algo_class: str = ""  # the registry key of the algorithm ("" = algo)
    config: dict[str, Any] = field(default_factory=dict)  # the resolved algorithm config, plain values
    config_hash: str = ""
    demo_source: str = ""
    git_sha: str = "unknown"
    study: str | None = None  # harness tune: the study and trial the run belongs to
    trial: int | None = None
    env_workers: int = 0  # > 1: the member envs stepped in that many worker processes (harness.env_pool)
    tensorboard: bool = False  # logger=tensorboard: the rows also as TensorBoard events (harness.tensorboard)
    update: str = RUN_KEYS["update"].default  # SAC updates: one of algorithms.core.sac.UPDATES

    def __post_init__(self) -> None:
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        if not self.algo_class:
            object.__setattr__(self, "algo_class", self.algo)

    @property
    def label(self) -> str:
        """How progress lines and errors name the group: ``env/algo seeds=0,1``."""
        return f"{self.env}/{self.algo} seeds={','.join(map(str, self.seeds))}"

    @property
    def meta(self) -> dict[str, Any]:
        """The metadata columns of every results row."""
        return {"config_hash": self.config_hash, "git_sha": self.git_sha, "demo_source": self.demo_source,
                "device": self.device, "study": self.study, "trial": self.trial}

    def seed_phase_note(self) -> str | None:
        """The warning for a budget within the method's seed phase (random actions before the first update): such a
        run never updates its networks. None when the budget goes past it."""
        seed_steps = int(self.config.get("seed_steps", 0))
        if self.steps > seed_steps:
            return None
        return (f"{self.env}/{self.algo}: steps={self.steps:,} is within seed_steps={seed_steps:,} (random actions "
                f"before the first update): these runs never update their networks; raise steps= or lower "
                f"{self.algo_class}.seed_steps=")

    def member_dirs(self) -> list[Path]:
        return [run_dir(Path(self.results), self.suite, self.env, self.algo, s) for s in self.seeds]

    def checkpoint_path(self) -> Path:
        return checkpoint_path(self.results, self.suite, self.env, self.algo, self.seeds)


@dataclass(frozen=True)
class Plan:
    """What ``harness run`` will do: its run groups (one process each) and where they run."""

    suite: str
    groups: list[RunSpec] = field(default_factory=list)
    workers: int = 1
    backend: str = "local"  # local (a process pool) or ray (harness.backends)
    ray_address: str | None = None  # a Ray cluster to join; None: start a local one
    calibrate: bool | str = True  # --dry-run measures groups not measured yet; "refresh": all (harness.calibration)
    machine: str = ""  # the node the plan was packed for (harness.packing.Machine.describe)
    packing: tuple[str, ...] = ()  # how members, workers and env_workers were chosen (harness.packing)
    per_device: int = 1  # processes at once per device (Ray reserves 1/per_device of a GPU per group)
    left_out: tuple[str, ...] = ()  # "algo on env (why)" for what a runnable_only suite leaves out
