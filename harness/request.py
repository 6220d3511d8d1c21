"""The words of ``harness run``, parsed once: the key table (:data:`RUN_KEYS`, printed by ``harness run --help``), the
limits of what a run can hold, and :class:`RunRequest`, what one command asks for.

Overrides (``key=value``): ``suite``, ``algo``/``algos``, ``env``/``envs``, ``seeds`` (a count or a
comma list), ``steps``, ``eval_every``, ``eval_episodes``, ``checkpoint_every``, ``members`` (E, seeds
trained in lockstep by one process), ``workers`` (parallel processes, default: cores), ``device``,
``results`` (directory), ``backend`` (``local``: a process pool, the default; ``ray``: one Ray task per
group, see ``harness/backends.py``), ``ray_address`` (``auto`` or ``HOST:PORT``; default: start a local
Ray instance), and algorithm config as ``<algo>.<key>=value`` or ``all.<key>=value``.
:mod:`harness.planning` turns a request into a plan; :mod:`harness.runner` runs it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from algorithms.update_modes import UPDATES
from harness.catalogue import algorithm_name
from harness.envs import ENVS, env_name
from harness.words import ConfigError, boolean, did_you_mean, key_word, names, parse_words
from harness.words import integer as _int

#: what a run can hold: one replay row per step (capacity <= 1e9), seeds as 31-bit integers
MAX_STEPS, MAX_SEEDS, MAX_SEED, MAX_MEMBERS, MAX_EPISODES, MAX_WORKERS = 10**9, 1000, 2**31 - 1, 1024, 10_000, 1024


@dataclass(frozen=True)
class Key:
    """One ``key=value`` word, declared once: its meaning, its default (what planning and :class:`RunSpec` use when
    neither the command nor the suite gives one; None where it is computed or has none), the bounds of an integer
    key, and ``shown``, how ``--help`` states a default that is computed."""

    help: str
    default: Any = None
    lo: int | None = None  # integer keys: the accepted range
    hi: int | None = None
    shown: str | None = None

    @property
    def default_text(self) -> str:
        return self.shown if self.shown is not None else "-" if self.default is None else str(self.default)

    def parse(self, name: str, value: Any) -> int:
        """An integer key's value, checked against its bounds (one line naming the key otherwise)."""
        return _int(name, value, self.lo if self.lo is not None else 0, self.hi)


#: every key=value word of ``harness run``; ``harness run --help`` prints this table, planning reads the defaults
RUN_KEYS: dict[str, Key] = {
    "suite": Key("a suite in suites/ or a path to a suite YAML (its name names the results directory)"),
    "algo": Key("algorithm(s), comma-separated, any case (ad hoc; with a suite of cells: selects cells)"),
    "algos": Key("same as algo"),
    "env": Key(f"env(s), comma-separated: {', '.join(ENVS)} (any case, or the gymnasium id: earl/SawyerDoor-v0)"),
    "envs": Key("same as env"),
    "seeds": Key("a count (seeds 0..n-1) or a list of distinct seeds: 0,3,7 or 0-4 (one seed: 7, or [7])", 1),
    "seed": Key("one seed: seed=7 is seeds=7,"),
    "steps": Key("training steps per run (300000, 3e5, 300k and 1.5M all work, here and in every step count)", None,
                 1, MAX_STEPS,
                 shown="/".join(f"{e.default_steps / 1e6:g}M" for e in ENVS.values()) + " per env"),
    "eval_every": Key("steps between deployed-policy evaluations", 10_000, 1, MAX_STEPS),
    "eval_episodes": Key("episodes per evaluation", 10, 1, MAX_EPISODES),
    "checkpoint_every": Key("steps between checkpoints (a multiple of eval_every)", 50_000, 1, MAX_STEPS,
                            shown="the first multiple of eval_every from 50000 on"),
    "keep_every": Key("also keep the checkpoints at multiples of it (checkpoint-<step>.pt; each a full checkpoint)", 0,
                      0, MAX_STEPS),
    "log_every": Key("steps between training-diagnostics rows in train.parquet (divides eval_every)", 1000, 1,
                     MAX_STEPS, shown="the largest divisor of eval_every up to 1000"),
    "members": Key("seeds trained in lockstep by one process", None, 1, MAX_MEMBERS,
                   shown="1 (cells: the cell's seeds; cuda: a cell's seeds, <= 128)"),
    "workers": Key("processes running groups in parallel", None, 1, MAX_WORKERS,
                   shown="cores (cuda: what the GPUs' memory and the cores hold)"),
    "device": Key("torch device, e.g. cpu or cuda:0", "cpu"),
    "results": Key("results directory", "results"),
    "backend": Key("local (a process pool) or ray (one Ray task per group)", "local"),
    "ray_address": Key("Ray cluster to join (auto or HOST:PORT), with backend=ray", shown="start one"),
    "env_workers": Key("worker processes stepping the member envs of each group (0: in the group's process; for many "
                       "seeds per process, e.g. on a GPU)", None, 0, MAX_WORKERS, shown="0 (cuda: spare cores)"),
    "update": Key("SAC updates: default (per-member kernels; E seeds per process equal E single-seed runs to float rounding), "
                  "static (one fixed kernel sequence, equal within rounding), compiled (static + torch.compile; CUDA "
                  "graphs on a GPU), autograd (the same losses through torch.autograd); a run resumes bit for bit only "
                  "in the mode it ran with", "default",
                  shown="default; a run resuming from its checkpoint: the mode it last ran with"),
    "logger": Key("parquet, or tensorboard: the same rows also as TensorBoard events in each run's tensorboard/ "
                  "directory (pip install tensorboard)", "parquet"),
    "calibrate": Key("with --dry-run: measure the speed of each kind of group not measured yet on this machine "
                     "(seconds each, cached with the date and the machine's load) for the time estimate; refresh: "
                     "measure every group again; false: use only what is cached", "true"),
}
BACKENDS = ("local", "ray")
LOGGERS = ("parquet", "tensorboard")
DEFAULT_STEPS = {name: e.default_steps for name, e in ENVS.items()}  # each env's EnvInfo.default_steps


