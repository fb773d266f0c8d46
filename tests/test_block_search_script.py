"""The scripted block Search (``tasks/scripted/block_search_script.py``) and the budget Search built on it: the budget
env
observes its progress and applies the script as its residual base, the script is Markov in the observation, and
alone it uncovers a target its hand hid at reset, leaving the pile in the box and the target where it was."""

import numpy as np
import pytest
from script_checks import assert_zero_corrections_apply

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, p_PalmHc_Palm, scale_action_to_limits
from seqdex_drake.scene.piles import InsideBox
from seqdex_drake.tasks.registry import budget_config, default_config
from seqdex_drake.tasks.residual import make_base
from seqdex_drake.tasks.scripted.block_search_script import ScriptedBlockSearch, run_episode


@pytest.fixture(scope="module")
def env():
    return make_env("search", budget_config("search"))


def test_budget_config_is_a_residual_on_the_script_with_progress_observed(env):
    config = budget_config("search")
    assert config.residual == "block_search_script" and config.observe_time and config.hand_actions
    assert config.ema == default_config("search").ema and config.phases is None
    assert config.success_threshold == default_config("search").success_threshold
    assert default_config("search").residual == ""  # The paper's variant is unchanged.
    assert isinstance(make_base(config.residual), ScriptedBlockSearch)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.shape == (161,) and observation[160] == 0.0  # Pixels, then the progress.
    assert observation[159] == env.task.target_pixels(env)


def test_the_script_is_markov_in_the_observation(env):
    observation, _ = env.reset(seed=5)
    first, second = ScriptedBlockSearch(), ScriptedBlockSearch()
    action = first.act(observation, 0)
    assert action.shape == (19,) and np.all(np.abs(action) <= 1.0)
    np.testing.assert_allclose(scale_action_to_limits(action[:16]), ALLEGRO_OPEN_Q, atol=1e-9)  # The open hand.
    for step in (0, 30, 74):
        np.testing.assert_array_equal(action, first.act(observation.copy(), step))  # No state, no schedule.
        np.testing.assert_array_equal(action, second.act(observation, step))
        np.testing.assert_array_equal(action, first.act(observation[:160], step))  # Progress entry or not.
    moved = observation.copy()
    moved[111] += 0.005  # The target 5 mm further along x: the hand goes after it.
    assert first.act(moved, 0)[16] > first.act(observation, 0)[16] + 0.2
    goal, hand = first.goal_and_hand(observation)
    assert abs(goal[1] - observation[112]) >= 0.14 and goal[2] > observation[113] + 0.15  # Beside and above.


def test_zero_corrections_apply_the_script(env):
    """The budget env given zeros applies exactly the script's action of its own observation."""
    assert_zero_corrections_apply(env, ScriptedBlockSearch(), seed=3, steps=4)


def test_the_script_alone_uncovers_a_target_the_hand_hid(env):
    """Seed 0: a 1x4 block on top of the pile, hidden by the open fingers at reset (3 pixels; 20 needed)."""
    episode = run_episode(env, 0)
    assert episode["start_pixels"] < 20 < episode["pixels"] and episode["success"]
    assert episode["target_moved"] < 0.02  # Where Orient and Grasp find it.
    assert np.all(InsideBox(env.objects.positions(env.context)))  # The pile is still in the box.
    observation = env.observation()
    hand = np.asarray(observation[98:101], float) + _rotation(observation[101:105]) @ p_PalmHc_Palm
    assert abs(hand[1] - observation[112]) > 0.12  # The hand is beside the target, off the camera's view of it.


def _rotation(q_wxyz) -> np.ndarray:
    from pydrake.common.eigen_geometry import Quaternion

    return Quaternion(np.asarray(q_wxyz, float) / np.linalg.norm(q_wxyz)).rotation()
