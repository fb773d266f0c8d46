"""The staging area (``tasks/blocks_common.STAGING_LOW``): Orient's and Grasp's resets put their block there with
``TaskConfig.reset_region = "staging"``, Grasp's script pinches a block there at its centre (the box's near-wall
bound applies only in the box) and lifts it, and ``seqdex rollout --reset-region`` refuses tasks it cannot place."""

import dataclasses

import numpy as np
import pytest

from seqdex_drake.cli.main import main
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.modeling.blocks import TOTAL_HEIGHT
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.blocks_common import STAGING_HIGH, STAGING_LOW, sample_reset_xy
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.scripted.block_grasp_script import ScriptedBlockGrasp, run_episode


def _in_box(p_xy, margin: float = 0.0) -> bool:
    return bool(np.all(np.abs(np.asarray(p_xy)[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF + margin))


def test_regions_sample_where_they_say_and_unknown_ones_are_refused():
    rng = np.random.default_rng(0)
    staged = np.array([sample_reset_xy(rng, "staging") for _ in range(200)])
    assert np.all(staged >= STAGING_LOW) and np.all(staged <= STAGING_HIGH)
    assert not any(_in_box(p, margin=0.02) for p in staged)  # Clear of the box, walls included.
    assert all(_in_box(sample_reset_xy(rng, "box")) for _ in range(50))
    with pytest.raises(ValueError, match="'table'.*box, staging"):
        sample_reset_xy(rng, "table")
    with pytest.raises(ValueError, match="reset_region must be 'box' or 'staging', got 'table'"):
        TaskConfig(name="grasp", reset_region="table")


def test_grasp_lifts_a_block_on_the_staging_area_pinched_at_its_centre():
    env = make_env("grasp", dataclasses.replace(budget_config("grasp"), reset_region="staging"))
    observation, _ = env.reset(seed=3)
    p = env.object_position()
    assert np.all(p[:2] >= STAGING_LOW) and np.all(p[:2] <= STAGING_HIGH)
    assert 0.0 < p[2] - BOX_CENTER[2] < TOTAL_HEIGHT  # Resting on the table (the box floor's height).
    script = ScriptedBlockGrasp()
    goal, _ = script.goal_and_hand(observation)
    assert goal[0] < script.x_min  # Not held back by the box's near wall, which is not there.
    episode = run_episode(env, seed=3)
    assert episode.success and episode.rise > 0.3


def test_rollout_refuses_a_region_for_a_task_without_single_block_resets(capsys):
    assert main(["rollout", "--task", "search", "--zero-action", "--reset-region", "staging", "--test"]) == 2
    assert "--reset-region" in capsys.readouterr().err
