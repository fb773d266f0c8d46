"""The README's main command (``scripts/simulate_chain.py``: the default manual, the shipped checkpoints, 3
switches) from its default seed: the chain fetches the manual's first block, a type-5 1x4, from the 72-block pile
and works it through its stages in the pile, without a simulator failure. It does not place it: with the pinned
numerics the main command places its first block from none of 32 seeds (``results/building_blocks.md``), so no
seed can be picked for a seat here until the stages work in the pile (issue 38). About 1.5 min on a core."""

from pathlib import Path

import numpy as np

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, goal_vector

DEFAULT_SEED = 0  # scripts/simulate_chain.py's default.
SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints" / "building_blocks"


def test_the_main_command_works_the_first_block_through_the_chain_from_its_default_seed():
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=str(SHIPPED), max_switches=3,
                                   seed=DEFAULT_SEED))
    assert runner.untrained == []
    step = LoadManual("small_wall").steps[0]
    name = runner.start_block(step.block_type, goal_vector(step))
    assert name.startswith(f"block_{step.block_type}_")
    start = runner.object_pose().translation().copy()
    stages, touched = set(), []

    def watch(r: ChainRunner) -> bool:
        stages.add(int(r.chain_output("active_stage")[0]))
        touched.append(r.objects.touches_robot(r.plant_context, name))
        return True

    outcome = runner.run(runner.episode_limit(), on_tick=watch)
    assert outcome.simulator_error == "" and not outcome.fell
    assert np.all(np.isfinite(runner.plant.GetPositionsAndVelocities(runner.plant_context)))
    # The chain got past Search to the stages that handle the block, and the hand handled it: it touched the
    # block and moved it from where the pile held it.
    assert max(stages) >= runner.tasks.index("orient") and any(touched)
    assert np.linalg.norm(runner.object_pose().translation() - start) > 0.01
    assert outcome.switches >= 1  # The switcher acted (F^orient scores Search's first tick above 1).
