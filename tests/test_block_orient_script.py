"""The scripted block Orient (``tasks/scripted/block_orient_script.py``) and the budget block Orient built on it: the
script is
Markov in (observation, step), the budget env observes its progress and applies the script as its residual base,
and the script alone stands a lying block upright, free in the box, the fingertip moved off it."""

import math

import numpy as np
import pytest
from script_checks import assert_markov, assert_zero_corrections_apply

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.orient import default_config
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.residual import make_base
from seqdex_drake.tasks.scripted.block_orient_script import ScriptedBlockOrient, roll_angle, run_episode


@pytest.fixture(scope="module")
def env():
    return make_env("orient", budget_config("orient"))


def test_budget_config_is_a_residual_on_the_script_with_progress_observed(env):
    config = budget_config("orient")
    assert config.residual == "block_orient_script" and not config.hand_actions and config.observe_time
    assert config.ema == 1.0 and config.episode_length == default_config().episode_length == 75
    assert default_config().ema == 0.2 and default_config().residual == ""  # The paper's variant is unchanged.
    assert isinstance(make_base(config.residual), ScriptedBlockOrient)
    observation, _ = env.reset(seed=2)
    assert env.observation_space.shape == (160,) and observation[159] == 0.0  # The progress entry.
    np.testing.assert_array_equal(env.action_space.high[:16], 0.0)  # The hand is the script's.
    observation, *_ = env.step(np.zeros(19))
    assert observation[159] == np.float32(1 / 75)


def test_roll_angle_names_the_resting_poses():
    from pydrake.math import RollPitchYaw

    for roll in (0.0, math.pi / 2, -math.pi / 2):  # Upright and on either long side, at any yaw.
        assert roll_angle(RollPitchYaw(roll, 0.0, 0.7).ToRotationMatrix().matrix()) == pytest.approx(roll)
    assert abs(roll_angle(RollPitchYaw(math.pi, 0.0, -2.0).ToRotationMatrix().matrix())) == pytest.approx(math.pi)


def test_the_script_is_markov_in_observation_and_step(env):
    observation, _ = env.reset(seed=5)
    first = assert_markov(ScriptedBlockOrient, observation, (0, 6, 20, 50, 74), 159)
    moved = observation.copy()
    moved[111] += 0.05  # The block 5 cm further along x: the wrist goes after it.
    assert first.act(moved, 20)[16] > first.act(observation, 20)[16]
    assert not np.array_equal(first.act(observation, 0)[:16], first.act(observation, 20)[:16])  # The hand's schedule.


def test_zero_corrections_apply_the_script(env):
    """The budget env given zeros applies exactly the script's action of its own observation."""
    assert_zero_corrections_apply(env, ScriptedBlockOrient(), seed=3, steps=20)


@pytest.mark.parametrize("seed", [5, 11])  # A 1x3 on a long side (one roll); a 1x2 upside down (two rolls).
def test_the_script_alone_stands_the_block_upright(env, seed):
    observation, _ = env.reset(seed=seed)
    start_roll = abs(roll_angle(_rotation(observation[114:118])))
    assert start_roll > math.radians(80)  # Not upright at the start.
    episode = run_episode(env, seed)
    assert episode.success and episode.up_z > 0.95  # Upright, not just within the success cone.
    assert episode.clearance > 0.01  # The fingertip off the block (moved away, lifting): it stands free.
    # It stays up: half a second more with the hand holding its last targets, the block (a 1x2 that stood up
    # late still rocks at the episode's end) has settled on its bottom, upright.
    env.simulator.AdvanceTo(env.context.get_time() + 0.5)
    observation = env.observation()
    assert _rotation(observation[114:118])[2, 2] > 0.95
    assert np.linalg.norm(observation[118:121]) < 0.02 and np.linalg.norm(observation[121:124]) < 1.0


def _rotation(q_wxyz) -> np.ndarray:
    from pydrake.common.eigen_geometry import Quaternion

    return Quaternion(np.asarray(q_wxyz, float) / np.linalg.norm(q_wxyz)).rotation()
