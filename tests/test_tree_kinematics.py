"""TreeKinematics (the compiled per-step kinematics) against Drake: poses, velocities, the IK's Jacobian step.

Every test runs twice: on the C extension and on its fallback, Drake's kinematics (``SEQDEX_NO_C_EXTENSION=1``);
the two are compared with each other on random states, and the fallback's warning is checked to come once."""

import os
import subprocess
import sys

import numpy as np
import pytest
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import (
    BallRpyJoint,
    JacobianWrtVariable,
    PrismaticJoint,
    RevoluteJoint,
    SpatialInertia,
)
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake.robots import tree_kinematics
from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY, p_PalmHc_Palm
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.robots.tree_kinematics import TreeKinematics, rotation_vector
from seqdex_drake.scenario import LoadScenario
from seqdex_drake.station import AddStationPlant, MakeControllerPlant


def _require_compiled():
    """Skips a test that needs the C extension where it is not built; in CI (which installs a compiler) fails."""
    if not tree_kinematics.compiled_available():
        message = ("the C extension seqdex_drake/robots/_kinematics.c is not built (install gcc and python3-dev, "
                   "then rerun bash scripts/venv.sh)")
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)


@pytest.fixture(params=["compiled", "drake"])
def backend(request, monkeypatch):
    """Each test on the C extension and on Drake's kinematics (the fallback, forced by SEQDEX_NO_C_EXTENSION)."""
    if request.param == "compiled":
        _require_compiled()
        monkeypatch.delenv(tree_kinematics.FORCE_DRAKE_VARIABLE, raising=False)
    else:
        monkeypatch.setenv(tree_kinematics.FORCE_DRAKE_VARIABLE, "1")
    return request.param


@pytest.fixture(scope="module")
def station_plant():
    plant, _ = AddStationPlant(DiagramBuilder(), LoadScenario("building_blocks/grasp"))
    return plant


@pytest.fixture(scope="module")
def controller_plant():
    return MakeControllerPlant(LoadScenario("building_blocks/grasp"))


def _palm(plant):
    return plant.GetBodyByName(PALM_BODY, plant.GetModelInstanceByName("allegro")).body_frame()


def _random_state(plant, rng):
    """Positions within the joint limits, free bodies' quaternions random and a little off unit length (as an
    integrator leaves them), and random velocities."""
    context = plant.CreateDefaultContext()
    low, high = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
    q = np.where(np.isfinite(low) & np.isfinite(high), rng.uniform(np.maximum(low, -3), np.minimum(high, 3)),
                 rng.normal(size=low.size))
    for body_index in plant.GetFloatingBaseBodies():
        start = plant.get_body(body_index).floating_positions_start()
        quaternion = rng.normal(size=4)
        q[start:start + 4] = 1.01 * quaternion / np.linalg.norm(quaternion)
    plant.SetPositions(context, q)
    plant.SetVelocities(context, rng.normal(size=plant.num_velocities()))
    return context


