"""Tool Reorient's standalone start varies with the seed: the synthesized fist grasp's yaw across the palm is drawn
from the episode's rng (``tasks/handoff.py``, :func:`sample_fist_grasp`), within a range the fist holds.

The range is checked at its ends: the hammer placed there touches nothing before the fist closes, settles, and then
stays put in the hand for a second under :func:`hold_action` (as ``tests/test_tool_handoff.py`` checks the
nominal grasp). About 15 s in all.
"""

import dataclasses

import numpy as np
import pytest
from pydrake.math import RigidTransform

from seqdex_drake.envs.subtask_env import SubtaskEnv
from seqdex_drake.robots.allegro import PALM_BODY
from seqdex_drake.tasks import handoff
from seqdex_drake.tasks.handoff import GRASP_YAW_JITTER, TOOL_GRASPS, hold_action, synthesized_tool_grasp
from seqdex_drake.tasks.tool_reorient import ToolReorientTask, default_config

TABLE_TOP = 0.6
HOLD_STEPS = 60  # 1 s at 60 Hz.
EXTREME_YAWS = (-GRASP_YAW_JITTER, GRASP_YAW_JITTER)


@pytest.fixture(scope="module")
def env():
    return SubtaskEnv(ToolReorientTask(default_config()))


def _X_PalmTool(env) -> RigidTransform:
    palm = env.plant.GetBodyByName(PALM_BODY, env.hand)
    return palm.EvalPoseInWorld(env.plant_context).InvertAndCompose(env.object_pose())


def _tool_clearance(env) -> float:
    """Smallest signed distance between the target tool and anything else (within 2 cm)."""
    query = env.station.GetOutputPort("query_object").Eval(env.station.GetMyContextFromRoot(env.context))
    inspector, tool = query.inspector(), env.object_body().index()
    distances = [pair.distance for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.02)
                 if tool in (env.plant.GetBodyFromFrameId(inspector.GetFrameId(pair.id_A)).index(),
                             env.plant.GetBodyFromFrameId(inspector.GetFrameId(pair.id_B)).index())]
    assert distances
    return min(distances)


def test_different_seeds_give_different_starts_and_a_seed_the_same(env):
    starts = [env.reset(seed=seed)[0] for seed in range(5)]
    goals = [env.goal.copy()]
    for i in range(5):
        for j in range(i):
            assert np.abs(starts[i] - starts[j]).max() > 1e-4, (i, j)
    again, _ = env.reset(seed=4)
    goals.append(env.goal.copy())
    np.testing.assert_array_equal(starts[4], again)
    np.testing.assert_array_equal(goals[0], goals[1])  # The goal follows the start: the same for the same seed.


def test_sampled_yaws_stay_within_the_range_and_vary():
    rng = np.random.default_rng(0)
    yaws = np.array([handoff.sample_fist_grasp("hammer", rng).yaw for _ in range(200)]) - TOOL_GRASPS["hammer"].yaw
    assert np.all(np.abs(yaws) <= GRASP_YAW_JITTER) and np.ptp(yaws) > GRASP_YAW_JITTER
    assert handoff.sample_fist_grasp("hammer", None) == TOOL_GRASPS["hammer"]


@pytest.mark.parametrize("yaw_offset", EXTREME_YAWS)
def test_the_ends_of_the_yaw_range_are_placed_clear_and_hold(env, monkeypatch, yaw_offset):
    grasp = dataclasses.replace(TOOL_GRASPS["hammer"], yaw=TOOL_GRASPS["hammer"].yaw + yaw_offset)
    monkeypatch.setitem(TOOL_GRASPS, "hammer", grasp)  # The nominal grasp (rng=None) is now this end.
    env.reset(seed=0)
    env.objects.park(env.context)
    env.set_target("hammer")
    env.set_robot(np.asarray(env.scenario.robot.arm_home, dtype=float),
                  np.r_[np.tile(handoff.FIST_FINGER_OPEN, 3), handoff.FIST_THUMB])
    palm = env.plant.GetBodyByName(PALM_BODY, env.hand)
    env.objects.set_pose(env.context, "hammer", palm.EvalPoseInWorld(env.plant_context) @ grasp.X_PalmT(), frozen=True)
    assert _tool_clearance(env) > 0.0005
    synthesized_tool_grasp(env, "hammer")  # Raises RuntimeError unless the hammer settled in the fist.
    env.refresh_sampled_outputs()
    start, action, lowest = _X_PalmTool(env), hold_action(env), np.inf
    for _ in range(HOLD_STEPS):
        _, _, terminated, _, info = env.step(action)
        assert not terminated and not info["simulator_error"]
        lowest = min(lowest, env.object_position()[2])
    end = _X_PalmTool(env)
    assert np.linalg.norm(end.translation() - start.translation()) < 0.01
    assert start.rotation().InvertAndCompose(end.rotation()).ToAngleAxis().angle() < 0.1
    assert lowest > TABLE_TOP + 0.1
