"""Carrying a held object to its goal: how far the carry reaches, how the goal's symmetric equivalents are chosen,
and the carry an Insert env applies to a hand-off from Grasp.

The whole chain's approach carries the block Grasp holds to ``CARRY_HEIGHT`` over its goal and turns the hand until
the block has its goal's orientation (``controller/chain_parts.py`` ``ApproachTarget``; ``evaluation/runner.py``
``CARRY_STAGES``, ``CARRY_GOAL_SYMMETRY``). :func:`carry_to_goal` leaves a hand-off from Grasp where that carry
leaves the block, so that forward initialization trains and measures Insert from there.
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RotationMatrix

from seqdex_drake.observation_layout import floats
from seqdex_drake.robots.allegro import PALM_BODY, p_PalmHc_Palm

#: The largest turn (rad) the carry gives the hand to bring the held object to its goal's orientation; a larger one
#: (the object upside down in hand) is not made.
MAX_CARRY_TURN = 1.75
#: A carried object's origin is at most this far (m) from the approach's controlled point (the hand centre); farther,
#: it is not in hand and the approach aims at the plain goal.
CARRY_REACH = 0.2
#: An object counts as in hand for :func:`carry_to_goal` only while at least this many robot bodies touch it.
MIN_HOLDING_BODIES = 2
#: A hand-off from Grasp starts Insert with the block this far (m) above its goal (:func:`carry_to_goal`).
CARRY_HEIGHT = 0.03
#: A restored state whose arm target turns the palm more than this (rad) from home continues a carried episode: its
#: wrist holds that orientation (:func:`restore_held_orientation`).
MIN_HELD_TURN = 0.02
#: A block's goal is the same turned by pi about its z.
BLOCK_GOAL_TURNS = (RotationMatrix(), RotationMatrix.MakeZRotation(np.pi))


def nearest_equivalent(R_WG: RotationMatrix, R_WO: RotationMatrix, turns) -> RotationMatrix:
    """Of the goal orientations ``R_WG @ turn`` (``turns``: rotations about the goal's z that leave it the same),
    the one nearest ``R_WO``."""
    return min((R_WG @ turn for turn in turns), key=lambda R: (R.inverse() @ R_WO).ToAngleAxis().angle())


def carry_to_goal(env, height: float = CARRY_HEIGHT) -> bool:
    """Moves the robot, with the block it holds, so that the block's origin is ``height`` above its goal and the block
    has its goal's orientation (the yaw-flipped goal if nearer), as the whole chain's carry leaves it
    (``evaluation/runner.py`` ``CARRY_STAGES``, ``CARRY_GOAL_SYMMETRY``): the arm is set by inverse kinematics to
    the palm pose that does it, the block moved with the palm (the grasp unchanged), everything at rest, the arm's
    PD targets there and the palm orientation the wrist holds from then on (``env.R_WP_hold``) the new one.
    Grasp's lift leaves the block about 1.1 m up anywhere over the box and turned 10-15 deg in the jaws: from there
    Insert's 125 steps at the wrist's 0.3 m/s reached the goal in none of 60 hand-offs. Returns False, changing
    nothing, when the block is not in hand (farther than ``CARRY_REACH`` from the hand centre), the turn would be
    over ``MAX_CARRY_TURN`` or the pose is out of the arm's reach. In hand also means touched by at least two of
    the hand's bodies: a block under the open hand, early in Grasp, is near the hand centre but not held, and
    moving it with the palm would set it over its goal without a grasp (6 of the 60 mid-Grasp hand-overs of an F^insert
    collection "succeeded" so, from as early as Grasp's first step)."""
    X_WPalm = env.plant.EvalBodyPoseInWorld(env.plant_context, env.plant.GetBodyByName(PALM_BODY, env.hand))
    X_WO = env.object_pose()
    if np.linalg.norm(X_WPalm @ p_PalmHc_Palm - X_WO.translation()) > CARRY_REACH:
        return False
    env.refresh_sampled_outputs()  # The restored state's contacts, not the last step's.
    if env.objects.robot_bodies_touching(env.plant_context, env.target_object) < MIN_HOLDING_BODIES:
        return False
    X_WG = RigidTransform(Quaternion(floats(env.goal[3:]) / np.linalg.norm(env.goal[3:])), floats(env.goal[:3]))
    R_WG = nearest_equivalent(X_WG.rotation(), X_WO.rotation(), BLOCK_GOAL_TURNS)
    X_WO_new = RigidTransform(R_WG, X_WG.translation() + [0.0, 0.0, height])
    X_WPalm_new = X_WO_new @ X_WO.InvertAndCompose(X_WPalm)
    if (X_WPalm_new.rotation() @ env.R_WP_hold.inverse()).ToAngleAxis().angle() > MAX_CARRY_TURN:
        return False
    q, error = env.ik.solve(np.asarray(env.scenario.robot.arm_home, dtype=float),
                            X_WPalm_new @ p_PalmHc_Palm, X_WPalm_new.rotation())
    if error > 1e-3:
        return False
    hand_q = env.plant.GetPositions(env.plant_context, env.hand)
    hand_target, previous_action = env._hand_target, env._previous_action
    env.set_robot(q, hand_q)  # At rest; then the grasp's PD targets and the previous action as they were.
    env._hand_target = hand_target
    env._set_sources(floats(q), hand_target, previous_action)
    env.objects.set_pose(env.context, env.target_object, env.ik.palm_pose(q) @ RigidTransform(
        -p_PalmHc_Palm) @ X_WPalm.InvertAndCompose(X_WO), frozen=False)
    env.R_WP_hold = X_WPalm_new.rotation()
    env.refresh_sampled_outputs()
    return True


def restore_held_orientation(env) -> None:
    """Sets the palm orientation ``env``'s wrist holds after restoring a state of its own: the one its arm target
    gives if that is turned more than ``MIN_HELD_TURN`` from home (an episode that began with
    :func:`carry_to_goal`), else home (the wrist IK keeps the home orientation to about 1e-3 rad, so a standalone
    state continues exactly as it would have). A carried state continues with the orientation read back from its arm
    target, within the wrist IK's tracking error of the one it held."""
    R_WP = env.ik.palm_pose(np.asarray(env._arm_target, dtype=float)).rotation()
    turned = (R_WP @ env.R_WP_home.inverse()).ToAngleAxis().angle() > MIN_HELD_TURN
    env.R_WP_hold = R_WP if turned else env.R_WP_home
