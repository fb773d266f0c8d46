"""The carry's orientation target (``ApproachTarget``'s ``hold_rotation``) on a two-body plant: the turn that brings
a held block to its goal's orientation, the same while the block turns with the palm, nearest of the goal's
symmetric equivalents, and the identity when nothing is carried."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import SpatialInertia

from seqdex_drake.controller.chain_parts import MAX_CARRY_TURN, ApproachTarget
from seqdex_drake.observation_layout import pose_vector
from seqdex_drake.sensors.observations import ObservationTarget

p_PalmC = np.array([0.08, 0.0, 0.1])
R_HOLD = RotationMatrix(RollPitchYaw(np.pi, 0.0, 0.0))  # Palm down.
GOAL = RigidTransform(RollPitchYaw(0.0, 0.0, np.pi / 2), [0.2, -0.2, 0.62])


def make(goal_symmetry=np.pi, stages=(False, True), carry=(np.nan, 0.03)):
    plant = MultibodyPlant(0.0)
    palm = plant.AddRigidBody("palm", SpatialInertia.SolidSphereWithMass(1.0, 0.01))
    block = plant.AddRigidBody("block", SpatialInertia.SolidSphereWithMass(0.1, 0.01))
    plant.Finalize()
    system = ApproachTarget(plant, list(stages), list(carry), (int(palm.index()), p_PalmC, 0.05), goal_symmetry,
                            R_HOLD)
    context = system.CreateDefaultContext()
    system.set_target(context, ObservationTarget(object_body=int(block.index()), goal=pose_vector(GOAL)))
    return system, context, int(palm.index()), int(block.index()), plant.num_bodies()


def hold(system, context, stage, X_WPalm, X_WB, palm, block, n):
    poses = [RigidTransform()] * n
    poses[palm], poses[block] = X_WPalm, X_WB
    system.GetInputPort("body_poses").FixValue(context, AbstractValue.Make(poses))
    system.GetInputPort("stage").FixValue(context, [float(stage)])
    return RotationMatrix(system.GetOutputPort("hold_rotation").Eval(context).reshape(3, 3))


def angle(R_a: RotationMatrix, R_b: RotationMatrix) -> float:
    return (R_a.inverse() @ R_b).ToAngleAxis().angle()


def test_the_turn_brings_a_held_block_to_its_goal_and_stays_put_while_it_turns_with_the_palm():
    system, context, palm, block, n = make()
    X_WPalm = RigidTransform(R_HOLD, [0.1, 0.2, 1.0])
    # Held 12 deg off the goal's yaw and tilted 14 deg along its length, as Grasp's jaws leave a block.
    X_PalmB = X_WPalm.inverse() @ RigidTransform(RollPitchYaw(np.deg2rad(-14), 0.0, np.pi / 2 + np.deg2rad(12)),
                                                 X_WPalm @ p_PalmC + [0.0, 0.0, -0.02])
    R_off = hold(system, context, 1, X_WPalm, X_WPalm @ X_PalmB, palm, block, n)
    # Turning the palm to R_off R_hold carries the block to the goal's orientation.
    X_WPalm_turned = RigidTransform(R_off @ R_HOLD, X_WPalm.translation())
    assert angle((X_WPalm_turned @ X_PalmB).rotation(), GOAL.rotation()) < 1e-9
    assert angle(R_off, RotationMatrix()) == pytest.approx(np.deg2rad(np.hypot(12, 14)), abs=np.deg2rad(1.5))
    # Midway through the turn (and moved elsewhere) the output is the same.
    X_WPalm_mid = RigidTransform(RotationMatrix.MakeZRotation(0.1) @ R_HOLD, [0.3, -0.1, 0.8])
    R_mid = hold(system, context, 1, X_WPalm_mid, X_WPalm_mid @ X_PalmB, palm, block, n)
    assert angle(R_mid, R_off) < 1e-9


def test_the_goal_turned_by_its_symmetry_is_the_nearest_and_nothing_turns_without_a_carried_block():
    system, context, palm, block, n = make()
    X_WPalm = RigidTransform(R_HOLD, [0.1, 0.2, 1.0])
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.0, -np.pi / 2 + 0.1), X_WPalm @ p_PalmC)  # The goal's yaw + pi + 0.1.
    R_off = hold(system, context, 1, X_WPalm, X_WB, palm, block, n)
    np.testing.assert_allclose(R_off.matrix(), RotationMatrix.MakeZRotation(-0.1).matrix(), atol=1e-9)
    identity = np.eye(3)
    far = RigidTransform(X_WB.rotation(), X_WPalm @ p_PalmC + [0.0, 0.0, -0.5])  # Dropped: not in hand.
    np.testing.assert_allclose(hold(system, context, 1, X_WPalm, far, palm, block, n).matrix(), identity)
    np.testing.assert_allclose(hold(system, context, 0, X_WPalm, X_WB, palm, block, n).matrix(), identity)
    upside_down = RigidTransform(RollPitchYaw(np.pi, 0.0, np.pi / 2), X_WB.translation())
    assert angle(RotationMatrix(RollPitchYaw(np.pi, 0, 0)), RotationMatrix()) > MAX_CARRY_TURN
    np.testing.assert_allclose(hold(system, context, 1, X_WPalm, upside_down, palm, block, n).matrix(), identity)
    plain, plain_context, *_ = make(goal_symmetry=0.0)
    np.testing.assert_allclose(hold(plain, plain_context, 1, X_WPalm, X_WB, palm, block, n).matrix(), identity)
    with pytest.raises(ValueError, match="goal_symmetry"):
        make(goal_symmetry=-1.0)
