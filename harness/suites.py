"""Suites and algorithm configs as data (YAML under ``suites/``), resolved into run groups.

A suite file (``suites/<name>.yaml``)::

    description: ...
    algos: [naive, medal]
    envs: [tabletop_manipulation, sawyer_door]
    seeds: 5                       # count (seeds 0..4) or an explicit list
    steps: {tabletop_manipulation: 3000000, sawyer_door: 5000000}   # or one number
    eval_every: 10000
    eval_episodes: 10
    config:                        # algorithm config overrides: per algo, or `all`
      all: {seed_steps: 10000}
      medal: {switch_every: 300}

Algorithm config = the algorithm's ``Config`` dataclass defaults (the card's values, documented in
the algorithm module), then ``suites/algorithms/<algo>.yaml`` (per-env values, e.g. VaPRL's
curriculum threshold: ``{defaults: {...}, env: {sawyer_door: {...}}}``), then the suite's
``config``, then command-line ``<algo>.<key>=value`` / ``all.<key>=value`` overrides.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from harness.words import ConfigError, did_you_mean, name_of

SUITES_DIR = Path(__file__).resolve().parent.parent / "suites"
SUITE_KEYS = {"description", "algos", "envs", "seeds", "steps", "eval_every", "eval_episodes", "checkpoint_every",
              "keep_every", "log_every", "config", "members", "cells", "criterion", "runnable_only"}


def list_suites() -> list[str]:
    return sorted(p.stem for p in SUITES_DIR.glob("*.yaml"))


class StrictLoader(yaml.SafeLoader):
    """A safe YAML loader that refuses a mapping with a repeated key (YAML would silently keep the last)."""


def _strict_mapping(loader: StrictLoader, node: yaml.MappingNode) -> dict:
    loader.flatten_mapping(node)
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key {key!r} appears twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=True)


StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _strict_mapping)


def read_yaml_text(text: str, where: str) -> Any:
    """YAML from ``text`` (repeated keys are an error), errors as one line naming ``where`` and the position."""
    try:
        return yaml.load(text, Loader=StrictLoader)  # noqa: S506 - StrictLoader is a SafeLoader
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        pos = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ConfigError(f"malformed YAML in {where}{pos}: {problem}") from None


def _read_yaml(path: Path) -> Any:
    try:
        return read_yaml_text(path.read_text(), str(path))
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {path}: {e.strerror if isinstance(e, OSError) else 'not UTF-8 text'}") from None


def check_name(kind: str, name: str) -> str:
    """A name that becomes a directory under results: letters, digits, '_' and '-', not starting with '-'."""
    if not name or name[0] == "-" or not all(c.isascii() and (c.isalnum() or c in "_-") for c in name):
        raise ConfigError(f"{kind} name {name!r} must be letters, digits, '_' and '-' (it names a results directory)")
    return name


def load_suite(name_or_path: str) -> tuple[str, dict[str, Any]]:
    """(suite name, suite dict) from a name in ``suites/`` or a path to a YAML file; the name (the file's stem) must
    be a plain identifier, since it names the directory under results."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file() and p.parts[:-1] in ((), ("suites",)) and (SUITES_DIR / p.name).is_file():
            p = SUITES_DIR / p.name  # `table1.yaml` or `suites/table1.yaml` from another folder: the bundled file
        if not p.is_file():
            raise ConfigError(f"suite file not found: {p}")
        path, name = p, check_name("suite", p.stem)
    else:
        check_name("suite", name_or_path)
        name = name_of(name_or_path, list_suites(), parts=False)  # any case, dashes for underscores
        path = SUITES_DIR / f"{name}.yaml"
        if not path.exists():
            raise ConfigError(f"unknown suite {name_or_path!r}{did_you_mean(name_or_path, list_suites())}; known "
                              f"suites: {', '.join(list_suites())}")
    d = _read_yaml(path)
    if not isinstance(d, dict):
        raise ConfigError(f"suite file {path} must be a mapping of keys to values")
    unknown = set(d) - SUITE_KEYS
    if unknown:
        raise ConfigError(f"unknown key(s) {sorted(unknown)} in suite {path}; known: {sorted(SUITE_KEYS)}")
    cfg = d.get("config")
    if cfg is not None:
        if not isinstance(cfg, dict):
            raise ConfigError(f"suite {path}: 'config' must map algorithm names (or 'all') to settings")
        for scope, settings in cfg.items():
            if not isinstance(settings, dict):
                raise ConfigError(f"suite {path}: config for {scope!r} must be a mapping of keys to values, "
                                  f"got {settings!r}")
    if not isinstance(d.get("runnable_only", False), bool):
        raise ConfigError(f"suite {path}: runnable_only must be true or false (leave out the algorithm x env pairs "
                          f"that cannot run), got {d['runnable_only']!r}")
    if "cells" in d and {"algos", "envs", "steps"} & set(d):
        raise ConfigError(f"suite {path} has 'cells': algorithms, envs and budgets belong in its cells, "
                          f"not in {sorted({'algos', 'envs', 'steps'} & set(d))}")
    return name, d


def algo_env_config(algo: str, env: str) -> dict[str, Any]:
    """Values from ``suites/algorithms/<algo>.yaml`` for ``env`` (defaults, then env-specific)."""
    path = SUITES_DIR / "algorithms" / f"{algo}.yaml"
    if not path.exists():
        return {}
    d = _read_yaml(path) or {}
    if not isinstance(d, dict) or set(d) - {"defaults", "env"}:
        raise ConfigError(f"{path} must have only the keys 'defaults' and 'env'")
    return {**(d.get("defaults") or {}), **((d.get("env") or {}).get(env) or {})}


def resolve_algo_config(config_cls, algo: str, env: str, *layers: dict[str, Any]):
    """The algorithm's config for ``env``: dataclass defaults, the algorithm YAML, then ``layers``
    (each ``{"all": {...}, algo: {...}}``). ``all`` settings apply to the algorithms that have them
    (:func:`check_all_keys` rejects one that no algorithm has); ``<algo>`` settings must exist."""
    merged = algo_env_config(getattr(config_cls, "config_file", None) or algo, env)
    keys = config_cls.keys()
    for layer in layers:
        merged.update({k: v for k, v in ((layer or {}).get("all") or {}).items() if k in keys})
        merged.update((layer or {}).get(algo) or {})
    unknown = sorted(set(merged) - keys)
    if unknown:
        raise ConfigError(f"unknown config key(s) {unknown} for algorithm {algo!r}; known: {sorted(keys)}")
    try:
        return config_cls.from_dict(merged)
    except (ValueError, TypeError) as e:
        raise ConfigError(f"bad config value for algorithm {algo!r}: {e}") from None


def check_all_keys(config_classes: list, *layers: dict[str, Any]) -> None:
    """An ``all.<key>`` setting must belong to at least one of the selected algorithms."""
    known = set().union(*(c.keys() for c in config_classes)) if config_classes else set()
    for layer in layers:
        unknown = sorted(set((layer or {}).get("all") or {}) - known)
        if unknown:
            raise ConfigError(f"unknown config key(s) {unknown} in 'all': no selected algorithm has them")


def config_hash(obj: Any) -> str:
    blob = json.dumps(obj, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def as_plain(cfg) -> dict[str, Any]:
    return json.loads(json.dumps(asdict(cfg), default=list))
