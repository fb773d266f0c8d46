"""The README's main command (``scripts/simulate_chain.py``: the default manual, the shipped checkpoints, 3
switches) seats a block: from a fixed seed its chain puts the manual's first block, a type-5 1x4 fetched from the
72-block pile, onto its studs on the baseplate. A physical check of the block's pose, not the runner's verdict alone.

Seed 4 is one of the seeds the main command places the first block from (``results/building_blocks.md``: the main
command's first block, 32 seeds); about 1.5 min on a core."""

from pathlib import Path

import numpy as np

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, goal_vector
from seqdex_drake.modeling.blocks import STUD_HEIGHT

SEED = 4
SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints" / "building_blocks"


def test_the_main_command_seats_the_default_manuals_first_block_from_a_fixed_seed():
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=str(SHIPPED), max_switches=3, seed=SEED))
    assert runner.untrained == []
    step = LoadManual("small_wall").steps[0]
    name = runner.start_block(step.block_type, goal_vector(step))
    assert name.startswith(f"block_{step.block_type}_")
    outcome = runner.run(runner.episode_limit())
    X_WB = runner.object_pose()
    offset = X_WB.translation() - runner.goal[:3]
    # Seated: on its cell (within 5 mm across), down on the studs (a block resting on their tops stands STUD_HEIGHT
    # higher), level and at its goal's yaw (or the yaw-flipped one: the same seat), released and at rest.
    assert np.linalg.norm(offset[:2]) < 0.005, offset
    assert abs(offset[2]) < STUD_HEIGHT / 4, offset
    assert runner.errors()[1] < np.deg2rad(3), runner.errors()
    assert X_WB.rotation().matrix()[2, 2] > np.cos(np.deg2rad(3))
    assert not runner.objects.touches_robot(runner.plant_context, name)
    assert outcome.success and outcome.simulator_error == ""
