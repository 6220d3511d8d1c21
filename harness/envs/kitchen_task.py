"""EARL's kitchen task as the harness catalogues it: EARL's constants, its :class:`EnvSpec` and :class:`EnvInfo`.

The simulator is :mod:`harness.envs.kitchen` (MuJoCo); this module imports only numpy, so that the env registry
(``harness.envs.ENVS``) stays cheap to import. Sources (EARL, github.com/architsharma97/earl_benchmark):
``earl_benchmark/envs/kitchen.py`` (goal, initial states, reward, success), ``earl_benchmark/__init__.py``
(``deployment_eval_config['kitchen']``: train horizon 1e5, eval horizon 400, task ``all_pairs``; ``has_demos``:
False for kitchen) and ``envs/kitchen_assets/adept_envs/adept_envs/franka/kitchen_multitask_v0.py`` (``KitchenV0``:
9-dim action, 9 robot + 14 object dofs, the goal concatenated to the observation).

State layout (23): the Franka's 7 arm joints and 2 finger joints (qpos 0-8), then the 14 object joints (qpos 9-22):
burner0 (9, 10), burner1 (11, 12), burner2 (13, 14), burner3 (15, 16), light switch (17, 18), slide cabinet (19),
hinge cabinet (20, 21), microwave (22). The goal has the same layout.
"""

from __future__ import annotations

import numpy as np

from harness.envs.base import EnvInfo, EnvSpec

#: EARL's ``component_to_state_idx`` (kitchen.py), in its dict order (the dense reward walks it in this order)
COMPONENTS: dict[str, tuple[int, ...]] = {
    "burner0": (9, 10),
    "burner1": (11, 12),
    "burner2": (13, 14),
    "burner3": (15, 16),
    "light_switch": (17, 18),
    "slide_cabinet": (19,),
    "hinge_cabinet": (20, 21),
    "microwave": (22,),
}

#: EARL's ``goal_states[0]`` ("clean goal state": every object closed / at its initial configuration), kitchen.py
GOAL_STATE = np.array([
    -4.1336253e-01, -1.6970085e+00, 1.4286385e+00, -2.5005307e+00, 6.2198675e-01, 1.2632011e+00, 8.8903642e-01,
    4.3514766e-02, 7.9217982e-03,
    -5.1586074e-04, 4.8548312e-04, -5.4527864e-06, 6.3510129e-06, 6.0837720e-05, -3.3861103e-05, 6.6394619e-05,
    -1.9801613e-05, -1.2477605e-04, 3.8065159e-04, -1.5148541e-04, -9.2229841e-04, 7.2293887e-03, 6.9650509e-03,
])

#: the opened configuration of each object EARL's pairs use (kitchen.py, after D4RL's kitchen_envs.py)
OPENED = {
    "microwave": (-0.7,),
    "light_switch": (-0.69, -0.05),
    "slide_cabinet": (0.37,),
    "hinge_cabinet": (0.0, 1.45),
}

#: EARL's ``initial_states['all_pairs']``, in its order: two objects opened, everything else at the goal
PAIRS = (
    ("microwave", "hinge_cabinet"),
    ("microwave", "slide_cabinet"),
    ("microwave", "light_switch"),
    ("light_switch", "slide_cabinet"),
    ("light_switch", "hinge_cabinet"),
    ("slide_cabinet", "hinge_cabinet"),
)


def _opened(names: tuple[str, ...]) -> np.ndarray:
    s = GOAL_STATE.copy()
    for name in names:
        s[list(COMPONENTS[name])] = OPENED[name]
    return s


INITIAL_STATES = np.stack([_opened(p) for p in PAIRS])
PAIR_NAMES = tuple("+".join(p) for p in PAIRS)


KITCHEN_SPEC = EnvSpec(
    name="kitchen", gym_id="earl/Kitchen-v0", state_dim=23, act_dim=9, success_idx=tuple(range(9, 23)),
    success_threshold=0.3, train_horizon=100_000, eval_horizon=400,
    initial_states=INITIAL_STATES, goal_states=GOAL_STATE[None].copy(),
    # EARL's dense reward of observations, its mocap and handle sites estimated from the observation (MuJoCo)
    reward_fn="harness.envs.kitchen:obs_reward",
)

#: the harness's catalogue entry (registered in ``harness.envs.ENVS``). EARL ships no kitchen demonstrations
#: (``EARLEnvs.has_demos``), so ``demos=False``; EARL's kitchen curves run to about 5M steps.
KITCHEN = EnvInfo(spec=KITCHEN_SPEC, label="Kitchen", env_class="harness.envs.kitchen:KitchenEnv",
                  default_steps=5_000_000, demos=False, published_metric="deployed_return")
