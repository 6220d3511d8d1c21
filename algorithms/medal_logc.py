"""MEDAL reward ablation: r_b = log C(s') instead of -log(1 - C(s')) (docs/algorithms.md section 10, [MP] App. A).

Identical to :class:`algorithms.medal.MEDAL` in every other respect. DEFAULT (NOT FOUND): r_b = log(sigmoid(D(o')) +
1e-10), the same epsilon as MEDAL's, with the same x10 reward scale. log C <= 0: every backward step is a penalty.
"""

from __future__ import annotations

from dataclasses import dataclass

from algorithms.medal import MEDAL, MEDALConfig


@dataclass
class MEDALLogCConfig(MEDALConfig):
    reward_form: str = "logc"


class MEDALLogC(MEDAL):
    """MEDAL with r_b = log C(s')."""

    label = "MEDAL (log C reward)"
    Config = MEDALLogCConfig