def test_frame_states_match_drake_on_the_station_plant(station_plant, backend):
    """The six observation frames (fingertips, palm, a free block), at random states, against Drake."""
    plant = station_plant
    hand = plant.GetModelInstanceByName("allegro")
    block = plant.get_body(plant.GetFloatingBaseBodies().pop())
    frames = [plant.GetFrameByName(name, hand) for name in FINGERTIP_FRAMES] + [_palm(plant), block.body_frame()]
    X_FQ = RigidTransform(RollPitchYaw(0.1, -0.4, 0.3), [0.01, -0.02, 0.03])  # An offset point on each.
    kinematics = TreeKinematics(plant, frames)
    offset = TreeKinematics(plant, frames, [X_FQ] * len(frames))
    assert kinematics.compiled == (backend == "compiled")
    rng = np.random.default_rng(0)
    for _ in range(10):
        context = _random_state(plant, rng)
        x = plant.GetPositionsAndVelocities(context)
        rows = np.reshape(kinematics.states(x.tolist()), (len(frames), 13))
        np.testing.assert_array_equal(kinematics.states(x), rows.ravel())  # An array works alike.
        shifted = np.reshape(offset.states(x.tolist()), (len(frames), 13))
        poses = np.reshape(kinematics.poses(x[:plant.num_positions()].tolist()), (len(frames), 12))
        for frame, row, row_q, pose in zip(frames, rows, shifted, poses, strict=True):
            X_WF = frame.CalcPoseInWorld(context)
            V_WF = frame.CalcSpatialVelocityInWorld(context)
            np.testing.assert_allclose(row[:3], X_WF.translation(), atol=1e-13)
            q = X_WF.rotation().ToQuaternion().wxyz()
            np.testing.assert_allclose(row[3:7], q if q[0] >= 0 else -q, atol=1e-13)
            assert row[3] >= 0
            np.testing.assert_allclose(row[7:10], V_WF.translational(), atol=1e-12)
            np.testing.assert_allclose(row[10:13], V_WF.rotational(), atol=1e-12)
            np.testing.assert_allclose(pose[:9], X_WF.rotation().matrix().ravel(), atol=1e-13)
            np.testing.assert_allclose(pose[9:], X_WF.translation(), atol=1e-13)
            X_WQ = X_WF @ X_FQ
            V_WQ = V_WF.Shift(X_WF.rotation() @ X_FQ.translation())
            np.testing.assert_allclose(row_q[:3], X_WQ.translation(), atol=1e-13)
            np.testing.assert_allclose(row_q[7:10], V_WQ.translational(), atol=1e-12)


@pytest.mark.usefixtures("backend")
def test_prismatic_and_offset_joints_match_drake():
    """A small tree with a prismatic joint, joint frames offset in both bodies and a floating branch."""
    plant = MultibodyPlant(0.0)
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.1)
    slider, arm, free = (plant.AddRigidBody(name, inertia) for name in ("slider", "arm", "free"))
    X_a = RigidTransform(RollPitchYaw(0.3, 0.2, -0.1), [0.1, 0.2, 0.3])
    X_b = RigidTransform(RollPitchYaw(-0.5, 0.4, 0.9), [0.0, -0.1, 0.05])
    plant.AddJoint(PrismaticJoint("rail", plant.AddFrame(_offset(plant.world_frame(), "rail_p", X_a)),
                                  plant.AddFrame(_offset(slider.body_frame(), "rail_c", X_b)), [0.6, 0.0, 0.8]))
    plant.AddJoint(RevoluteJoint("hinge", plant.AddFrame(_offset(slider.body_frame(), "hinge_p", X_b)),
                                 plant.AddFrame(_offset(arm.body_frame(), "hinge_c", X_a)), [0.0, 0.6, 0.8]))
    plant.Finalize()  # "free" gets a quaternion floating joint.
    kinematics = TreeKinematics(plant, [arm.body_frame(), free.body_frame(), slider.body_frame()])
    rng = np.random.default_rng(1)
    for _ in range(10):
        context = _random_state(plant, rng)
        rows = np.reshape(kinematics.states(plant.GetPositionsAndVelocities(context).tolist()), (3, 13))
        for body, row in zip((arm, free, slider), rows, strict=True):
            X_WB, V_WB = body.EvalPoseInWorld(context), body.EvalSpatialVelocityInWorld(context)
            np.testing.assert_allclose(row[:3], X_WB.translation(), atol=1e-13)
            np.testing.assert_allclose(row[7:10], V_WB.translational(), atol=1e-12)
            np.testing.assert_allclose(row[10:13], V_WB.rotational(), atol=1e-12)


def _offset(parent, name, X):
    from pydrake.multibody.tree import FixedOffsetFrame

    return FixedOffsetFrame(name, parent, X)


