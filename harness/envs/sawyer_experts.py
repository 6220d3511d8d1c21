"""Scripted experts for the EARL Sawyer door and peg tasks (forward and backward).

Each expert is a deterministic, pure function of one 14-dim EARL observation ``[s, g]`` returning an
action in ``[-1, 1]^4`` (``dx, dy, dz, gripper``; gripper > 0 closes). The hand is moved with
Meta-World's proportional rule ``a = clip(25 * (target - hand), -1, 1)`` (``metaworld.policies.move``).

Door (``harness.envs.sawyer.SawyerDoorEnv``): the door hinge is at ``DOOR_HINGE_XY`` and the handle's
polar angle about it at hinge angle 0 is ``DOOR_HANDLE_PHASE0`` (both constants of EARL's model,
checked against the model by the tests), so the hinge angle is read off the handle xy. Points on
the door are given in the door frame (``x`` along the door from the hinge, ``-y`` the handle side;
the handle bar runs along x at ``y = -0.12``, ``x`` in [0.31, 0.46]).

- ``door_forward`` (close, adapted from Meta-World's door-close policy to EARL's geometry): go over
  a point outside the handle bar, descend to handle height, push along the door normal.
- ``door_backward`` (open to the goal's handle position): rise, move over the gap between the bar
  and the door beyond the panel's edge, descend into it and pull the bar along the arc to the goal
  angle (the gripper closed, so the fingers fit in the gap).

Peg (``SawyerPegEnv``; the observation holds the peg *head*, the grasp point is 0.13 behind it):

- ``peg_forward`` (adapted from Meta-World's peg-insert-side policy): grasp, lift and align the head
  with the hole (the goal's head position) 0.12 in front of it, push in.
- ``peg_backward``: grasp (the peg may be in the hole), pull it out along +x, carry the head over
  the goal's head position (an EARL initial state), lower it and release.
"""

from __future__ import annotations

import math

import numpy as np

# ---- constants of EARL's door model (sawyer_door_pull.xml with the door body at (0.1, 0.95, 0.1)) ----
DOOR_HINGE_XY = np.array([-0.08499999850988388, 0.8499999880790711])  # (-0.085, 0.85) via float32 body pos
DOOR_HANDLE_PHASE0 = -0.27778495388188557  # atan2 of (handle - hinge) at hinge angle 0
DOOR_HANDLE_Z = 0.10003595

PEG_GRASP_FROM_HEAD = np.array([0.13, 0.0, 0.01])  # pegGrasp - pegHead, peg lying along x
_P = 25.0  # Meta-World policies' gain


def _move(hand, target, grip: float) -> np.ndarray:
    a = np.empty(4, dtype=np.float32)
    a[:3] = np.clip(_P * (np.asarray(target, dtype=np.float64) - hand), -1.0, 1.0)
    a[3] = grip
    return a


# ------------------------------------------------------------------------------------------------
# door
# ------------------------------------------------------------------------------------------------

def door_angle(handle_xy) -> float:
    """Hinge angle of the door whose handle is at ``handle_xy`` (0 = closed, negative = open)."""
    r = np.asarray(handle_xy, dtype=np.float64) - DOOR_HINGE_XY
    ang = math.atan2(r[1], r[0]) - DOOR_HANDLE_PHASE0
    return (ang + math.pi) % (2 * math.pi) - math.pi


