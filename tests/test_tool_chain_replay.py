"""The shipped tool chain is reproducible: recorded ``seqdex evaluate`` episodes (``results/tool_positioning/
eval_switcher``, held-out seeds; the trained F^reorient hands the hammer over in them) replay bit-identically in a
fresh runner, whatever episodes the recording's worker ran before them, on the CPU model that made them (its table
names it: the pinned kernels still round differently on other CPU models, docs/architecture.md)."""

import json
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake import numerics
from seqdex_drake.evaluation.episodes import run_config, run_episode
from seqdex_drake.evaluation.experiments import EvalConfig
from seqdex_drake.evaluation.runner import ChainRunner

ROOT = Path(__file__).resolve().parent.parent
RECORDS = ROOT / "results" / "tool_positioning" / "eval_switcher" / "episodes.jsonl"
#: The evaluation of the record: ``seqdex evaluate --task tool_positioning --seed 100 --seeds 3 --objects hammer
#: --max-switches 3 --run-dir checkpoints/tool_positioning`` (experiments/evaluate_tool_positioning.sh; the tool
#: chain's switcher trigger, ``chain_settings.SWITCH_TRIGGER``).
CONFIG = EvalConfig(family="tool_positioning", run_dir=str(ROOT / "checkpoints" / "tool_positioning"),
                    seeds=(100, 101, 102), max_switches=3)
#: Recorded episodes (seed, episode) to replay: the hammer grasped, handed over, turned (a few seconds each).
REPLAYED = [(100, 5), (100, 9)]
HAMMER = 0
TAGS = ("experiment", "setting", "seed", "object", "episode")


@pytest.fixture(scope="module")
def runner():
    return ChainRunner(run_config(CONFIG))


def _record(seed: int, episode: int) -> dict:
    for line in RECORDS.read_text().splitlines():
        record = json.loads(line)
        if (record["experiment"], record["seed"], record["object"], record["episode"]) == ("main", seed, HAMMER,
                                                                                           episode):
            return {key: value for key, value in record.items() if key not in TAGS}
    raise AssertionError(f"{RECORDS} has no episode ({seed}, {episode}): regenerate the test's choice with it")


def _made_on() -> str:
    table = (RECORDS.parent / "table2_tool_positioning.md").read_text().splitlines()
    return next((line.lstrip("- ") for line in table if "made on:" in line), "the record's machine is not named")


@pytest.mark.parametrize(("seed", "episode"), REPLAYED)
def test_recorded_episodes_replay_bit_identically(runner, seed, episode):
    recorded = _record(seed, episode)
    assert recorded["success"] and recorded["switches"] >= 1  # F^reorient switched the chain in the record.
    result, _, _ = run_episode(runner, CONFIG, HAMMER, seed, episode, scatter=False)
    # Every float to the last bit (JSON keeps them exactly).
    assert json.loads(json.dumps(result)) == recorded, f"this machine: {numerics.machine()}; {_made_on()}"



def test_a_tool_knocked_off_the_table_ends_the_episode_as_fallen_not_diverged(runner):
    """Nothing below the table catches a tool: the runner ends the episode once it is below ``FELL_BELOW``, failed,
    with ``fell`` (it used to fall for 14 s until its height passed the divergence bound)."""
    from pydrake.math import RigidTransform

    from seqdex_drake.evaluation.runner import FELL_BELOW

    runner.context.SetTime(0.0)
    name = runner.start_tool(HAMMER, np.random.default_rng(0))
    runner.objects.set_pose(runner.context, name, RigidTransform([1.2, 0.0, 0.75]))  # Beyond the table's edge.
    outcome = runner.run(5.0)
    assert outcome.fell and not outcome.success and outcome.simulator_error == ""
    assert runner.object_pose().translation()[2] < FELL_BELOW and outcome.time < 1.0
