"""Names, order and colours of envs and methods, shared by ``app.py``, ``harness report`` and ``harness.tables``.

The env order and labels are the env registry's (``harness.envs.ENVS``, each env's ``EnvInfo.label``); a method's
label is its algorithm class's ``label`` (``harness.catalogue.algorithm_labels``, without importing torch), published
method names included
(:data:`PUBLISHED_ALIASES`, :data:`PUBLISHED_ONLY_LABELS`); a name outside both (a suite's variant) is its own label.
"""

from __future__ import annotations

from typing import Iterable

from harness.catalogue import algorithm_labels
from harness.envs import ENVS

#: the env registry's order and labels (each env's ``EnvInfo.label``); :func:`env_label` reads the registry itself
ENV_ORDER = tuple(ENVS)
ENV_LABELS = {name: e.label for name, e in ENVS.items()}
ALGO_ORDER = ("naive", "fbrl", "r3l", "vaprl", "medal", "oracle")
#: published method names that are a registered algorithm under another name
PUBLISHED_ALIASES = {"risc_no_timeout_bootstrap": "risc_no_tab"}  # the RISC paper's name of the same ablation
#: labels of the methods that only published curves hold (the registered ones' are their class's ``label``)
PUBLISHED_ONLY_LABELS = {"risc_no_switching": "RISC w/o switching"}

#: One fixed colour per method, shared by `harness report` and the dashboard: the 8 Okabe-Ito colours and 7 of
#: Paul Tol's "muted" ones (both chosen to stay apart under the common colour-vision deficiencies), 15 in all, so
#: no two registered methods (nor the published-only RISC ablations) share one.
METHOD_COLORS: dict[str, str] = {
    "naive": "#000000", "fbrl": "#E69F00", "r3l": "#56B4E9", "vaprl": "#009E73", "medal": "#D55E00",
    "oracle": "#0072B2", "medal_logc": "#CC79A7", "fbrl_vice": "#F0E442", "bc": "#882255", "gail_naive": "#117733",
    "gail_oracle": "#332288", "risc": "#AA4499", "risc_no_tab": "#DDCC77", "vaprl_risc": "#44AA99",
    "risc_no_switching": "#88CCEE", "risc_no_timeout_bootstrap": "#DDCC77",  # the published name of risc_no_tab
}
#: a method split by suite (``harness.analysis.separate_suites``): "<algo> · <suite>"
COHORT_SEP = " · "
#: for names outside the table (a suite's variants): a deterministic pick from these, by name
EXTRA_COLORS = ("#999933", "#CC6677", "#6699CC", "#997700", "#EE99AA", "#004488", "#994455", "#666666")




def method_color(name: str) -> str:
    """The fixed colour of method ``name`` (a registered algorithm, a published method, or a variant); a method split
    by suite gets a colour of its own per suite (by name), so two suites of one method never share one."""
    import zlib

    return METHOD_COLORS.get(name) or EXTRA_COLORS[zlib.crc32(name.encode()) % len(EXTRA_COLORS)]


def method_colors(names: Iterable[str]) -> dict[str, str]:
    """The colours of the methods shown together: each registered or published method its fixed colour; the others
    (variants, suites split apart) their :func:`method_color` unless another name of the same figure holds it, then
    the next free one of :data:`EXTRA_COLORS`, so up to 8 such names in one figure never share a colour."""
    names = list(dict.fromkeys(names))
    out = {n: METHOD_COLORS[n] for n in names if n in METHOD_COLORS}
    taken: set[str] = set()
    for n in sorted(n for n in names if n not in METHOD_COLORS):
        i = EXTRA_COLORS.index(method_color(n))
        free = [EXTRA_COLORS[(i + k) % len(EXTRA_COLORS)] for k in range(len(EXTRA_COLORS))]
        out[n] = next((c for c in free if c not in taken), free[0])
        taken.add(out[n])
    return {n: out[n] for n in names}


#: ablation groups shown by the dashboard when their algorithms have results
ABLATIONS: dict[str, tuple[str, ...]] = {
    "Imitation (BC / GAIL vs MEDAL)": ("bc", "gail_naive", "gail_oracle", "medal"),
    "State distribution (MEDAL vs FBRL + VICE)": ("medal", "fbrl_vice"),
    "Reward form (MEDAL vs log C)": ("medal", "medal_logc"),
}


def env_label(env: str) -> str:
    """The display label of ``env``: its ``EnvInfo.label`` (the name itself for an env outside the registry)."""
    return ENVS[env].label if env in ENVS else env


def algo_label(algo: str) -> str:
    """The display label of a method: its algorithm class's ``label`` (published names too), else the name itself
    (a suite's variants)."""
    if COHORT_SEP in algo:  # a method split by suite: "MEDAL · reproduction"
        base, suite = algo.split(COHORT_SEP, 1)
        return f"{algo_label(base)}{COHORT_SEP}{suite}"
    label = algorithm_labels().get(PUBLISHED_ALIASES.get(algo, algo))
    return label or PUBLISHED_ONLY_LABELS.get(algo, algo)


#: every known method's label (a view of the registry, as imported)
ALGO_LABELS = {a: algo_label(a) for a in (*algorithm_labels(), *PUBLISHED_ALIASES, *PUBLISHED_ONLY_LABELS)}


def order_envs(envs: Iterable[str]) -> list[str]:
    envs = list(dict.fromkeys(envs))
    return [e for e in ENV_ORDER if e in envs] + sorted(e for e in envs if e not in ENV_ORDER)


def order_algos(algos: Iterable[str]) -> list[str]:
    """Table 1's methods first in the paper's order, then the rest by name; a method split by suite sits with its
    method (``medal``, ``medal · reproduction``, ``medal · smoke``)."""
    algos = list(dict.fromkeys(algos))

    def key(a: str) -> tuple:
        base = a.split(COHORT_SEP, 1)[0]
        return (ALGO_ORDER.index(base) if base in ALGO_ORDER else len(ALGO_ORDER), base, a)

    return sorted(algos, key=key)
