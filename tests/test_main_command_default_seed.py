"""The README's main command (``scripts/simulate_chain.py``: the default manual, the shipped checkpoints, 3
switches) from its default seed: the chain fetches the manual's first block, a type-5 1x4, from the 72-block pile;
Search uncovers it, the scripted retrieve takes it out of the pile and sets it down on the staging area, and Orient
stands it up there. The test stops when Orient's first attempt ends (about 14 s simulated, under a minute on a
core). From this seed the chain does not go on to place the block: Grasp does not lift it (it was set down 5 cm off
the staging point, toward the baseplate); ``results/building_blocks.md`` gives the seeds that place it."""

from pathlib import Path

import numpy as np

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, goal_vector
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.scripted.block_retrieve_script import on_staging_area

DEFAULT_SEED = 0  # scripts/simulate_chain.py's default.
SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints" / "building_blocks"
UPRIGHT = np.cos(np.radians(20.0))


def test_the_main_command_takes_its_first_block_out_of_the_pile_and_stands_it_up_from_its_default_seed():
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=str(SHIPPED), max_switches=3,
                                   seed=DEFAULT_SEED))
    assert runner.untrained == [] and runner.tasks == ["search", "retrieve", "orient", "grasp", "insert"]
    step = LoadManual("small_wall").steps[0]
    name = runner.start_block(step.block_type, goal_vector(step))
    assert name.startswith(f"block_{step.block_type}_")
    assert np.all(np.abs(runner.object_pose().translation()[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF)  # In the box.
    entered = []  # (stage, block position, block z axis's world z) as each stage starts.

    def watch(r: ChainRunner) -> bool:
        stage = r.tasks[int(r.chain_output("active_stage")[0])]
        if not entered or entered[-1][0] != stage:
            X = r.object_pose()
            entered.append((stage, X.translation().copy(), float(X.rotation().matrix()[2, 2])))
        return len(entered) < 4  # Until Orient's first attempt has ended.

    outcome = runner.run(runner.episode_limit(), on_tick=watch)
    assert outcome.simulator_error == "" and not outcome.fell
    assert [stage for stage, _, _ in entered[:3]] == ["search", "retrieve", "orient"]
    _, p_orient, _ = entered[2]
    assert on_staging_area(p_orient)  # The retrieve set it down out of the pile, alone.
    assert not np.all(np.abs(p_orient[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF)
    assert entered[3][2] >= UPRIGHT  # Orient stood it up.
