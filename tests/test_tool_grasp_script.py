"""The scripted tool_grasp demonstrator: it picks the hammer up on two fixed seeds and keeps the phase rules
(free wrist in steps 0-59, wrist exactly [0, 0, 1] in 60-89, a constant action from 90 on)."""

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import SubtaskEnv
from seqdex_drake.tasks.registry import make_task
from seqdex_drake.tasks.scripted.tool_grasp_script import ScriptedToolGrasp, run_episode


@pytest.fixture(scope="module")
def env():
    return SubtaskEnv(make_task("tool_grasp"))


@pytest.mark.parametrize("seed", [19, 24])
def test_scripted_tool_grasp_lifts_the_hammer(env, seed):
    success, actions = run_episode(env, seed, ScriptedToolGrasp())
    assert success
    assert actions.shape == (150, 19)
    assert np.all(np.abs(actions) <= 1.0)
    np.testing.assert_array_equal(actions[60:90, 16:], np.tile([0.0, 0.0, 1.0], (30, 1)))
    np.testing.assert_array_equal(actions[90:, 16:], 0.0)
    np.testing.assert_array_equal(actions[90:, :16], np.tile(actions[89, :16], (60, 1)))