@pytest.mark.usefixtures("backend")
def test_dls_step_matches_the_formula_on_drakes_jacobian(controller_plant):
    """dq = J^T (J J^T + d^2 I)^-1 e with Drake's Jacobian and log map, scaled and clamped as documented."""
    plant, palm = controller_plant, _palm(controller_plant)
    ik, context = PalmIK(plant, p_PalmC_Palm=p_PalmHc_Palm), plant.CreateDefaultContext()
    low, high = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
    rng = np.random.default_rng(2)
    for max_step in (0.05, 10.0):  # Scaled down, and not.
        for _ in range(15):
            q = rng.uniform(low, high)
            plant.SetPositions(context, q)
            X_WC = palm.CalcPoseInWorld(context) @ RigidTransform(p_PalmHc_Palm)
            target = X_WC.translation() + rng.normal(scale=0.05, size=3)
            R_target = RotationMatrix(RollPitchYaw(rng.normal(scale=0.3, size=3))) @ X_WC.rotation()
            J = plant.CalcJacobianSpatialVelocity(context, JacobianWrtVariable.kQDot, palm, p_PalmHc_Palm,
                                                  plant.world_frame(), plant.world_frame())
            angle_axis = (R_target @ X_WC.rotation().inverse()).ToAngleAxis()
            w = ik.orientation_weight
            e = np.r_[w * angle_axis.angle() * angle_axis.axis(), target - X_WC.translation()]
            J[:3] *= w
            dq = J.T @ np.linalg.solve(J @ J.T + ik.damping**2 * np.eye(6), e)
            dq *= min(1.0, max_step / np.linalg.norm(dq))
            expected = np.clip(q + dq, low, high)
            np.testing.assert_allclose(ik.step(q, target, R_target, max_step=max_step), expected, atol=1e-12)


@pytest.mark.usefixtures("backend")
def test_palm_ik_reports_drakes_palm_pose_and_converges(controller_plant):
    ik, context = PalmIK(controller_plant, p_PalmC_Palm=p_PalmHc_Palm), controller_plant.CreateDefaultContext()
    q = np.array([0.3, -0.5, 0.2, -2.0, 0.1, 1.8, 0.6])
    controller_plant.SetPositions(context, q)
    X_WP = _palm(controller_plant).CalcPoseInWorld(context)
    X_WC = ik.palm_pose(q)
    np.testing.assert_allclose(X_WC.translation(), X_WP.multiply(p_PalmHc_Palm), atol=1e-14)
    np.testing.assert_allclose(X_WC.rotation().matrix(), X_WP.rotation().matrix(), atol=1e-14)
    target = X_WC.translation() + [0.05, -0.03, 0.04]
    solution, error = ik.solve(q, target, X_WC.rotation())
    assert error < 1e-4
    np.testing.assert_allclose(ik.palm_position(solution), target, atol=1e-4)


@pytest.mark.usefixtures("backend")
def test_rotation_vector_matches_drakes_angle_axis_up_to_half_turns():
    rng = np.random.default_rng(7)
    small_turns = np.c_[np.ones(150), 1e-3 * rng.normal(size=(150, 3))]  # A few milliradians, as the IK sees.
    for q in np.r_[small_turns, rng.normal(size=(300, 4))]:  # Any turn: about half beyond 90 degrees.
        R = RotationMatrix(Quaternion(q / np.linalg.norm(q)))
        angle_axis = R.ToAngleAxis()
        np.testing.assert_allclose(rotation_vector(R.matrix()), angle_axis.angle() * angle_axis.axis(), atol=1e-12)
    assert rotation_vector(np.eye(3)) == [0.0, 0.0, 0.0]
    for angle in (np.pi - 1e-3, np.pi - 1e-7, np.pi):  # At and near a half turn: the rotation is reproduced.
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        r = np.array(rotation_vector(RotationMatrix(_angle_axis(angle, axis)).matrix()))
        assert abs(np.linalg.norm(r) - angle) < 1e-9
        R_back = RotationMatrix(_angle_axis(np.linalg.norm(r), r / np.linalg.norm(r))).matrix()
        np.testing.assert_allclose(R_back, RotationMatrix(_angle_axis(angle, axis)).matrix(), atol=1e-7)


def _angle_axis(angle, axis):
    from pydrake.common.eigen_geometry import AngleAxis

    return AngleAxis(angle, axis)


