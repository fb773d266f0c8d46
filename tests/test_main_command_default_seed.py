"""The README's main command (``scripts/simulate_chain.py``: the default manual, the shipped checkpoints, 3
switches) from its default seed places its first block: the chain fetches the manual's first block, a type-5 1x4,
from the 72-block pile; Search uncovers it, the scripted retrieve takes it out of the pile and sets it down on the
staging area, Orient stands it up there, and after the switcher's restarts Grasp lifts it and Insert seats it on
its goal on the baseplate (about 42 s simulated, about 2.5 min on a core). The episode's record is the one
``experiments/main_command_seeds.py`` wrote for this seed in ``results/building_blocks/main_command_first_block.json``
(the same seed gives the same record); ``results/building_blocks.md`` gives the other seeds."""

import json
from pathlib import Path

import numpy as np

from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, goal_vector
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.retrieve import block_staged

DEFAULT_SEED = 0  # scripts/simulate_chain.py's default.
REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "checkpoints" / "building_blocks"
RECORD = REPO / "results" / "building_blocks" / "main_command_first_block.json"
UPRIGHT = np.cos(np.radians(20.0))


def test_the_main_command_places_its_first_block_from_its_default_seed():
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=str(SHIPPED), max_switches=3,
                                   seed=DEFAULT_SEED))
    assert runner.untrained == [] and runner.tasks == ["search", "retrieve", "orient", "grasp", "insert"]
    step = LoadManual("small_wall").steps[0]
    name = runner.start_block(step.block_type, goal_vector(step))
    assert name.startswith(f"block_{step.block_type}_")
    assert np.all(np.abs(runner.object_pose().translation()[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF)  # In the box.
    entered = []  # (stage, block pose, block z axis's world z) as each stage starts.

    def watch(r: ChainRunner) -> bool:
        stage = r.tasks[int(r.chain_output("active_stage")[0])]
        if not entered or entered[-1][0] != stage:
            X = r.object_pose()
            entered.append((stage, X, float(X.rotation().matrix()[2, 2])))
        return True

    outcome = runner.run(runner.episode_limit(), on_tick=watch)
    assert outcome.simulator_error == "" and not outcome.fell
    assert [stage for stage, _, _ in entered[:3]] == ["search", "retrieve", "orient"]
    _, X_orient, _ = entered[2]
    assert block_staged(X_orient, step.block_type)  # The retrieve set it down out of the pile, alone.
    assert not np.all(np.abs(X_orient.translation()[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF)
    grasp_starts = [up_z for stage, _, up_z in entered if stage == "grasp"]
    assert grasp_starts and grasp_starts[-1] >= UPRIGHT  # Stood up when Grasp started on it.
    assert outcome.success and runner.is_success()  # Seated on its goal, let go, at rest.
    assert outcome.position_error < 0.02 and outcome.rotation_error < 0.2
    recorded = next(row for row in json.loads(RECORD.read_text())["per_block"] if row["seed"] == DEFAULT_SEED)
    assert (name, round(outcome.time, 2), round(float(outcome.position_error), 4),
            round(float(outcome.rotation_error), 4), int(outcome.switches)) == \
        (recorded["block"], recorded["time"], recorded["position_error"], recorded["rotation_error"],
         recorded["switches"])  # The recorded episode, replayed.
