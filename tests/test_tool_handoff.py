"""Tool Reorient's standalone reset: the hammer settled, by simulation, in a fist grasp (``tasks/handoff.py``).

After ``ToolReorientTask.reset`` the hammer must be a free body held by the hand alone: touching only hand
links, and staying put relative to the palm (< 1 cm) and well above the table (> 0.1 m) over one more second
of simulation. That second is driven through ``env.step`` with :func:`hold_action`, the policy action that keeps
the hand's PD targets: hand actions are absolute targets scaled to the joint limits, so ``np.zeros(19)`` would
command the mid-range posture, i.e. open the fist (the hammer then sags 3.6 cm and jams in the index finger).
About 10 s in all.
"""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix

from seqdex_drake.envs.subtask_env import SubtaskEnv
from seqdex_drake.robots.allegro import PALM_BODY, scale_action_to_limits
from seqdex_drake.sensors.observations import pose_vector
from seqdex_drake.tasks.handoff import (
    FIST_FINGER_OPEN,
    FIST_THUMB,
    TOOL_GRASPS,
    hold_action,
    synthesized_tool_grasp,
)
from seqdex_drake.tasks.rewards import quaternion_angle
from seqdex_drake.tasks.tool_reorient import ToolReorientTask, default_config

TABLE_TOP = 0.6
HOLD_STEPS = 60  # 1 s at 60 Hz.


@pytest.fixture(scope="module")
def env():
    return SubtaskEnv(ToolReorientTask(default_config()))


def _palm(env):
    return env.plant.GetBodyByName(PALM_BODY, env.hand)


def _X_PalmTool(env) -> RigidTransform:
    return _palm(env).EvalPoseInWorld(env.plant_context).InvertAndCompose(env.object_pose())


def _contact_bodies(env) -> list[tuple[str, str, float]]:
    """(model instance, body, normal force [N]) of everything touching the target tool."""
    results = env.station.GetOutputPort("contact_results").Eval(env.station.GetMyContextFromRoot(env.context))
    tool = env.object_body().index()
    touching = []
    for k in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(k)
        if tool in (info.bodyA_index(), info.bodyB_index()):
            other = env.plant.get_body(info.bodyB_index() if info.bodyA_index() == tool else info.bodyA_index())
            touching.append((env.plant.GetModelInstanceName(other.model_instance()), other.name(),
                             float(np.linalg.norm(info.contact_force()))))
    return touching


def test_the_reset_leaves_the_hammer_held_in_the_hand_for_a_second(env):
    observation, _ = env.reset(seed=0)
    assert env.target_object == "hammer" and np.all(np.isfinite(observation))
    assert not env.objects.frozen_mask(env.context)[env.objects.index("hammer")]  # A free body, not pinned.
    touching = _contact_bodies(env)
    assert touching and {instance for instance, _, _ in touching} == {"allegro"}, touching
    # Held up by the hand: the contact forces carry at least the hammer's weight (5 N).
    assert sum(force for _, _, force in touching) > env.object_body().default_mass() * 9.81
    action = hold_action(env)
    np.testing.assert_allclose(scale_action_to_limits(action[:16]), env._hand_target, atol=1e-12)
    start = _X_PalmTool(env)
    lowest = np.inf
    for _ in range(HOLD_STEPS):
        observation, reward, terminated, truncated, info = env.step(action)
        assert np.all(np.isfinite(observation)) and np.isfinite(reward) and not info["simulator_error"]
        assert not terminated
        lowest = min(lowest, env.object_position()[2])
    end = _X_PalmTool(env)
    assert np.linalg.norm(end.translation() - start.translation()) < 0.01
    assert start.rotation().InvertAndCompose(end.rotation()).ToAngleAxis().angle() < 0.1
    assert lowest > TABLE_TOP + 0.1
    assert {instance for instance, _, _ in _contact_bodies(env)} == {"allegro"}


def test_the_reset_is_deterministic_for_a_seed(env):
    first, _ = env.reset(seed=7)
    state = env.get_state()
    env.step(np.full(19, 0.3))
    second, _ = env.reset(seed=7)
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(state.plant_positions, env.get_state().plant_positions)
    np.testing.assert_array_equal(state.goal, env.goal)


def test_the_goal_is_the_start_flipped_about_the_handle(env):
    env.reset(seed=1)
    X_WT = env.object_pose()
    pose = pose_vector(X_WT)
    np.testing.assert_allclose(env.goal[:3], pose[:3], atol=1e-12)
    assert quaternion_angle(pose[3:], env.goal[3:]) == pytest.approx(np.pi, abs=1e-6)
    flipped = X_WT.rotation() @ RotationMatrix.MakeYRotation(np.pi)
    np.testing.assert_allclose(pose_vector(RigidTransform(flipped))[3:], env.goal[3:], atol=1e-9)


def test_the_hammer_is_placed_touching_nothing_before_the_fist_closes(env):
    """The synthesized placement must not interpenetrate the open hand: a tool released (or pinned) inside a
    finger would be shot out, and the grasp would not come from simulation."""
    env.reset(seed=0)
    env.objects.park(env.context)
    env.set_target("hammer")
    env.set_robot(np.asarray(env.scenario.robot.arm_home, dtype=float), np.r_[np.tile(FIST_FINGER_OPEN, 3), FIST_THUMB])
    X_WT = _palm(env).EvalPoseInWorld(env.plant_context) @ TOOL_GRASPS["hammer"].X_PalmT()
    env.objects.set_pose(env.context, "hammer", X_WT, frozen=True)
    query = env.station.GetOutputPort("query_object").Eval(env.station.GetMyContextFromRoot(env.context))
    inspector, tool = query.inspector(), env.object_body().index()
    distances = [pair.distance for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.02)
                 if tool in (env.plant.GetBodyFromFrameId(inspector.GetFrameId(pair.id_A)).index(),
                             env.plant.GetBodyFromFrameId(inspector.GetFrameId(pair.id_B)).index())]
    assert distances and min(distances) > 0.0005  # The palm face is 1.4 mm away, every finger >= 1.4 cm.


def test_tools_without_a_synthesized_grasp_are_refused(env):
    with pytest.raises(ValueError, match="no synthesized grasp for 'spatula'.*initial_state"):
        synthesized_tool_grasp(env, "spatula")