@pytest.mark.usefixtures("backend")
def test_quaternions_match_drakes_conversion():
    """The compiled rotation-to-quaternion conversion (Shepperd's method, qw >= 0) agrees with Drake's, also at
    the half turns where w = 0 and each of its pivots is taken."""
    plant = MultibodyPlant(0.0)
    body = plant.AddRigidBody("free", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.Finalize()
    kinematics, context = TreeKinematics(plant, [body.body_frame()]), plant.CreateDefaultContext()
    rng = np.random.default_rng(3)
    rotations = [RotationMatrix(Quaternion(q / np.linalg.norm(q))) for q in rng.normal(size=(300, 4))]
    rotations += [RotationMatrix(), RotationMatrix.MakeXRotation(np.pi), RotationMatrix.MakeYRotation(np.pi),
                  RotationMatrix.MakeZRotation(np.pi), RotationMatrix.MakeXRotation(-0.5 * np.pi)]
    for R in rotations:
        plant.SetFreeBodyPose(context, body, RigidTransform(R, [0.1, 0.2, 0.3]))
        q = np.array(kinematics.states(plant.GetPositionsAndVelocities(context).tolist())[3:7])
        expected = R.ToQuaternion().wxyz()
        assert q[0] >= 0.0
        if expected[0] < 0 or (abs(expected[0]) < 1e-12 and q @ expected < 0):  # q and -q: the same rotation.
            expected = -expected
        np.testing.assert_allclose(q, expected, atol=1e-15)


@pytest.mark.usefixtures("backend")
def test_bad_input_is_a_clear_error(station_plant, controller_plant):
    plant = MultibodyPlant(0.0)
    body = plant.AddRigidBody("ball", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.AddJoint(BallRpyJoint("socket", plant.world_frame(), body.body_frame()))
    plant.Finalize()
    with pytest.raises(ValueError, match="'socket' is a ball_rpy joint; only revolute, prismatic, weld"):
        TreeKinematics(plant, [body.body_frame()])
    kinematics = TreeKinematics(controller_plant, [_palm(controller_plant)])
    with pytest.raises(ValueError, match="plant state \\[q, v\\] must have 14 entries, got 7"):
        kinematics.states([0.0] * 7)
    with pytest.raises(TypeError):
        kinematics.poses([0.0] * 6 + ["a"])
    with pytest.raises(ValueError, match="single frame"):
        TreeKinematics(station_plant, [_palm(station_plant)] * 2).dls_step([0.0] * 7, [0.0] * 3, [1.0] * 9, 1.0,
                                                                            0.1, 0.1, [-1.0] * 7, [1.0] * 7)
    with pytest.raises(ValueError, match="all revolute or prismatic joints"):  # The station has free bodies.
        block = station_plant.get_body(station_plant.GetFloatingBaseBodies().pop())
        TreeKinematics(station_plant, [block.body_frame()]).dls_step(
            [0.0] * station_plant.num_positions(), [0.0] * 3, np.eye(3).ravel().tolist(), 1.0, 0.1, 0.1,
            [-1.0] * station_plant.num_positions(), [1.0] * station_plant.num_positions())
    with pytest.raises(ValueError, match="at most 64 frames|between 1 and 64 frames"):
        TreeKinematics(controller_plant, [])


def test_the_fallback_gives_the_compiled_results(station_plant, controller_plant):
    """Drake's kinematics (the fallback) against the C extension, call by call, on random states: frame states
    and poses with offsets, the DLS step (scaled and not) and the log map."""
    _require_compiled()
    plant = station_plant
    hand = plant.GetModelInstanceByName("allegro")
    block = plant.get_body(plant.GetFloatingBaseBodies().pop())
    frames = [plant.GetFrameByName(name, hand) for name in FINGERTIP_FRAMES] + [_palm(plant), block.body_frame()]
    X_FQ = [RigidTransform(RollPitchYaw(0.1 * i, -0.4, 0.3), [0.01, -0.02 * i, 0.03]) for i in range(len(frames))]
    compiled, drake = (TreeKinematics(plant, frames, X_FQ, compiled=flag) for flag in (True, False))
    assert compiled.compiled and not drake.compiled
    rng = np.random.default_rng(11)
    for _ in range(20):
        x = plant.GetPositionsAndVelocities(_random_state(plant, rng))
        np.testing.assert_allclose(drake.states(x.tolist()), compiled.states(x.tolist()), rtol=0, atol=1e-12)
        np.testing.assert_allclose(drake.poses(x), compiled.poses(x), rtol=0, atol=1e-13)
    palm = _palm(controller_plant)
    X_PalmC = [RigidTransform(p_PalmHc_Palm)]
    compiled, drake = (TreeKinematics(controller_plant, [palm], X_PalmC, compiled=flag) for flag in (True, False))
    low, high = controller_plant.GetPositionLowerLimits(), controller_plant.GetPositionUpperLimits()
    for max_step in (0.05, 10.0):
        for _ in range(20):
            q = rng.uniform(low, high).tolist()
            X_WC = compiled.pose(q)
            target = (X_WC.translation() + rng.normal(scale=0.05, size=3)).tolist()
            R_target = (RotationMatrix(RollPitchYaw(rng.normal(scale=0.5, size=3))) @ X_WC.rotation()).matrix()
            args = (q, target, R_target.ravel().tolist(), 0.3, 0.05, max_step, low.tolist(), high.tolist())
            np.testing.assert_allclose(drake.dls_step(*args), compiled.dls_step(*args), rtol=0, atol=1e-12)
    for quaternion in rng.normal(size=(100, 4)):
        R = RotationMatrix(Quaternion(quaternion / np.linalg.norm(quaternion))).matrix()
        np.testing.assert_allclose(rotation_vector(R, compiled=False), rotation_vector(R, compiled=True), atol=1e-12)


def test_without_the_extension_the_package_says_so_once():
    """A process without the built extension falls back to Drake's kinematics and warns once (every warning
    shown), naming the fix; a child process started after the warning stays quiet."""
    script = """
import subprocess, sys, warnings
warnings.simplefilter("always")
sys.modules["seqdex_drake.robots._kinematics"] = None  # As an install without a compiler: the import fails.
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import SpatialInertia
from seqdex_drake.robots.tree_kinematics import TreeKinematics, rotation_vector
plant = MultibodyPlant(0.0)
body = plant.AddRigidBody("free", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
plant.Finalize()
for _ in range(3):
    kinematics = TreeKinematics(plant, [body.body_frame()])
assert not kinematics.compiled
assert kinematics.poses([1.0, 0, 0, 0, 0.1, 0.2, 0.3])[9:] == [0.1, 0.2, 0.3]
rotation_vector([[1, 0, 0], [0, 1, 0], [0, 0, 1]])
child = subprocess.run([sys.executable, "-c", "import os; print(os.environ.get('SEQDEX_KINEMATICS_WARNED'))"],
                       capture_output=True, text=True)
print("child:", child.stdout.strip())
"""
    env = {key: value for key, value in os.environ.items()
           if key not in ("SEQDEX_KINEMATICS_WARNED", tree_kinematics.FORCE_DRAKE_VARIABLE)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stderr.count("SlowKinematicsWarning") == 1, done.stderr
    assert "install a C compiler and Python's headers (apt-get install gcc python3-dev)" in done.stderr
    assert "rerun `bash scripts/venv.sh`" in done.stderr
    assert "child: 1" in done.stdout  # Env workers inherit the mark and do not repeat the warning.
    forced = subprocess.run([sys.executable, "-c", "from seqdex_drake.robots.tree_kinematics import rotation_vector;"
                             "rotation_vector([[1, 0, 0], [0, 1, 0], [0, 0, 1]])"], capture_output=True, text=True,
                            env=dict(env, SEQDEX_NO_C_EXTENSION="1"), timeout=120)
    assert forced.returncode == 0 and "SlowKinematicsWarning" not in forced.stderr, forced.stderr
