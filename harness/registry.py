"""The algorithm registry: name -> Algorithm class. An explicit dict (no import side effects).

Names match the method names of the published curves (``shared/earl/reference``).
"""

from __future__ import annotations

from algorithms.api import Algorithm
from algorithms.bc import BC
from algorithms.fbrl import FBRL
from algorithms.fbrl_vice import FBRLVICE
from algorithms.gail import GAILNaive, GAILOracle
from algorithms.medal import MEDAL
from algorithms.medal_logc import MEDALLogC
from algorithms.naive import Naive
from algorithms.oracle import Oracle
from algorithms.r3l import R3L
from algorithms.risc import RISC, RISCNoTAB
from algorithms.vaprl import VaPRL, VaPRLRISC

ALGORITHMS: dict[str, type[Algorithm]] = {
    "naive": Naive,
    "oracle": Oracle,
    "fbrl": FBRL,
    "r3l": R3L,
    "medal": MEDAL,
    "medal_logc": MEDALLogC,
    "fbrl_vice": FBRLVICE,
    "bc": BC,
    "gail_naive": GAILNaive,
    "gail_oracle": GAILOracle,
    "vaprl": VaPRL,
    "vaprl_risc": VaPRLRISC,
    "risc": RISC,
    "risc_no_tab": RISCNoTAB,
}
#: the registry as its source builds it: what a spawned worker process (or a Ray task) imports. An entry added or
#: replaced at run time (a notebook, a script) lives in this process only (``harness.planning.runtime_entries``).
BUILT_IN: dict[str, type[Algorithm]] = dict(ALGORITHMS)
