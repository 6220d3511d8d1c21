"""What ``harness list`` (and the first checks of a command's words) know about the algorithms, read from the source: the registry's names
(``harness/registry.py``'s ``ALGORITHMS``) and the first line of each class's docstring, found with :mod:`ast` without
importing the algorithms (and torch), so the answer comes at once. ``tests/test_cli_run.py`` checks it against the
imported registry."""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def algorithm_names() -> tuple[str, ...]:
    """The registry's algorithm names, in its order (for checking a command's words before anything heavy loads): the
    live ``ALGORITHMS`` where it is imported already (it may have gained an algorithm at run time: a notebook, a
    test), else the names in its source."""
    import sys

    registry = sys.modules.get("harness.registry")
    return tuple(registry.ALGORITHMS) if registry is not None else tuple(algorithm_summaries())


def algorithm_name(word: str) -> str:
    """The registry name of the algorithm ``word`` names in any case or with dashes (``MEDAL`` -> ``medal``,
    ``risc-no-tab`` -> ``risc_no_tab``); any other word unchanged (the check that follows names it as unknown)."""
    from harness.words import name_of

    return name_of(word, algorithm_names(), parts=False)


def algorithm_summaries() -> dict[str, str]:
    """Registry name -> the first line of its class's docstring, in the registry's order."""
    return {name: doc for name, (doc, _) in _summaries()}


def algorithm_labels() -> dict[str, str]:
    """Registry name -> its class's display ``label``: the live registry's where it is imported already, else read
    from the source (every registered class sets its own), so reports and the dashboard name methods without torch."""
    import sys

    registry = sys.modules.get("harness.registry")
    if registry is not None:
        return {name: cls.label for name, cls in registry.ALGORITHMS.items()}
    return {name: label for name, (_, label) in _summaries()}


@lru_cache(maxsize=1)
def _summaries() -> tuple[tuple[str, tuple[str, str]], ...]:
    """(name, (docstring's first line, label)) per registered class, parsed once per process: a suite of cells checks
    its names once per cell."""
    tree = ast.parse((ROOT / "harness" / "registry.py").read_text())
    module_of = {a.asname or a.name: node.module for node in tree.body if isinstance(node, ast.ImportFrom)
                 for a in node.names}
    table = next(node.value for node in tree.body if isinstance(node, ast.AnnAssign)
                 and isinstance(node.target, ast.Name) and node.target.id == "ALGORITHMS")
    out: dict[str, tuple[str, str]] = {}
    for key, value in zip(table.keys, table.values):
        cls = value.id
        source = ROOT / Path(*module_of[cls].split(".")).with_suffix(".py")
        node = next(n for n in ast.parse(source.read_text()).body if isinstance(n, ast.ClassDef) and n.name == cls)
        label = next((n.value.value for n in node.body if isinstance(n, ast.Assign) and isinstance(n.value, ast.Constant)
                      and any(isinstance(t, ast.Name) and t.id == "label" for t in n.targets)), "")
        out[key.value] = ((ast.get_docstring(node) or "").strip().splitlines()[0], label)
    return tuple(out.items())


@lru_cache(maxsize=1)
def algorithm_setting_names() -> frozenset[str]:
    """Every key an algorithm's config declares (the fields of the ``...Config`` and ``...Fields`` dataclasses under
    ``algorithms/``), read from the source: a command-line word that names one without its ``<algo>.`` scope is told
    how to give it, before torch loads."""
    names: set[str] = set()
    for source in sorted((ROOT / "algorithms").rglob("*.py")):
        for node in ast.walk(ast.parse(source.read_text())):
            if isinstance(node, ast.ClassDef) and node.name.endswith(("Config", "Fields")):
                names |= {n.target.id for n in node.body if isinstance(n, ast.AnnAssign)
                          and isinstance(n.target, ast.Name) and "ClassVar" not in ast.unparse(n.annotation)}
    return frozenset(names)


def check_unscoped_settings(words: list[str], command_keys) -> None:
    """Name the form of an algorithm setting given without its scope (``seed_steps=5``, for ``harness run`` or
    ``tune``), rather than calling it an unknown key: one :class:`~harness.words.ConfigError` line."""
    from harness.words import ConfigError, key_word

    for w in words:
        k, _, v = w.partition("=")
        k = key_word(k)
        if "." not in k and k not in command_keys and k in algorithm_setting_names():
            raise ConfigError(f"{k} is an algorithm setting: give it as all.{k}={v} (every algorithm that has it) "
                              f"or <algo>.{k}={v} (one algorithm)")
