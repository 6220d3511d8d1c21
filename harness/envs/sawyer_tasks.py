"""The EARL Sawyer door and peg tasks as the harness catalogues them: EARL's constants, their
:class:`EnvSpec` and :class:`EnvInfo` records.

The simulators are in :mod:`harness.envs.sawyer`, which imports Meta-World (over a second); this module
imports only numpy, so that the env registry (``harness.envs.ENVS``) stays cheap to import. The catalogue
entries name the classes and the scripted experts (:mod:`harness.envs.sawyer_experts`) by ``"module:name"``.
"""

from __future__ import annotations

import numpy as np

from harness.envs.base import EnvInfo, EnvSpec

# ------------------------------------------------------------------------------------------------
# EARL constants (envs/sawyer_door.py, envs/sawyer_peg.py, __init__.py)
# ------------------------------------------------------------------------------------------------

DOOR_INITIAL_STATES = np.array([[0.00591636, 0.39968333, 0.19493164, 1.0, 0.01007495, 0.47104556, 0.10003595]])
DOOR_GOAL_STATES = np.array([[0.29072163, 0.74286009, 0.10003595, 1.0, 0.29072163, 0.74286009, 0.10003595]])

_PEG_HAND = [0.00615235, 0.6001898, 0.19430117, 1.0]
_PEG_HEADS = [
    [0.00313463, 0.68326396], [-0.04035005, 0.67949003], [0.02531051, 0.6074387], [0.05957219, 0.6271171],
    [-0.07566337, 0.62575287], [-0.01177235, 0.55206996], [0.02779735, 0.54707706], [0.01835314, 0.5329686],
    [0.02690855, 0.6263067], [0.01766127, 0.59630984], [0.0560186, 0.6634998], [-0.03950658, 0.6323736],
    [-0.03216827, 0.5247563], [0.01265727, 0.69466716], [0.05076993, 0.6025737],
]
PEG_INITIAL_STATES = np.array([_PEG_HAND + xy + [0.02] for xy in _PEG_HEADS])
PEG_GOAL_STATES = np.array([[0.0, 0.6, 0.2, 1.0, -0.3 + 0.03, 0.6, 0.0 + 0.13]])

DOOR_SPEC = EnvSpec(
    name="sawyer_door", gym_id="earl/SawyerDoor-v0", state_dim=7, act_dim=4, success_idx=(4, 5, 6),
    success_threshold=0.02, train_horizon=200_000, eval_horizon=300,
    initial_states=DOOR_INITIAL_STATES, goal_states=DOOR_GOAL_STATES,
)
PEG_SPEC = EnvSpec(
    name="sawyer_peg", gym_id="earl/SawyerPeg-v0", state_dim=7, act_dim=4, success_idx=(4, 5, 6),
    success_threshold=0.05, train_horizon=100_000, eval_horizon=200,
    initial_states=PEG_INITIAL_STATES, goal_states=PEG_GOAL_STATES,
)

#: the harness's catalogue entries (registered in ``harness.envs.ENVS``)


def _sawyer(spec: EnvSpec, label: str, task: str, steps: int, demos: tuple[int, int], metaworld: str) -> EnvInfo:
    """A Sawyer task's record: its env class ``Sawyer<Task>Env``, scripted experts ``<task>_forward/_backward``."""
    return EnvInfo(spec=spec, label=label, env_class=f"harness.envs.sawyer:Sawyer{task.title()}Env", default_steps=steps,
                   experts=(f"harness.envs.sawyer_experts:{task}_forward", f"harness.envs.sawyer_experts:{task}_backward"),
                   scripted_demos=demos, metaworld_class=f"metaworld.envs.{metaworld}",
                   offline_assets="harness.envs.sawyer_assets:write_sawyer_assets", in_table1=True)


SAWYER_DOOR = _sawyer(DOOR_SPEC, "Sawyer Door", "door", 5_000_000, (5, 5), "sawyer_door_close_v3:SawyerDoorCloseEnvV3")
SAWYER_PEG = _sawyer(PEG_SPEC, "Sawyer Peg", "peg", 8_000_000, (10, 20),
                     "sawyer_peg_insertion_side_v3:SawyerPegInsertionSideEnvV3")
