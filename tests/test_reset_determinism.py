"""A seeded reset is a full reset: whatever an environment did before, ``reset(seed=s)`` followed by the same
actions gives the same trajectory as a fresh environment's, bit for bit.

For every registered sub-task, one env plays an episode with random actions (seeded like the later one, so that
it stirs the very objects the later episode starts among: Search's pile around the target), then both it and a
fresh env are reset with the same seed and given the same random actions. The restorable env states right after
the reset (plant state, freezer state, wake/sleep bookkeeping, targets, previous action, time) and every step's
observation, reward, flags and info must be equal.
"""

import dataclasses

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.randomization_config import RandomizationConfig
from seqdex_drake.tasks.registry import default_config, task_names

SEED = 9
PREVIOUS_STEPS = 8  # Search's ~5 steps/s set the scale; 8 steps leave blocks moving when the episode ends.
STEPS = {"search": 4}  # Steps compared after the reset (Search steps slowly; others are cheap).
DEFAULT_STEPS = 6


def _states_equal(a, b) -> None:
    """Asserts two :class:`~seqdex_drake.envs.subtask_env.EnvState` are equal in every field."""
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, dict):
            assert x.keys() == y.keys(), field.name
            for key in x:
                np.testing.assert_array_equal(x[key], y[key], err_msg=f"{field.name}[{key}]")
        else:
            np.testing.assert_array_equal(x, y, err_msg=field.name)


def _rollout(env, actions: np.ndarray) -> list[tuple]:
    """(observation, reward, terminated, truncated, info) of each step."""
    return [env.step(action) for action in actions]


def _assert_same_episode(used, fresh, actions: np.ndarray) -> None:
    """Resets both envs with :data:`SEED` and checks they start and continue identically under ``actions``."""
    first = [env.reset(seed=SEED) for env in (used, fresh)]
    np.testing.assert_array_equal(first[0][0], first[1][0], err_msg="reset observation")
    assert first[0][1] == first[1][1]
    _states_equal(used.get_state(), fresh.get_state())
    for k, (a, b) in enumerate(zip(_rollout(used, actions), _rollout(fresh, actions), strict=True)):
        np.testing.assert_array_equal(a[0], b[0], err_msg=f"observation of step {k}")
        assert a[1:4] == b[1:4], f"reward, terminated, truncated of step {k}"
        assert a[4] == b[4], f"info of step {k}"


def _play(env, rng: np.random.Generator, steps: int) -> None:
    env.reset(seed=SEED)
    for action in rng.uniform(-1.0, 1.0, size=(steps, 19)):
        env.step(action)


@pytest.mark.parametrize("name", task_names())
def test_a_seeded_reset_forgets_the_previous_episode(name):
    steps = STEPS.get(name, DEFAULT_STEPS)
    # The episode ends (truncated) at the last compared step, so the flag is compared too.
    config = dataclasses.replace(default_config(name), episode_length=steps)
    used, fresh = make_env(name, config), make_env(name, config)
    rng = np.random.default_rng(0)
    _play(used, rng, PREVIOUS_STEPS)
    _assert_same_episode(used, fresh, rng.uniform(-1.0, 1.0, size=(steps, 19)))


def test_a_seeded_reset_forgets_the_previous_randomization():
    """With domain randomization on (the paper's table), a seeded reset re-draws every physical parameter, so
    the previous episode's draw must not leak into the new one, not even into a reset that simulates."""
    name = "tool_grasp"  # Its reset simulates (the tool settles on the table): with the physical parameters in force.
    config = dataclasses.replace(default_config(name), episode_length=DEFAULT_STEPS,
                                 randomization=RandomizationConfig.paper())
    used, fresh = make_env(name, config), make_env(name, config)
    rng = np.random.default_rng(1)
    used.reset(seed=SEED + 1)  # Another seed: other physical parameters than those of the compared episode.
    for action in rng.uniform(-1.0, 1.0, size=(PREVIOUS_STEPS, 19)):
        used.step(action)
    _assert_same_episode(used, fresh, rng.uniform(-1.0, 1.0, size=(DEFAULT_STEPS, 19)))
