"""SerialChainKinematics: the controller plant's palm pose and Jacobian in floats, against Drake's."""

import numpy as np
import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable, PrismaticJoint, SpatialInertia
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake.robots.allegro import PALM_BODY, p_PalmHc_Palm
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.robots.chain_kinematics import SerialChainKinematics
from seqdex_drake.scenario import LoadScenario
from seqdex_drake.station import AddStationPlant, MakeControllerPlant


@pytest.fixture(scope="module")
def controller_plant():
    return MakeControllerPlant(LoadScenario("building_blocks/grasp"))


def _palm(plant):
    return plant.GetBodyByName(PALM_BODY, plant.GetModelInstanceByName("allegro")).body_frame()


def test_pose_and_jacobian_match_drake(controller_plant):
    plant, palm = controller_plant, _palm(controller_plant)
    kinematics, context = SerialChainKinematics(plant, palm), plant.CreateDefaultContext()
    rng = np.random.default_rng(0)
    for _ in range(30):
        q = rng.uniform(plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits())
        plant.SetPositions(context, q)
        X_WP = palm.CalcPoseInWorld(context)
        (R, p), joints = kinematics.pose(q.tolist())
        np.testing.assert_allclose(np.reshape(R, (3, 3)), X_WP.rotation().matrix(), atol=1e-14)
        np.testing.assert_allclose(p, X_WP.translation(), atol=1e-14)
        p_WC = X_WP.multiply(p_PalmHc_Palm)
        J = plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kQDot, palm, p_PalmHc_Palm,
                                              plant.world_frame(), plant.world_frame())
        np.testing.assert_allclose(kinematics.jacobian(joints, p_WC.tolist()), J, atol=1e-14)


def test_palm_ik_reports_drakes_palm_pose(controller_plant):
    ik, context = PalmIK(controller_plant, p_PalmC_Palm=p_PalmHc_Palm), controller_plant.CreateDefaultContext()
    q = np.array([0.3, -0.5, 0.2, -2.0, 0.1, 1.8, 0.6])
    controller_plant.SetPositions(context, q)
    X_WP = _palm(controller_plant).CalcPoseInWorld(context)
    X_WC = ik.palm_pose(q)
    np.testing.assert_allclose(X_WC.translation(), X_WP.multiply(p_PalmHc_Palm), atol=1e-14)
    np.testing.assert_allclose(X_WC.rotation().matrix(), X_WP.rotation().matrix(), atol=1e-14)
    # The IK still converges on a reachable target (the position error below a tenth of a millimetre).
    target = X_WC.translation() + [0.05, -0.03, 0.04]
    solution, error = ik.solve(q, target, X_WC.rotation())
    assert error < 1e-4
    np.testing.assert_allclose(ik.palm_position(solution), target, atol=1e-4)


def test_plants_it_cannot_handle_are_clear_errors():
    # The station's plant: the chain to the palm is the arm, but the plant also has the fingers and objects.
    plant, _ = AddStationPlant(DiagramBuilder(), LoadScenario("building_blocks/grasp"))
    with pytest.raises(ValueError, match="must be exactly the chain's revolute joints"):
        SerialChainKinematics(plant, _palm(plant))
    # A prismatic joint on the chain.
    plant = MultibodyPlant(0.0)
    body = plant.AddRigidBody("slider", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.AddJoint(PrismaticJoint("rail", plant.world_frame(), body.body_frame(), [1.0, 0.0, 0.0]))
    plant.Finalize()
    with pytest.raises(ValueError, match="'rail' is a prismatic joint; only revolute and weld joints"):
        SerialChainKinematics(plant, body.body_frame())
