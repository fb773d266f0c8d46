"""The scripted block Grasp (``tasks/scripted/block_grasp_script.py``) and the budget block Grasp built on it: the
script is
Markov in (observation, step), the budget env observes its progress and applies the script as its residual base,
the script alone lifts a block out of the box, and the phases lift the wrist from step 75 whatever the policy
sends."""

import dataclasses

import numpy as np
import pytest
from script_checks import assert_markov, assert_zero_corrections_apply

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.robots.allegro import p_PalmHc_Palm
from seqdex_drake.tasks.phases import apply_phases, release_block_grasp_phases
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.residual import make_base
from seqdex_drake.tasks.scripted.block_grasp_script import ScriptedBlockGrasp, run_episode


@pytest.fixture(scope="module")
def env():
    return make_env("grasp", budget_config("grasp"))


def test_budget_config_is_a_residual_on_the_script_with_progress_observed(env):
    config = budget_config("grasp")
    assert config.residual == "block_grasp_script" and not config.hand_actions
    assert config.phases == release_block_grasp_phases() and config.observe_time and config.reward.lift > 0
    assert isinstance(make_base(config.residual), ScriptedBlockGrasp)
    observation, _ = env.reset(seed=2)
    assert env.observation_space.shape == (160,) and observation[159] == 0.0  # The progress entry.
    np.testing.assert_array_equal(env.action_space.high[:16], 0.0)  # The hand is the script's.
    observation, _, _, _, info = env.step(np.zeros(19))
    assert observation[159] == np.float32(1 / 150) and "reward/lift" in info


def test_the_script_is_markov_in_observation_and_step(env):
    observation, _ = env.reset(seed=5)
    first = assert_markov(ScriptedBlockGrasp, observation, (0, 10, 40, 74, 100), 159)
    moved = observation.copy()
    moved[111] += 0.05  # The block 5 cm further along x: the wrist goes after it.
    assert first.act(moved, 10)[16] > first.act(observation, 10)[16]
    assert not np.array_equal(first.act(observation, 0)[:16], first.act(observation, 40)[:16])  # The hand's schedule.


def test_zero_corrections_apply_the_script(env):
    """The budget env given zeros applies exactly the script's action of its own observation."""
    assert_zero_corrections_apply(env, ScriptedBlockGrasp(), seed=3, steps=20)


@pytest.mark.parametrize("seed", [2, 11])  # A 1x4 pinched across its width; a 1x2 at yaw 0, pinched as it turns.
def test_the_script_alone_lifts_the_block_out_of_the_box(env, seed):
    episode = run_episode(env, seed)
    assert episode.success
    assert episode.rise > 0.30 and episode.fingertip_distance < 0.4  # Lifted, and in hand.
    observation = env.observation()
    hand = observation[98:101] + _rotation(observation[101:105]) @ p_PalmHc_Palm
    assert np.linalg.norm(observation[111:114] - hand) < 0.1  # Still between the fingers at the end.


def test_phases_lift_the_wrist_from_step_75_whatever_the_policy_sends(env):
    phases = release_block_grasp_phases()
    action, previous = [0.3] * 16 + [0.5, -0.5, -1.0], [0.1] * 16 + [0.0] * 3
    assert apply_phases(phases, 74, action, previous) == (action, False)  # The policy's own.
    lifted, frozen = apply_phases(phases, 75, action, previous)
    assert lifted == [0.3] * 16 + [0.0, 0.0, 1.0] and not frozen  # Lifting; the hand is the policy's.
    assert apply_phases(phases, 149, action, previous)[0][16:] == [0.0, 0.0, 1.0]

    config = dataclasses.replace(budget_config("grasp"), episode_length=90)
    downward = make_env("grasp", config)  # A policy pushing the wrist down all along.
    downward.reset(seed=2)
    heights = []
    for _ in range(90):
        downward.step(np.r_[np.zeros(16), 0.0, 0.0, -1.0])
        heights.append(downward.ik.palm_point(downward._arm_target)[2])
    env.reset(seed=2)  # The script alone rises to its approach height over its first steps ...
    start = env.ik.palm_point(env._arm_target)[2]
    for _ in range(8):
        env.step(np.zeros(19))
    assert env.ik.palm_point(env._arm_target)[2] - start > 0.02
    assert abs(heights[7] - heights[0]) < 0.005  # ... the policy's correction (down) applies before step 75 ...
    assert abs(heights[74] - heights[73]) < 1e-3  # ... here cancelling the script's early lift (+1 - 1).
    rises = np.diff(heights[74:])  # heights[k] is the target after step k.
    np.testing.assert_allclose(rises, config.wrist_step, rtol=0.05)  # The scripted lift from step 75 on (IK: ~98 %).


def _rotation(q_wxyz) -> np.ndarray:
    from pydrake.common.eigen_geometry import Quaternion

    return Quaternion(np.asarray(q_wxyz, float) / np.linalg.norm(q_wxyz)).rotation()
