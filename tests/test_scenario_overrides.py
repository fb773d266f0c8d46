"""A chain run on a physics variant (``RunConfig.scenario_overrides``): the overrides reach the built plant, the
run's seed stays the seed, and bad overrides are refused with a message that says what to give; the real-time
benchmark times a variant from the command line (``--scenario-overrides``)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from seqdex_drake.evaluation.run_types import ChainRunError, RunConfig, scenario_text
from seqdex_drake.evaluation.runner import ChainRunner
from seqdex_drake.scenario import ScenarioError

ROOT = Path(__file__).resolve().parents[1]
VARIANT = "{plant_config: {time_step: 0.004}}"


def test_the_overrides_and_the_seed_make_the_scenario_text():
    assert scenario_text(RunConfig(seed=7)) == "{random_seed: 7}\n"  # As runs without overrides always loaded.
    assert scenario_text(RunConfig(seed=3, scenario_overrides=VARIANT)) == \
        "{plant_config: {time_step: 0.004}, random_seed: 3}\n"


@pytest.mark.parametrize("overrides, says", [("[1, 2]", "must be a YAML mapping"), ("{a: [", "not valid YAML"),
                                             ("{random_seed: 4}", "set the run's seed instead")])
def test_bad_overrides_are_refused_with_what_to_give(overrides, says):
    with pytest.raises(ChainRunError, match=says):
        scenario_text(RunConfig(scenario_overrides=overrides))


def test_a_run_builds_its_plant_with_the_overrides():
    runner = ChainRunner(RunConfig(family="tool_positioning", seed=2, scenario_overrides=VARIANT))
    assert runner.plant.time_step() == 0.004 and runner.scenario.random_seed == 2
    assert ChainRunner(RunConfig(family="tool_positioning")).plant.time_step() == 0.002  # The shipped physics.
    with pytest.raises(ScenarioError, match="no_such_key"):  # An unknown key: the scenario loader names it.
        ChainRunner(RunConfig(family="tool_positioning", scenario_overrides="{no_such_key: 1}"))


def _benchmark(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / "main_command_realtime.py"), "--test",
                           "--families", "tool_positioning", "--no-meshcat", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def test_the_realtime_benchmark_times_a_variant_and_refuses_a_bad_one():
    done = _benchmark("--scenario-overrides", VARIANT)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["scenario_overrides"] == VARIANT
    run = result["tool_positioning"]
    assert run["meshcat"] is None and run["headless"]["simulated_s"] == pytest.approx(0.3, abs=1e-6)
    bad = _benchmark("--scenario-overrides", "[1, 2]")
    assert bad.returncode == 2 and "must be a YAML mapping" in bad.stderr and "Traceback" not in bad.stderr