SEEDS_FORMS = "a count (seeds=3: seeds 0, 1, 2) or a list (seeds=0,4 or seeds=0-4; one seed: seeds=7, or seed=7)"


def parse_seeds(v: Any) -> list[int]:
    """``seeds=``: a count n (seeds 0..n-1) or a list of distinct seeds: a YAML list, or on the command line
    ``0,3,7``, ``[0,3,7]``, ``0 3 7``, ranges ``0-4`` (``0-2,7``), and for one seed ``7,`` or ``[7]``."""
    raw = v
    if isinstance(v, str) and re.search(r"[,\[\s-]", v.strip()):
        v = re.split(r"\s*,\s*|\s+", v.strip().removeprefix("[").removesuffix("]").strip())
        if not v[-1]:  # "7," is the list [7], "[]" the empty list
            v = v[:-1]
        v = [x for part in v for x in _seed_range(part, raw)]
    if isinstance(v, (list, tuple)):
        if not v:
            raise ConfigError("seeds is an empty list")
        seeds = [_seed(x, raw) for x in v]
        if len(set(seeds)) != len(seeds):
            raise ConfigError(f"seeds must be distinct, got {raw!r}")
        if len(seeds) > MAX_SEEDS:
            raise ConfigError(f"at most {MAX_SEEDS} seeds per run command, got {len(seeds)}")
        return seeds
    if str(v).strip() in ("0", "0.0"):
        raise ConfigError("seeds=0 asks for no seeds (seeds=N is a count); for seed 0 alone write seed=0 or seeds=[0]")
    try:
        return list(range(_int("seeds", v, 1, MAX_SEEDS)))
    except ConfigError as e:
        if "integer" not in str(e):
            raise
        raise ConfigError(f"seeds must be {SEEDS_FORMS}, got {raw!r}") from None


def _seed(x: Any, raw: Any) -> int:
    try:
        return _int("seeds", x, 0, MAX_SEED)
    except ConfigError as e:
        if "integer" not in str(e):
            raise
        raise ConfigError(f"seeds must be {SEEDS_FORMS}, got {raw!r}") from None


def _seed_range(part: str, raw: Any) -> list[Any]:
    """``3-5`` -> [3, 4, 5]; any other part as it is."""
    m = re.fullmatch(r"([0-9]+)-([0-9]+)", part)
    if not m:
        return [part]
    lo, hi = int(m[1]), int(m[2])
    if hi < lo or hi - lo >= MAX_SEEDS:
        raise ConfigError(f"seeds range {part!r} in {raw!r} must go up, to at most {MAX_SEEDS} seeds")
    return list(range(lo, hi + 1))


def check_device(v: str, local: bool = True) -> str:
    """A torch device name; with ``local``, CUDA must be available here (a Ray cluster's GPUs need not be visible
    from the driver)."""
    if v == "cpu":  # the common case, answered without loading torch
        return v
    import torch  # here, not at the top: the command line loads this module for --help and answers at once

    try:
        dev = torch.device(v)
    except RuntimeError:
        raise ConfigError(f"device must be a torch device such as cpu or cuda:0, got {v!r}") from None
    if local and dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {v!r} requested but CUDA is not available on this machine")
    return v


