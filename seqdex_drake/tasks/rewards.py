"""Reward terms of the paper's appendix ("Reward functions"), as named, individually reported terms.

Every function returns a dict ``{term_name: value}``; the reward is the sum of the values. Notation:
``fingertip_distance`` is the sum over the four fingertips of their distance to the object (Sigma f_i),
``action`` the 19-dim policy action, ``hand_torque`` the torques of the 16 Allegro motors (the paper's
"commanded torques"; the arm's tens of N m would swamp the other terms).

One deliberate deviation: the paper writes the Grasp reward as ``exp[alpha0 * min(e0 - Sigma f, 0)]`` with
``alpha0 = -5``, which *grows* as the fingers move away (the min term is <= 0). We use the evidently intended
``exp[-alpha0 * min(e0 - Sigma f, 0)] = exp[5 * min(e0 - Sigma f, 0)]``, equal to 1 within e0 and decaying
beyond it.
"""

import dataclasses
import math
import operator

import numpy as np

from seqdex_drake.observation_layout import GOAL_POSITION_ERROR, GOAL_ROTATION_ERROR, floats

_IDENTITY = [1.0, 0.0, 0.0, 0.0]


@dataclasses.dataclass
class RewardWeights:
    """The lambda, alpha and e0 values of one sub-task's reward (paper appendix)."""

    progress: float = 1.0
    """lambda_1: weight of the task-progress term (pixels, rotation, grasp closeness, goal closeness)."""
    fingertip: float = 1.0
    """Weight of min(e0 - Sigma f, 0) (Search/Orient lambda_2, Insert lambda_2 = 0)."""
    action: float = -0.001
    """Weight of ||a||^2."""
    torque: float = -0.003
    """Weight of ||tau||^2."""
    e0: float = 0.1
    """Fingertip distance budget e0 (m)."""
    alpha0: float = 20.0
    """Position (Insert) or closeness (Grasp, magnitude) sharpness alpha_0."""
    alpha1: float = 1.0
    """Rotation sharpness alpha_1 (Insert)."""
    clearance: float = 0.0
    """Weight of the hover-clearance term (the hand-over chain's Reach only; not a paper term)."""
    lift: float = 0.0
    """Weight of the lift term of the Grasp sub-tasks' small-budget variants (``tool_grasp.budget_config``,
    ``grasp.budget_config``; not a paper term): the object's rise above its start as a fraction of the success
    lift, capped at 1, while it is held as success requires (tool: orientation within the tolerance; block:
    fingertips within the reach sum)."""


def penalties(weights: RewardWeights, action: np.ndarray, hand_torque: np.ndarray) -> dict[str, float]:
    """The action and torque penalty terms shared by every sub-task."""
    return {"action_penalty": weights.action * _squared_norm(action),
            "torque_penalty": weights.torque * _squared_norm(hand_torque)}


def _squared_norm(v) -> float:
    """||v||^2 of a short vector (array or list), in float arithmetic (see ``observation_layout.floats``)."""
    v = floats(v)
    return sum(map(operator.mul, v, v))


def fingertip_term(weights: RewardWeights, fingertip_distance: float) -> float:
    """lambda * min(e0 - Sigma f, 0): zero when the fingertips are within e0 in total, negative beyond."""
    return weights.fingertip * min(weights.e0 - fingertip_distance, 0.0)


def quaternion_angle(q_a: np.ndarray, q_b: np.ndarray) -> float:
    """Rotation angle (rad) between unit quaternions [w, x, y, z]: 2 asin(clamp(||vec(q_a conj(q_b))||, 0, 1))."""
    a0, a1, a2, a3 = floats(q_a)  # Plain float arithmetic: cheaper than numpy's per-call overhead, per env step.
    b0, b1, b2, b3 = floats(q_b)
    b1, b2, b3 = -b1, -b2, -b3
    x = a0 * b1 + b0 * a1 + a2 * b3 - a3 * b2
    y = a0 * b2 + b0 * a2 + a3 * b1 - a1 * b3
    z = a0 * b3 + b0 * a3 + a1 * b2 - a2 * b1
    return 2.0 * math.asin(min(math.sqrt(x * x + y * y + z * z), 1.0))


def goal_errors(observation) -> tuple[float, float]:
    """Position (m) and rotation (rad) errors of the object's origin frame to the goal, from the goal part of an
    observation (an array or ``SubtaskEnv.observation_values()``; Insert, tool Reorient: goal - position,
    goal * conj(object quaternion))."""
    x, y, z = floats(observation[GOAL_POSITION_ERROR])
    return math.sqrt(x * x + y * y + z * z), quaternion_angle(observation[GOAL_ROTATION_ERROR], _IDENTITY)


def search_reward(weights, target_pixels, fingertip_distance, action, hand_torque) -> dict[str, float]:
    """Search: lambda1 P + lambda2 min(e0 - Sigma f, 0) + penalties (lambda = 5, 1, -0.001, -0.003; e0 = 0.2)."""
    return {"pixels": weights.progress * float(target_pixels),
            "fingertip": fingertip_term(weights, fingertip_distance), **penalties(weights, action, hand_torque)}


def orient_reward(weights, rotation_from_start, fingertip_distance, action, hand_torque) -> dict[str, float]:
    """Orient: lambda1 theta + lambda2 min(e0 - Sigma f, 0) + penalties, theta = rotation since the start."""
    return {"rotation": weights.progress * float(rotation_from_start),
            "fingertip": fingertip_term(weights, fingertip_distance), **penalties(weights, action, hand_torque)}


def grasp_reward(weights, fingertip_distance, action, hand_torque) -> dict[str, float]:
    """Grasp (blocks and tools): lambda1 exp[|alpha0| min(e0 - Sigma f, 0)] + penalties (see module note)."""
    closeness = math.exp(abs(weights.alpha0) * min(weights.e0 - fingertip_distance, 0.0))
    return {"closeness": weights.progress * float(closeness), **penalties(weights, action, hand_torque)}


def goal_reward(weights, position_error, rotation_error, fingertip_distance, action, hand_torque) -> dict[str, float]:
    """Insert and tool Reorient: lambda1 exp[-(alpha0 ||x_o - x_g|| + alpha1 d_rot)] + lambda2 min(...) + penalties.

    ``rotation_error`` is the paper's 2 asin(clamp(||d_a||, 0, 1)), see :func:`quaternion_angle`.
    """
    closeness = math.exp(-(weights.alpha0 * position_error + weights.alpha1 * rotation_error))
    return {"goal": weights.progress * float(closeness), "fingertip": fingertip_term(weights, fingertip_distance),
            **penalties(weights, action, hand_torque)}
