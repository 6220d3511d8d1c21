"""FBRL + VICE: MEDAL with discriminator positives from rho0 (docs/algorithms.md section 11, [MP] section 5.3).

The backward policy then minimises JS(rho_b || rho0): a practical FBRL whose "reach rho0" reward is learned from
examples. Everything else (reward -log(1 - C(s')), mixup, batch 800, one step every 10, 128-unit discriminator,
buffers, switching) is MEDAL's.

DEFAULT (NOT FOUND which rho0 samples were used): positives = all pairs [s0, g] of EARL's initial states and task goals
(tabletop 1 x 4, door 1 x 1, peg 15 x 1; :func:`algorithms.medal.rho0_states`), sampled with replacement. The optional
extra positives (first observations of the forward demos) are not added.
"""

from __future__ import annotations

from dataclasses import dataclass

from algorithms.medal import MEDAL, MEDALConfig


@dataclass
class FBRLVICEConfig(MEDALConfig):
    positives: str = "rho0"


class FBRLVICE(MEDAL):
    """MEDAL whose discriminator separates rho0 states (positives) from backward states."""

    label = "FBRL + VICE"
    Config = FBRLVICEConfig
    needs_demos = False  # positives from rho0; the demos only seed the buffers
