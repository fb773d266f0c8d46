"""Gymnasium ids of the sub-task envs (``gym.make("seqdex/Grasp-v0")``), their time limits, keyword overrides and
the reduced-action wrapper for wrist-only tasks, and the budget variants' own ids with their reduced action spaces."""

import dataclasses
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.passive_env_checker import check_action_space

import seqdex_drake  # noqa: F401 (registers the ids)
from seqdex_drake.envs.registration import BUDGET_GYM_IDS, GYM_IDS, gym_id, make_budget_env
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.envs.wrappers import FreeActionsWrapper
from seqdex_drake.tasks.registry import budget_config, default_config, task_names

# gym.make's own checker warns about the wrist-only tasks' fixed hand dims (what FreeActionsWrapper removes).
pytestmark = pytest.mark.filterwarnings("ignore:.*maximum and minimum values are equal")


def _episode_length(env, action) -> tuple[int, bool, bool]:
    """Steps ``action`` from ``reset(seed=0)`` until the episode ends: (steps, terminated, truncated)."""
    env.reset(seed=0)
    steps = 0
    while True:
        _, _, terminated, truncated, _ = env.step(action)
        steps += 1
        if terminated or truncated:
            return steps, terminated, truncated


def test_every_subtask_is_registered_lazily():
    assert list(GYM_IDS) == task_names()
    assert GYM_IDS["tool_reorient"] == "seqdex/ToolReorient-v0" and GYM_IDS["reach"] == "seqdex/Reach-v0"
    for task, env_id in GYM_IDS.items():
        spec = gym.spec(env_id)
        assert spec.max_episode_steps == default_config(task).episode_length
        assert spec.kwargs == {"task": task}
    with pytest.raises(ValueError, match="valid tasks"):
        gym_id("juggle")
    # A fresh interpreter: the ids exist after `import seqdex_drake`, which builds no env and loads no torch.
    code = ("import sys, gymnasium, seqdex_drake; assert 'seqdex/Lower-v0' in gymnasium.registry; "
            "print('torch' in sys.modules, 'seqdex_drake.envs.subtask_env' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False"]


def test_budget_variants_have_their_own_ids_and_only_free_action_dims():
    assert set(BUDGET_GYM_IDS) == {"search", "orient", "grasp", "insert", "tool_grasp", "tool_reorient"}
    assert BUDGET_GYM_IDS["tool_grasp"] == "seqdex/ToolGraspBudget-v0"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # The env checker's "maximum and minimum values are equal" included.
        env = gym.make(BUDGET_GYM_IDS["grasp"])
        space = env.action_space
        assert space.shape == (3,) and np.all(space.low < space.high)  # The wrist residual, hand pinned.
        assert env.spec.max_episode_steps == budget_config("grasp").episode_length
        assert env.unwrapped.config == budget_config("grasp")
        observation, _ = env.reset(seed=0)
        observation, *_ = env.step(space.sample())
        assert observation.shape == env.observation_space.shape
    full = make_env("grasp", budget_config("grasp")).action_space
    assert full.shape == (19,) and int(np.sum(full.low == full.high)) == 16
    with pytest.raises(ValueError, match="no small-budget variant"):
        make_budget_env("reach")


@pytest.mark.parametrize("task", task_names())
def test_make_resets_and_steps(task):
    env = gym.make(GYM_IDS[task])
    assert env.spec.id == GYM_IDS[task]
    assert env.spec.max_episode_steps == default_config(task).episode_length == env.unwrapped.config.episode_length
    observation, info = env.reset(seed=0)
    assert observation.shape == env.observation_space.shape and "success" in info
    env.action_space.seed(0)
    observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert observation.shape == env.observation_space.shape and np.isfinite(observation).all()
    assert np.isfinite(reward) and not truncated and not info["simulator_error"]


def test_time_limit_and_env_agree():
    # Default: the spec's limit is the env's own episode length (both end the episode at the same step).
    steps, terminated, truncated = _episode_length(gym.make("seqdex/Lower-v0"), np.zeros(19))
    assert (steps, terminated, truncated) == (15, False, True)
    # max_episode_steps shortens or lengthens the env's own episodes too.
    for limit in (4, 20):
        env = gym.make("seqdex/Lower-v0", max_episode_steps=limit)
        assert env.spec.max_episode_steps == limit == env.unwrapped.config.episode_length
        assert _episode_length(env, np.zeros(19))[0] == limit
    # No TimeLimit at all: the env still ends its episodes at its config's length.
    env = gym.make("seqdex/Lower-v0", max_episode_steps=-1)
    assert env.spec.max_episode_steps is None and _episode_length(env, np.zeros(19))[0] == 15


def test_config_overrides_pass_through_make():
    config = dataclasses.replace(default_config("lower"), episode_length=5, ema=0.5)
    env = gym.make("seqdex/Lower-v0", config=config, max_episode_steps=5)
    assert env.unwrapped.config.ema == 0.5 and _episode_length(env, np.zeros(19))[0] == 5
    assert env.spec.kwargs["config"] == config and env.unwrapped.config is not config  # The env has its own copy.
    env = gym.make("seqdex/Reach-v0", wrist_step=0.002, hover_height=0.06)
    assert (env.unwrapped.config.wrist_step, env.unwrapped.config.hover_height) == (0.002, 0.06)
    # The recorded spec re-creates the same env.
    again = gym.make(env.spec)
    assert again.unwrapped.config == env.unwrapped.config and again.spec.max_episode_steps == 30
    # A config episode length the TimeLimit does not share is refused, naming the fix.
    with pytest.raises(ValueError, match="max_episode_steps=5"):
        gym.make("seqdex/Lower-v0", config=config)
    with pytest.raises(ValueError, match="max_episode_steps=7"):
        gym.make("seqdex/Lower-v0", episode_length=7, max_episode_steps=9)
    with pytest.raises(ValueError, match="not 'lower'"):
        gym.make("seqdex/Lower-v0", config=default_config("reach"))
    with pytest.raises(ValueError, match="must be a TaskConfig"):
        gym.make("seqdex/Lower-v0", config={"episode_length": 5})
    with pytest.raises(ValueError, match=r"\['wrist_speed'\]"):
        gym.make("seqdex/Lower-v0", wrist_speed=0.1)


