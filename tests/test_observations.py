"""The observation layout against Drake's own kinematics, and the env's helpers that read it."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import BasicVector

from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY
from seqdex_drake.systems.observations import pose_vector
from seqdex_drake.tasks.registry import make_env
from seqdex_drake.tasks.rewards import goal_errors, quaternion_angle


@pytest.fixture(scope="module")
def env():
    env = make_env("tool_reorient")
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(4):  # Moving: nonzero velocities everywhere.
        env.step(rng.uniform(-1, 1, 19))
    return env


def _body_rows(env, frames) -> np.ndarray:
    rows = []
    for frame in frames:
        X = frame.CalcPoseInWorld(env.plant_context)
        V = frame.CalcSpatialVelocityInWorld(env.plant_context)
        rows.append(np.concatenate([pose_vector(X), V.translational(), V.rotational()]))
    return np.array(rows)


def test_observation_matches_the_plants_kinematics(env):
    obs = env.raw_observation()
    plant, context = env.plant, env.plant_context
    q, v = plant.GetPositions(context, env.arm), plant.GetVelocities(context, env.arm)
    np.testing.assert_array_equal(obs[:7], q)
    np.testing.assert_array_equal(obs[7:23], plant.GetPositions(context, env.hand))
    np.testing.assert_array_equal(obs[23:30], v)
    np.testing.assert_array_equal(obs[30:46], plant.GetVelocities(context, env.hand))
    frames = [plant.GetFrameByName(name, env.hand) for name in FINGERTIP_FRAMES]
    frames += [plant.GetBodyByName(PALM_BODY, env.hand).body_frame(), env.object_body().body_frame()]
    np.testing.assert_allclose(obs[46:124].reshape(6, 13), _body_rows(env, frames), atol=1e-12)
    np.testing.assert_array_equal(obs[124:143], env._previous_action)
    np.testing.assert_array_equal(obs[143:159], env.hand_torque())
    assert np.abs(obs[46:124].reshape(6, 13)[:, 7:]).max() > 1e-3  # Really moving.


def test_fingertip_frames_offset_from_their_bodies(env):
    """The assembler's general case, frames not at their body's origin (our Allegro's tips are tip links)."""
    assembler, context = env.assembler, env._assembler_context
    X_BF = RigidTransform(RollPitchYaw(0.3, -0.2, 0.5), [0.01, -0.02, 0.03])
    saved = assembler._X_BF, assembler._tips_are_bodies
    try:
        assembler._X_BF, assembler._tips_are_bodies = np.array([X_BF.GetAsMatrix34()] * 4), False
        out = BasicVector(assembler.size)
        type(assembler)._calc(assembler, context, out)
    finally:
        assembler._X_BF, assembler._tips_are_bodies = saved
    for k, name in enumerate(FINGERTIP_FRAMES):
        body = env.plant.GetFrameByName(name, env.hand).body()
        X_WB = body.EvalPoseInWorld(env.plant_context)
        V_WB = body.EvalSpatialVelocityInWorld(env.plant_context)
        V_WF = V_WB.Shift(X_WB.rotation() @ X_BF.translation())
        expected = np.concatenate([pose_vector(X_WB @ X_BF), V_WF.translational(), V_WF.rotational()])
        np.testing.assert_allclose(out.value()[46 + 13 * k:59 + 13 * k], expected, atol=1e-12)


def test_hand_points_and_fingertip_distance_agree_with_the_plant(env):
    expected = env.objects.hand_points(env.context)
    np.testing.assert_allclose(env.hand_points(), expected, atol=1e-12)
    com = env.object_pose() @ env.object_body().default_com()
    np.testing.assert_allclose(env.object_position(), com, atol=1e-12)
    assert env.fingertip_distance() == pytest.approx(np.linalg.norm(expected[:4] - com, axis=1).sum(), abs=1e-12)


def test_the_helpers_read_the_same_state_inside_a_step(env):
    """Within a step the tasks read the step's own observation as floats (``observation_values``) and the
    helpers derived from it; they must match what the same helpers compute from the plant after the step."""
    seen = {}
    is_success = env.task.is_success

    def spy(e):
        seen.update(values=list(e.observation_values()), raw=e.raw_observation().copy(), points=e.hand_points(),
                    position=e.object_position(), distance=e.fingertip_distance(), torque=e.hand_torque())
        return is_success(e)

    env.task.is_success = spy
    try:
        env.step(np.random.default_rng(3).uniform(-1, 1, 19))
    finally:
        del env.task.is_success
    np.testing.assert_array_equal(seen["values"], seen["raw"])
    np.testing.assert_array_equal(seen["raw"], env.raw_observation())  # The port's value, after the step.
    np.testing.assert_allclose(seen["points"], env.objects.hand_points(env.context), atol=1e-12)
    np.testing.assert_allclose(seen["position"], env.object_position(), atol=1e-12)
    assert seen["distance"] == pytest.approx(env.fingertip_distance(), abs=1e-12)
    np.testing.assert_array_equal(seen["torque"], env.hand_torque())


def test_goal_errors_read_from_the_observation_match_the_pose(env):
    pose, goal = pose_vector(env.object_pose()), env.goal
    position, rotation = goal_errors(env.raw_observation())
    assert position == pytest.approx(np.linalg.norm(pose[:3] - goal[:3]), abs=1e-12)
    assert rotation == pytest.approx(quaternion_angle(pose[3:], goal[3:]), abs=1e-9)
    assert rotation > 1.0  # tool Reorient's goal is the tool flipped: a real angle, not a trivial zero.


def test_quaternions_match_drakes_conversion():
    """The float rotation-matrix-to-quaternion conversion agrees with Drake's, also at the 180-degree turns
    where w = 0 and each pivot of Shepperd's method is taken."""
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RotationMatrix

    from seqdex_drake.systems.observations import quaternions_wxyz

    rng = np.random.default_rng(3)
    rotations = [RotationMatrix(Quaternion(q / np.linalg.norm(q))) for q in rng.normal(size=(500, 4))]
    rotations += [RotationMatrix(), RotationMatrix.MakeXRotation(np.pi), RotationMatrix.MakeYRotation(np.pi),
                  RotationMatrix.MakeZRotation(np.pi), RotationMatrix.MakeXRotation(-0.5 * np.pi)]
    expected = np.array([pose_vector(RigidTransform(R, np.zeros(3)))[3:] for R in rotations])
    q = np.array(quaternions_wxyz(np.array([R.matrix() for R in rotations])))
    assert np.all(q[:, 0] >= 0.0)
    # At w = 0, q and -q are the same rotation: compare up to that sign there.
    flip = (np.abs(expected[:, 0]) < 1e-12) & (np.sum(q * expected, axis=1) < 0)
    q[flip] *= -1.0
    np.testing.assert_allclose(q, expected, atol=1e-15)


def test_the_steps_observation_is_the_ports():
    """``SubtaskEnv.step`` assembles the observation on the plant's own context; the port computes it on the
    assembler's. Both must give the same numbers, bit for bit, for every layout (base, goal, pixels)."""
    for name in ("grasp", "insert", "search"):
        env = make_env(name)
        env.reset(seed=1)
        rng = np.random.default_rng(1)
        for _ in range(3):
            observation, *_ = env.step(rng.uniform(-1, 1, 19))
            port = env.assembler.get_output_port().Eval(env._assembler_context)
            np.testing.assert_array_equal(observation, port.astype(np.float32))
            np.testing.assert_array_equal(env._assemble_values(), port)
