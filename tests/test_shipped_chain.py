"""The shipped Tool Positioning chain works: from a fixed seed, the chain runner with the repository's checkpoints
(``checkpoints/tool_positioning``, loaded by default by ``scripts/simulate_chain.py``) grasps the hammer and
re-orients it in hand to within tool Reorient's success tolerance (a physical check of the final pose)."""

import types
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake.evaluation.runner import TOOL_GOAL_LIFT, TOOL_HELD_LIFT, TOOL_TOLERANCE, ChainRunner, RunConfig
from seqdex_drake.tasks.tools_common import TABLE_TOP

SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints" / "tool_positioning"
#: An evaluation episode (seed, hammer, episode) in which the shipped chain succeeds (``seqdex evaluate`` seeds its
#: episodes the same way: ``default_rng([seed, tool, episode])``).
EPISODE = (0, 0, 1)


def test_the_shipped_chain_reorients_the_hammer_in_hand():
    runner = ChainRunner(RunConfig(family="tool_positioning", run_dir=str(SHIPPED), max_switches=3))
    assert runner.shipped is not None and runner.untrained == [] and runner.missing == []
    assert all(path is not None for path in runner.shipped.feasibility[1:])
    runner.context.SetTime(0.0)
    name = runner.start_tool(0, np.random.default_rng(list(EPISODE)))
    assert name == "hammer"
    outcome = runner.run(runner.episode_limit())
    pose = runner.object_pose()
    # The hammer is turned about its handle to within the success tolerance of its goal orientation ...
    assert outcome.rotation_error < TOOL_TOLERANCE, outcome
    # ... and held above the table: lifted at least half the goal's lift from where it lay.
    start_height = runner.goal[2] - TOOL_GOAL_LIFT
    assert pose.translation()[2] > start_height + TOOL_HELD_LIFT > TABLE_TOP
    assert outcome.success and outcome.last_stage == 1


@pytest.mark.parametrize("tool", [1, 2])
def test_the_shipped_chain_runs_the_unseen_tools(tool):
    """Spatula and spoon (never trained on) run through the same chain without error; whether they succeed is
    measured by ``seqdex evaluate`` (results/tool_positioning.md), not asserted."""
    runner = ChainRunner(RunConfig(family="tool_positioning", run_dir=str(SHIPPED), max_switches=0))
    runner.start_tool(tool, np.random.default_rng([0, tool, 0]))
    outcome = runner.run(2.0)
    assert np.isfinite(outcome.rotation_error) and np.isfinite(outcome.position_error)


def test_a_simulator_failure_ends_the_episode_as_a_failure():
    """A failed step (pydrake raises failed assertions, e.g. a non-finite state, as SystemExit) fails the episode
    and names the error instead of ending the evaluation; the next episode starts from a clean scene."""
    runner = ChainRunner(RunConfig(family="tool_positioning", untrained_hidden_sizes=(16,)))
    runner.start_tool(0, np.random.default_rng(0))
    simulator = runner.simulator

    def failing(time):
        raise SystemExit("Failure at multibody_plant.h in SetPositions(): condition 'AllFinite(q)' failed.")

    runner.simulator = types.SimpleNamespace(AdvanceTo=failing)  # The next step fails, as a diverged one does.
    outcome = runner.run(1.0)
    assert not outcome.success and "AllFinite" in outcome.simulator_error and np.isnan(outcome.rotation_error)
    runner.simulator = simulator
    runner.start_tool(0, np.random.default_rng(0))
    outcome = runner.run(0.1)
    assert outcome.simulator_error == "" and np.isfinite(outcome.rotation_error)


def test_a_diverged_but_finite_state_ends_the_episode_as_a_failure():
    """A blown-up state that is still finite (Drake steps on) fails the episode with a message, instead of the
    wake check's arithmetic overflowing and ending the evaluation."""
    runner = ChainRunner(RunConfig(family="tool_positioning", untrained_hidden_sizes=(16,)))
    runner.start_tool(0, np.random.default_rng(0))
    simulator = runner.simulator

    def diverging(time):
        simulator.AdvanceTo(time)
        q = runner.plant.GetPositions(runner.plant_context)
        q[-3:] = 1e160  # The last free body's position, as a diverged spoon episode left it.
        runner.plant.SetPositions(runner.plant_context, q)

    runner.simulator = types.SimpleNamespace(AdvanceTo=diverging)
    outcome = runner.run(1.0)
    assert not outcome.success and "diverged" in outcome.simulator_error and np.isnan(outcome.position_error)
