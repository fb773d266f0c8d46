"""Sub-task environments: registry-wide create/reset/step, the paper's observation sizes, gymnasium API."""

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from seqdex_drake.tasks.registry import default_config, make_env, task_names

PAPER_OBSERVATION_SIZE = {"search": 160, "orient": 159, "grasp": 159, "insert": 173,
                          "tool_grasp": 159, "tool_reorient": 173}
PAPER_EPISODE_LENGTH = {"search": 75, "orient": 75, "grasp": 150, "insert": 125, "tool_grasp": 150,
                        "tool_reorient": 125}


@pytest.fixture(scope="module", params=task_names())
def env(request):
    return make_env(request.param)


def test_observation_size_and_episode_length_match_the_paper(env):
    name = env.config.name
    assert env.observation_space.shape == (PAPER_OBSERVATION_SIZE[name],)
    assert env.config.episode_length == PAPER_EPISODE_LENGTH[name]
    assert env.action_space.shape == (19,)  # 16 hand joints + 3D wrist translation.


def test_reset_and_step_with_zero_and_random_actions(env):
    observation, info = env.reset(seed=3)
    assert observation.shape == env.observation_space.shape and np.all(np.isfinite(observation))
    for action in [np.zeros(19), *[env.action_space.sample() for _ in range(4)]]:
        observation, reward, terminated, truncated, info = env.step(action)
        assert np.all(np.isfinite(observation)) and np.isfinite(reward)
        assert not info["simulator_error"]
        terms = {k: v for k, v in info.items() if k.startswith("reward/")}
        assert terms and reward == pytest.approx(sum(terms.values()))


def test_reset_is_deterministic_for_a_seed(env):
    first, _ = env.reset(seed=11)
    env.step(np.full(19, 0.3))
    second, _ = env.reset(seed=11)
    np.testing.assert_array_equal(first, second)


def test_saved_state_restores_exactly(env):
    env.reset(seed=5)
    env.step(np.full(19, -0.2))
    state = env.get_state()
    observation = env.observation()
    env.reset(seed=6)
    restored, _ = env.reset(options={"initial_state": state})
    np.testing.assert_array_equal(observation, restored)


def test_bad_actions(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(19,\)"):
        env.step(np.zeros(23))
    observation, reward, terminated, truncated, info = env.step(np.full(19, np.nan))
    assert truncated and info["nan_action"] and np.all(np.isfinite(observation))


def test_gymnasium_env_checker():
    check_env(make_env("grasp"), skip_render_check=True)


def test_unknown_task_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid tasks: search"):
        default_config("dance")
