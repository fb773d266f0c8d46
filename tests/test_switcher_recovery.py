"""The shipped tool chain's switcher recovers a dropped tool in the real diagram: the hammer, grasped and handed
over to tool Reorient, is knocked out of the hand onto the table a few ticks into Reorient; at the end of Reorient's
budget the trained F^reorient scores the state infeasible (c < 1) and the chain goes back to tool Grasp (paper
Sec. 3.3: a dropped object sends the chain back to the stage that picks it up). The F was fitted with knocked-out
hand-overs (``seqdex feasibility --knocked-out``). While the hammer is in hand the approach target reports it lifted,
which keeps the switcher from sending the chain back to tool Grasp with the hammer in the fist
(``ChainParams.free_object_stages``)."""

from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.tasks.tools_common import TABLE_TOP, TOOL_XY

ROOT = Path(__file__).resolve().parent.parent
#: A held-out episode (seed, episode of ``seqdex evaluate``'s hammer rows) whose grasp lifts the hammer.
SEED, EPISODE, HAMMER = 100, 9, 0


@pytest.fixture(scope="module")
def runner():
    return ChainRunner(RunConfig(family="tool_positioning", run_dir=str(ROOT / "checkpoints" / "tool_positioning"),
                                 max_switches=3, seed=SEED))


def _stage(runner) -> int:
    return int(runner.chain_output("active_stage")[0])


def _lifted(runner) -> bool:
    approach = runner.controller.GetSubsystemByName("approach_target")
    return bool(approach.GetOutputPort("object_lifted").Eval(approach.GetMyContextFromRoot(runner.context))[0])


def test_a_hammer_knocked_out_of_the_hand_sends_the_chain_back_to_tool_grasp(runner):
    runner.context.SetTime(0.0)
    name = runner.start_tool(HAMMER, np.random.default_rng([SEED, HAMMER, EPISODE]))
    ticks_in_reorient = []
    outcome = runner.run(runner.episode_limit(), stop_on_success=False,
                         on_tick=lambda r: not ticks_in_reorient.append(_stage(r) == 1) and sum(ticks_in_reorient) < 5)
    assert sum(ticks_in_reorient) == 5 and outcome.simulator_error == "", "the hammer never reached tool Reorient"
    lifted = runner.object_pose().translation()[2]
    assert _lifted(runner)  # In hand: a switch back to tool Grasp would be blocked (free_object_stages).
    switches = int(runner.chain_output("switches_used")[0])
    # Knocked out: back on the table (as it started, a little aside), the hand where it is.
    runner.objects.set_pose(runner.context, name, RigidTransform(RollPitchYaw(0.0, 0.0, 0.3),
                                                                 [TOOL_XY[0] + 0.02, TOOL_XY[1], TABLE_TOP + 0.0725]),
                            frozen=False)
    assert not _lifted(runner)
    stages = []
    runner.run(runner.episode_limit(), stop_on_success=False,
               on_tick=lambda r: not stages.append(_stage(r)) and stages[-1] == 1)
    assert stages[-1] == 0, f"the chain stayed in tool Reorient for {len(stages)} ticks with the hammer dropped"
    assert int(runner.chain_output("switches_used")[0]) == switches + 1  # A feasibility switch, not a restart.
    assert runner.object_pose().translation()[2] < lifted - 0.1  # The hammer still lay on the table.
