"""The words of every ``harness`` command: ``key=value`` parsing and value coercion, in one place.

:func:`parse_words` splits words into plain keys and scoped ones (``<scope>.<key>=value``, e.g. an algorithm
setting), refusing a word without ``=``, an empty or unknown key, and a key given twice. :func:`integer`,
:func:`number` and :func:`boolean` coerce a value (from the command line or a YAML file) with bounds; every error is a
:class:`ConfigError` of one line naming the key, the value and what is allowed.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Collection, Iterable
from typing import Any

from algorithms.api import parse_int as _parse_int


class ConfigError(ValueError):
    """Bad input (a word, a suite file, a setting); reported as one line, exit code 2."""


UsageError = ConfigError  # the name the command-line code uses


#: keys whose value is a path: a leading ``~`` means the home directory, as the shell would expand it
PATH_KEYS = frozenset({"results", "to", "out", "doc", "dest", "record", "search", "suite", "storage"})


def parse_words(words: list[str], allowed: Collection[str] | None = None, *,
                scope: Callable[[str], bool] | None = None) -> tuple[dict[str, str], dict[str, dict[str, str]]]:
    """(plain ``{key: value}``, scoped ``{scope: {key: value}}``) from ``key=value`` words. ``allowed``: the plain
    keys (None: any); ``scope``: accepts the part before a dot (a word with a dot is plain when it is None)."""
    plain: dict[str, str] = {}
    scoped: dict[str, dict[str, str]] = {}
    seen: set[str] = set()
    for w in words:
        if "=" not in w:
            raise ConfigError(f"expected key=value, got {w!r}")
        k, v = w.split("=", 1)
        k = key_word(k)
        if not k:
            raise ConfigError(f"empty key in {w!r}")
        if k in seen:
            raise ConfigError(f"{k} is given twice ({w!r}); give each key once")
        seen.add(k)
        if k in PATH_KEYS:
            v = os.path.expanduser(v)  # results=~/runs: a quoted word, zsh, a notebook or run_cli([...]) keeps the ~
        if scope is not None and "." in k:
            s, key = k.split(".", 1)
            if not scope(s):
                raise ConfigError(f"unknown scope {s!r} in {w!r}")
            scoped.setdefault(s, {})[key] = v
        elif allowed is not None and k not in allowed:
            raise ConfigError(f"unknown key {k!r}{did_you_mean(k, allowed)}; known keys: {', '.join(sorted(allowed))}"
                              + (" or <algo>.<key>" if scope is not None else ""))
        else:
            plain[k] = v
    return plain, scoped


def key_word(k: str) -> str:
    """A key as people type it, in the form the tables declare: any case, dashes for underscores (``eval-every``,
    ``--steps`` after :func:`harness.cli.flag_words`)."""
    return k.strip().lower().replace("-", "_")


def name_of(word: str, known: Iterable[str], aliases: dict[str, str] | None = None, parts: bool = True) -> str:
    """The name in ``known`` that ``word`` means: the name itself in any case, with dashes or spaces for its
    underscores, an alias (``aliases``: other spellings, e.g. gymnasium ids, in any case), or with ``parts`` a part
    of exactly one name (``door`` -> ``sawyer_door``); any other word unchanged (the check that follows names it as
    unknown)."""
    known = list(known)
    if word in known:
        return word
    w = word.strip().lower().replace("-", "_").replace(" ", "_")
    forms = {n.lower(): n for n in known} | {a.lower(): n for a, n in (aliases or {}).items()}
    if w in forms or word.strip().lower() in forms:
        return forms.get(w) or forms[word.strip().lower()]
    holders = [n for n in known if parts and w and w in n.lower().split("_")]
    return holders[0] if len(holders) == 1 else word


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """`` (did you mean X?)`` for the closest name in ``known``, or nothing when none is close."""
    import difflib

    close = difflib.get_close_matches(str(word).lower(), [str(k) for k in known], n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def integer(key: str, value: Any, minimum: int = 0, maximum: int | None = None) -> int:
    """An integer (``300000``, ``3e5``, ``300_000``) in [``minimum``, ``maximum``]."""
    try:
        n = _parse_int(key, value)
    except (ValueError, OverflowError) as e:
        raise ConfigError(str(e) if isinstance(e, ValueError) else f"{key} must be an integer, got {value!r}") from None
    shown = value if len(str(value)) <= 40 else f"{str(value)[:20]}... ({len(str(value))} characters)"
    if n < minimum:
        raise ConfigError(f"{key} must be >= {minimum}, got {shown}")
    if maximum is not None and n > maximum:
        raise ConfigError(f"{key} must be <= {maximum:,}, got {shown}")
    return n


def optional_integer(key: str, value: Any, default: int, minimum: int = 0, maximum: int | None = None) -> int:
    """:func:`integer`, or ``default`` when ``value`` is None (a key not given)."""
    return default if value is None else integer(key, value, minimum, maximum)


def number(key: str, value: Any, minimum: float | None = None, maximum: float | None = None) -> float:
    """A finite number in [``minimum``, ``maximum``]."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ConfigError(f"{key} must be a finite number, got {value!r}")
    if minimum is not None and x < minimum or maximum is not None and x > maximum:
        raise ConfigError(f"{key} must be in [{minimum}, {maximum}], got {value!r}")
    return x


def boolean(key: str, value: Any) -> bool:
    if isinstance(value, bool):
        return value
    v = str(value).lower()
    if v in ("true", "1", "yes", "on"):
        return True
    if v in ("false", "0", "no", "off"):
        return False
    raise ConfigError(f"{key} must be true or false, got {value!r}")


def names(key: str, value: Any) -> list[str]:
    """A comma list (or a YAML list) of names; a name given twice is an error."""
    out = [str(x) for x in value] if isinstance(value, (list, tuple)) else \
        [x.strip() for x in str(value).split(",") if x.strip()]
    twice = sorted({n for n in out if out.count(n) > 1})
    if twice:
        raise ConfigError(f"{key} lists {', '.join(twice)} more than once")
    return out
