"""The algorithm registry: name -> Algorithm class. An explicit dict (no import side effects).

Names match the method names of the published curves (``shared/earl/reference``).
"""

from __future__ import annotations

from algorithms.api import Algorithm
from algorithms.medal import MEDAL
from algorithms.risc import RISC, RISCNoTAB
from algorithms.vaprl import VaPRL

ALGORITHMS: dict[str, type[Algorithm]] = {
    "medal": MEDAL,
    "vaprl": VaPRL,
    "risc": RISC,
    "risc_no_tab": RISCNoTAB,
}

#: methods of the paper and of RISC that suites may name before they are implemented
PLANNED: tuple[str, ...] = (
    "naive", "oracle", "fbrl", "r3l", "medal_logc", "fbrl_vice", "bc", "gail_naive", "gail_oracle",
)