def test_preset_selects_the_training_variant():
    budget = gym.make("seqdex/ToolGrasp-v0", preset="budget", max_episode_steps=3)
    assert budget.unwrapped.config == dataclasses.replace(budget_config("tool_grasp"), episode_length=3)
    assert budget.unwrapped.config != dataclasses.replace(default_config("tool_grasp"), episode_length=3)
    assert _episode_length(budget, np.zeros(19))[0] == 3
    assert gym.make("seqdex/Lower-v0", preset="paper").unwrapped.config == default_config("lower")
    with pytest.raises(ValueError, match="not both"):
        gym.make("seqdex/Lower-v0", preset="paper", config=default_config("lower"))
    with pytest.raises(ValueError, match="unknown preset 'cheap'"):
        gym.make("seqdex/Lower-v0", preset="cheap")


def _space_warnings(space) -> list[str]:
    """The warnings gymnasium's checker gives for action space ``space``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_action_space(space)
    return [str(warning.message) for warning in caught]


def test_check_env_passes_with_and_without_free_actions():
    env = gym.make("seqdex/Reach-v0")
    check_env(env.unwrapped, skip_render_check=True)
    reduced = FreeActionsWrapper(env)
    check_env(reduced, skip_render_check=True)
    # The 16 fixed hand dims are what the checker warns about; the wrapper removes them.
    assert any("maximum and minimum values are equal" in message for message in _space_warnings(env.action_space))
    assert _space_warnings(reduced.action_space) == []


def test_free_actions_wrapper_on_a_wrist_only_task():
    full = gym.make("seqdex/Lower-v0")
    reduced = FreeActionsWrapper(gym.make("seqdex/Lower-v0"))
    assert reduced.action_space.shape == (3,) and reduced.free_indices.tolist() == [16, 17, 18]
    np.testing.assert_array_equal(reduced.action_space.low, -1.0)
    np.testing.assert_array_equal(reduced.action_space.high, 1.0)
    action = np.array([0.3, -0.7, 0.9], np.float32)
    mapped = reduced.action(action)
    assert mapped.shape == (19,) and not mapped[:16].any()
    np.testing.assert_array_equal(mapped[16:], action)
    np.testing.assert_array_equal(reduced.reverse_action(mapped), action)
    # Stepping the wrapper with the reduced action is stepping the env with the full one.
    np.testing.assert_array_equal(full.reset(seed=4)[0], reduced.reset(seed=4)[0])
    for _ in range(3):
        expected, reward, *_ = full.step(mapped)
        observation, reduced_reward, *_ = reduced.step(action)
        np.testing.assert_array_equal(observation, expected)
        assert reduced_reward == reward
    assert reduced.spec.additional_wrappers[-1].name == "FreeActionsWrapper"
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        reduced.step(np.zeros(19))


def test_free_actions_wrapper_keeps_a_full_action_space():
    env = FreeActionsWrapper(make_env("grasp"))
    assert env.action_space == make_env("grasp").action_space and env.free_indices.tolist() == list(range(19))


class _FixedDimsEnv(gym.Env):
    """A one-step env whose action dims 0 and 2 are fixed (at 0.25 and -0.5); it records the action it gets."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, low, high):
        self.action_space = gym.spaces.Box(np.array(low, np.float32), np.array(high, np.float32))
        self.last_action = None

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.last_action = np.array(action)
        return np.zeros(1, np.float32), 0.0, True, False, {}


def test_free_actions_wrapper_fills_fixed_dims_with_their_value():
    env = _FixedDimsEnv([0.25, -1.0, -0.5, 0.0], [0.25, 1.0, -0.5, 2.0])
    wrapper = FreeActionsWrapper(env)
    assert wrapper.action_space.shape == (2,) and wrapper.free_indices.tolist() == [1, 3]
    np.testing.assert_array_equal(wrapper.action_space.low, [-1.0, 0.0])
    np.testing.assert_array_equal(wrapper.action_space.high, [1.0, 2.0])
    wrapper.reset(seed=0)
    wrapper.step(np.array([0.5, 1.5], np.float32))
    np.testing.assert_array_equal(env.last_action, [0.25, 0.5, -0.5, 1.5])
    with pytest.raises(ValueError, match="nothing for an agent to choose"):
        FreeActionsWrapper(_FixedDimsEnv([0.0, 1.0], [0.0, 1.0]))
    with pytest.raises(ValueError, match="finite action bounds"):
        FreeActionsWrapper(_FixedDimsEnv([-np.inf, 0.0], [0.0, 1.0]))
    discrete = _FixedDimsEnv([0.0], [1.0])
    discrete.action_space = gym.spaces.Discrete(3)
    with pytest.raises(ValueError, match="one-dimensional Box"):
        FreeActionsWrapper(discrete)