@dataclass(frozen=True)
class RunRequest:
    """What a ``harness run`` command asks for, parsed once from its words (:meth:`from_words`), or built directly
    (``harness tune`` makes one per trial from the sampled parameters). ``None``: the suite's value (or the default).
    ``config`` holds algorithm settings by scope (``{"all" | algo: {key: value}}``); ``study``/``trial`` mark a tuning
    trial (its runs go under the suite ``tune_<study>`` and carry both in their metadata)."""

    suite: str | None = None
    algos: tuple[str, ...] = ()
    envs: tuple[str, ...] = ()
    seeds: tuple[int, ...] | None = None
    steps: int | None = None
    eval_every: int | None = None
    eval_episodes: int | None = None
    checkpoint_every: int | None = None
    keep_every: int | None = None
    log_every: int | None = None
    members: int | None = None
    workers: int | None = None
    device: str = RUN_KEYS["device"].default
    results: str = RUN_KEYS["results"].default
    backend: str = RUN_KEYS["backend"].default
    ray_address: str | None = None
    calibrate: bool | str = True  # True, False or "refresh"
    logger: str = RUN_KEYS["logger"].default
    env_workers: int | None = None
    update: str | None = None  # None: the mode the runs last ran with (resumed_update), else default
    config: dict[str, dict[str, Any]] = field(default_factory=dict)
    study: str | None = None
    trial: int | None = None

    @classmethod
    def from_words(cls, words: list[str]) -> "RunRequest":
        """Parse and check the words of ``harness run`` (one line naming the first problem)."""
        from harness.catalogue import algorithm_names, check_unscoped_settings  # before torch loads

        ALGORITHMS = algorithm_names()
        check_unscoped_settings([w for w in words if "=" in w], RUN_KEYS)
        for w in words:  # name the unknown algorithm of an override, not just its scope
            if "=" not in w:
                continue  # parse_words names it
            k = key_word(w.split("=", 1)[0])  # MEDAL.lr, risc-no-tab.lr: as parse_words reads them
            scope = k.split(".", 1)[0] if "." in k else None
            if scope is not None and scope != "all" and scope not in ALGORITHMS:
                raise ConfigError(f"unknown algorithm {scope!r} in override {w!r}{did_you_mean(scope, ALGORITHMS)}; "
                                  f"known: {', '.join(ALGORITHMS)}")
        ov, config = parse_words(words, RUN_KEYS, scope=lambda s: s == "all" or s in ALGORITHMS)
        for a, b in (("algo", "algos"), ("env", "envs"), ("seed", "seeds")):
            if a in ov and b in ov:
                raise ConfigError(f"give {a}= or {b}=, not both")
        def given(key: str) -> Any:
            return ov.get(key, RUN_KEYS[key].default)

        backend = given("backend")
        if backend not in BACKENDS:
            raise ConfigError(f"unknown backend {backend!r}; known backends: {', '.join(BACKENDS)}")
        if "ray_address" in ov and backend != "ray":
            raise ConfigError("ray_address is only used with backend=ray")
        device = check_device(given("device"), local=not (backend == "ray" and ov.get("ray_address")))

        update = ov.get("update")
        if update is not None and update not in UPDATES:
            raise ConfigError(f"unknown update {update!r}; known: {', '.join(UPDATES)}")
        logger = given("logger")
        if logger not in LOGGERS:
            raise ConfigError(f"unknown logger {logger!r}; known: {', '.join(LOGGERS)}")
        if logger == "tensorboard":
            from harness.tensorboard import check_available

            check_available()

        def opt(key: str) -> int | None:
            return RUN_KEYS[key].parse(key, ov[key]) if key in ov else None

        for key in ("results", "suite", "device", "backend"):
            if key in ov and not str(ov[key]).strip():
                raise ConfigError(f"{key}= is empty: give a value (or leave {key} out for its default)")
        return cls(
            suite=ov.get("suite"), algos=tuple(names("algo", [algorithm_name(a) for a in names(
                "algo", ov.get("algos") or ov.get("algo") or [])])),
            envs=tuple(names("env", [env_name(e) for e in names("env", ov.get("envs") or ov.get("env") or [])])),
            seeds=tuple(parse_seeds(ov["seeds"] if "seeds" in ov else [str(ov["seed"]).strip("[] ")]))
            if {"seed", "seeds"} & set(ov)
            else None, steps=opt("steps"),
            eval_every=opt("eval_every"), eval_episodes=opt("eval_episodes"), checkpoint_every=opt("checkpoint_every"),
            keep_every=opt("keep_every"), log_every=opt("log_every"), members=opt("members"), workers=opt("workers"),
            device=device, results=given("results"), backend=backend, ray_address=ov.get("ray_address"),
            calibrate="refresh" if given("calibrate") == "refresh" else boolean("calibrate", given("calibrate")),
            logger=logger,
            config=config, env_workers=opt("env_workers"), update=update,
        )
