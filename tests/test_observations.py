"""The observation layout against Drake's own kinematics, and the env's helpers that read it."""

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY
from seqdex_drake.sensors.observations import pose_vector
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
