"""Real-time factor of the main command: the shipped chains as ``seqdex simulate`` (``scripts/simulate_chain.py``)
runs them, with Meshcat and without.

For each task family the chain is built as the main command builds it (``ChainRunner`` with the shipped
checkpoints, the default seed 0, the switcher's defaults) and its first object started: Building Blocks the
default manual's first block (Search in the 72-block pile, then the retrieve, Orient, Grasp, Insert), Tool
Positioning the hammer. The chain then runs ``--seconds`` simulated seconds as fast as it can (no target real-time
rate; the first ``WARMUP`` seconds off the clock) or until its episode ends, and ``realtime_factor`` = simulated /
wall seconds; ``*_cpu`` per process-CPU second (on a shared machine wall time includes waiting for a core).
With Meshcat the run publishes to a fresh local Meshcat server as the main command does (no browser attached).
Goal (issues 38 and 39, reported, not asserted): real-time factor with Meshcat >= 1.0 for each family.
``load_average`` is the 1-minute load average when the script starts: time it on an otherwise idle machine.

    python benchmarks/main_command_realtime.py [--seconds 20] [--families building_blocks tool_positioning]
    python benchmarks/main_command_realtime.py --families building_blocks --no-meshcat \
        --scenario-overrides "{plant_config: {time_step: 0.004166666666666667}}"   # a physics variant's speed
    python benchmarks/main_command_realtime.py --test          # 0.3 simulated seconds each, for CI

The last line printed is one JSON object.
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from seqdex_drake.evaluation.run_types import ChainRunError
from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, goal_vector

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("building_blocks", "tool_positioning")
#: Simulated seconds run before the clock starts (first-call allocations, Meshcat's first scene upload).
WARMUP = 0.1
#: The main command's default manual (``seqdex simulate --manual``).
MANUAL = "small_wall"


def start_first_object(runner: ChainRunner, family: str, seed: int) -> str:
    """Starts the object the main command starts first; returns its name."""
    if family == "tool_positioning":
        return runner.start_tool(0, np.random.default_rng(seed))
    step = LoadManual(MANUAL).steps[0]
    return runner.start_block(step.block_type, goal_vector(step))


def time_family(family: str, seconds: float, meshcat, seed: int = 0, scenario_overrides: str = "") -> dict:
    """Wall and CPU seconds of ``seconds`` simulated seconds of ``family``'s shipped chain (``meshcat`` or None),
    its scenario changed by ``scenario_overrides`` (YAML; ``RunConfig.scenario_overrides``) if given."""
    checkpoints = ROOT / "checkpoints" / family
    run_dir = str(checkpoints) if (checkpoints / "manifest.json").is_file() else None
    runner = ChainRunner(RunConfig(family=family, run_dir=run_dir, seed=seed, scenario_overrides=scenario_overrides),
                         meshcat=meshcat)
    start_first_object(runner, family, seed)
    t0 = runner.context.get_time()
    clock = {}

    def on_tick(r) -> bool:
        elapsed = r.context.get_time() - t0
        if "wall" not in clock and elapsed >= WARMUP - 1e-9:
            clock["sim"], clock["wall"], clock["cpu"] = r.context.get_time(), time.perf_counter(), time.process_time()
        return elapsed < WARMUP + seconds - 1e-9

    outcome = runner.run(runner.episode_limit(), on_tick=on_tick)
    if "wall" not in clock:
        raise RuntimeError(f"{family}'s episode ended within the {WARMUP} s warm-up: nothing was timed")
    simulated = runner.context.get_time() - clock["sim"]
    wall, cpu = time.perf_counter() - clock["wall"], time.process_time() - clock["cpu"]
    return {"simulated_s": round(simulated, 3), "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
            "realtime_factor": round(simulated / wall, 4), "realtime_factor_cpu": round(simulated / cpu, 4),
            "last_stage": outcome.last_stage, "checkpoints": "shipped" if run_dir else "untrained"}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0,
                        help="simulated seconds timed per run (default 20, as the issue's 78 s wall figure)")
    parser.add_argument("--families", nargs="+", choices=FAMILIES, default=list(FAMILIES))
    parser.add_argument("--test", action="store_true", help="0.3 simulated seconds per run (no timing meaning)")
    parser.add_argument("--no-meshcat", action="store_true", help="time the headless runs only")
    parser.add_argument("--scenario-overrides", default="",
                        help="YAML mapping applied to each chain's scenario (a physics variant, e.g. \"{plant_config: "
                             "{time_step: 0.004166666666666667}}\"); the shipped policies were trained without one")
    args = parser.parse_args()
    if not args.seconds > 0:
        parser.error(f"--seconds must be > 0, got {args.seconds}")
    seconds = 0.3 if args.test else args.seconds
    from pydrake.geometry import Meshcat

    results = {"load_average": round(os.getloadavg()[0], 2), "seconds": seconds,
               **({"scenario_overrides": args.scenario_overrides} if args.scenario_overrides else {})}
    meshcat = None
    if not args.no_meshcat:
        try:
            meshcat = Meshcat()  # One server, as the main command starts one; each run deletes the previous scene.
        except RuntimeError as error:
            print(f"Meshcat did not start ({error}); the Meshcat figures are null", flush=True)
    try:
        for family in args.families:
            _time_both(family, seconds, meshcat, args.scenario_overrides, results)
    except ChainRunError as error:
        parser.error(str(error))
    print(json.dumps(results))


def _time_both(family: str, seconds: float, meshcat, scenario_overrides: str, results: dict) -> None:
    """Times ``family`` headless and (with ``meshcat``) with Meshcat; adds its figures to ``results``."""
    headless = time_family(family, seconds, None, scenario_overrides=scenario_overrides)
    with_meshcat = None
    if meshcat is not None:
        meshcat.Delete()
        with_meshcat = time_family(family, seconds, meshcat, scenario_overrides=scenario_overrides)
    results[family] = {"headless": headless, "meshcat": with_meshcat, "realtime_factor": headless["realtime_factor"],
                       "realtime_factor_meshcat": with_meshcat and with_meshcat["realtime_factor"]}
    shown = "no Meshcat" if with_meshcat is None else f"{with_meshcat['realtime_factor']:.2f} with Meshcat"
    print(f"{family}: real-time factor {headless['realtime_factor']:.2f} headless, {shown} (goal >= 1; "
          f"{seconds:g} simulated s)", flush=True)


if __name__ == "__main__":
    main()