def _door_to_world(lx: float, ly: float, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return DOOR_HINGE_XY + np.array([c * lx - s * ly, s * lx + c * ly])


def _world_to_door(xy, angle: float) -> tuple[float, float]:
    c, s = math.cos(angle), math.sin(angle)
    r = np.asarray(xy, dtype=np.float64) - DOOR_HINGE_XY
    return c * r[0] + s * r[1], -s * r[0] + c * r[1]


_PUSH_X, _PUSH_Y = 0.40, -0.20  # pre-push point: outside the handle bar
_HOOK_X, _HOOK_Y = 0.43, -0.055  # between the bar and the door, beyond the panel's edge (0.365)
_LOW_Z = DOOR_HANDLE_Z  # hand height when pushing / pulling
_HIGH_Z = 0.27  # fingers clear the door panel (top at 0.223)


def door_forward(obs) -> np.ndarray:
    """Close the door (push the handle bar from outside along the door normal)."""
    o = np.asarray(obs, dtype=np.float64)
    hand, handle = o[0:3], o[4:7]
    ang = door_angle(handle[:2])
    lx, ly = _world_to_door(hand[:2], ang)
    pre = _door_to_world(_PUSH_X, _PUSH_Y, ang)
    if hand[2] > _LOW_Z + 0.03:  # still above: get over the pre-push point, then descend
        if math.hypot(lx - _PUSH_X, ly - _PUSH_Y) > 0.02:
            return _move(hand, (pre[0], pre[1], max(hand[2], _LOW_Z + 0.08)), 1.0)
        return _move(hand, (pre[0], pre[1], _LOW_Z), 1.0)
    if ly > -0.10:  # low but between bar and door (should not happen): go up
        return _move(hand, (hand[0], hand[1], _HIGH_Z), 1.0)
    if ang > -0.01:  # closed: hold still (pushing on would force the soft joint limit)
        return _move(hand, hand, 1.0)
    push = _door_to_world(_PUSH_X, ly + 0.03, ang)  # push the bar a little ahead: the door turns closed
    return _move(hand, (push[0], push[1], _LOW_Z), 1.0)


def door_backward(obs) -> np.ndarray:
    """Open the door to the goal's handle position: rise, move over the gap between the handle bar
    and the door (beyond the panel's edge), descend into it and pull the bar along the arc."""
    o = np.asarray(obs, dtype=np.float64)
    hand, handle, goal_handle = o[0:3], o[4:7], o[11:14]
    ang = door_angle(handle[:2])
    target_ang = door_angle(goal_handle[:2])
    lx, ly = _world_to_door(hand[:2], ang)
    if hand[2] < _LOW_Z + 0.03 and abs(lx - _HOOK_X) < 0.04 and -0.11 < ly < 0.0:  # hooked: pull
        step = max(min(target_ang - ang, 0.0), -0.15)
        pull = _door_to_world(_HOOK_X, _HOOK_Y - 0.03, ang + step)
        return _move(hand, (pull[0], pull[1], _LOW_Z), 1.0)
    hook = _door_to_world(_HOOK_X, _HOOK_Y, ang)
    if math.hypot(lx - _HOOK_X, ly - _HOOK_Y) > 0.012:  # go over the gap (rise first)
        if hand[2] < _HIGH_Z - 0.03:
            return _move(hand, (hand[0], hand[1], _HIGH_Z), 1.0)
        return _move(hand, (hook[0], hook[1], _HIGH_Z), 1.0)
    return _move(hand, (hook[0], hook[1], _LOW_Z), 1.0)  # descend into the gap


# ------------------------------------------------------------------------------------------------
# peg
# ------------------------------------------------------------------------------------------------

def _peg_grasp(o: np.ndarray):
    """Shared grasping logic. Returns ``(held, action_or_None)``: the action to take while not yet
    holding the peg, or ``None`` when the peg is held firmly."""
    hand, opening, head = o[0:3], o[3], o[4:7]
    grasp = head + PEG_GRASP_FROM_HEAD
    near_xy = math.hypot(hand[0] - grasp[0], hand[1] - grasp[1])
    near_z = hand[2] - grasp[2]
    if near_xy < 0.03 and abs(near_z) < 0.04 and 0.15 < opening < 0.8:
        return True, None  # closed on the peg
    if near_xy > 0.015:  # go over the grasp point, gripper open
        z = max(grasp[2] + 0.12, 0.15) if near_xy > 0.04 else hand[2]
        return False, _move(hand, (grasp[0], grasp[1], z), -1.0)
    if opening <= 0.15:  # closed on nothing: open and retry from above
        return False, _move(hand, (grasp[0], grasp[1], grasp[2] + 0.1), -1.0)
    if near_z > 0.025:  # descend, open (the mocap floor keeps the hand ~0.021 above)
        return False, _move(hand, grasp, -1.0)
    return False, _move(hand, grasp, 1.0)  # close


def peg_forward(obs) -> np.ndarray:
    """Grasp the peg, align its head with the goal head position 0.12 in front of it, push it in."""
    o = np.asarray(obs, dtype=np.float64)
    hand, opening, head, goal = o[0:3], o[3], o[4:7], o[11:14]
    held, act = _peg_grasp(o)
    if not held:
        return act
    if opening > 0.5 and head[2] < 0.03:  # still closing on the peg
        return _move(hand, hand, 1.0)
    pre = goal + np.array([0.12, 0.0, 0.0])
    if head[0] > pre[0] - 0.02 and np.linalg.norm(head[1:] - goal[1:]) > 0.01:
        if head[0] < pre[0] + 0.06 or head[2] > goal[2] - 0.03:
            target_head = pre  # align in front of the hole
        else:
            target_head = np.array([head[0], head[1], goal[2]])  # lift first
    else:
        target_head = goal + np.array([-0.05, 0.0, 0.0])  # push in
    return _move(hand, hand + (target_head - head), 1.0)


def peg_backward(obs) -> np.ndarray:
    """Pull the peg out of the hole and put its head back at the goal's head position, released."""
    o = np.asarray(obs, dtype=np.float64)
    hand, head, goal = o[0:3], o[4:7], o[11:14]
    if math.hypot(head[0] - goal[0], head[1] - goal[1]) < 0.015 and head[2] < goal[2] + 0.02:
        return _move(hand, (hand[0], hand[1], 0.2), -1.0)  # placed: release and withdraw
    held, act = _peg_grasp(o)
    if not held:
        return act
    if head[0] < -0.12:  # in (or at) the hole: pull straight out along +x
        target_head = np.array([-0.05, head[1], head[2]])
    elif math.hypot(head[0] - goal[0], head[1] - goal[1]) > 0.01:
        target_head = np.array([goal[0], goal[1], max(goal[2] + 0.06, head[2])])  # carry above
    else:
        target_head = np.array([goal[0], goal[1], goal[2] + 0.005])  # lower
    return _move(hand, hand + (target_head - head), 1.0)
