"""A tool knocked out of the hand (``tasks/tools_common.knock_out_tool``): it lies on the table again, tool Reorient
cannot succeed from there (its success needs the tool lifted, as the chain's does), and F's knocked-out
transitions record it, in the real tool envs."""

import numpy as np

from seqdex_drake.chaining.rollouts import collect_transitions
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.registry import KNOCK_OUTS, budget_config
from seqdex_drake.tasks.rewards import goal_errors
from seqdex_drake.tasks.tools_common import HELD_LIFT, TOOL_XY, is_lifted, knock_out_tool, rest_height


def test_a_knocked_out_tool_rests_on_the_table_and_reorient_fails_from_there():
    env = make_env("tool_reorient", budget_config("tool_reorient"))
    env.reset(seed=0)  # The hammer settled in a fist at the arm's home pose.
    assert is_lifted(env)
    knock_out_tool(env, np.random.default_rng(0))
    for _ in range(30):
        _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
        if terminated or truncated:
            break
    z = env.object_pose().translation()[2]
    assert abs(z - rest_height("hammer")) < 0.01 and z < rest_height("hammer") + HELD_LIFT
    assert np.linalg.norm(env.object_pose().translation()[:2] - TOOL_XY) < 0.1
    assert not is_lifted(env) and not env.task.is_success(env)
    # Even with its goal met (the goal moved to where the tool lies), a tool on the table is no success.
    env.set_target(env.target_object, np.r_[env.object_pose().translation(),
                                            env.object_pose().rotation().ToQuaternion().wxyz()])
    env.step(np.zeros(env.action_space.shape))
    position, rotation = goal_errors(env.observation_values())
    assert position < 0.01 and rotation < 0.05 and not env.task.is_success(env)


def test_knocked_out_transitions_of_the_tool_chain():
    grasp = make_env("tool_grasp", budget_config("tool_grasp"))
    reorient = make_env("tool_reorient", budget_config("tool_reorient"))
    zero = [lambda obs, env=env: np.zeros(env.action_space.shape) for env in (grasp, reorient)]
    data = collect_transitions([grasp, reorient], zero, 1, episodes=0, seed=3, history=10, knocked_out=1,
                               knock_out=KNOCK_OUTS["tool_grasp"])
    assert data.histories.shape == (1, 10, 160) and not data.successes[0]
    # The last 10 observations of tool Grasp (its layout, progress last) show the hammer back on the table.
    assert np.all(data.histories[0, :, 113] < rest_height("hammer") + HELD_LIFT) and data.histories[0, -1, -1] == 1.0
