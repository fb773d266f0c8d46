"""Simulate a Sequential Dexterity task in Drake, shown live in meshcat.

Today this runs the Building Blocks station with the 72 blocks settled in the box (a cached pile) and the
robot holding its home pose; the sub-policies and the feasibility switcher join it as they are trained
(see README). Far-away blocks are frozen until the hand comes near (see seqdex_drake/scene/freezing.py).

    python scripts/simulate_chain.py                   # meshcat in the browser, runs until Ctrl-C
    python scripts/simulate_chain.py --headless --test # a short simulation, exits 0
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from seqdex_drake import LoadScenario, ScenarioError
from seqdex_drake.harness import MakeStationHarness


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="building_blocks/search",
                        help="scenario name, family/name (default: building_blocks/search)")
    parser.add_argument("--scenario-text", default="{}", help="YAML overrides applied to the scenario")
    parser.add_argument("--seed", type=int, default=0, help="random seed (also picks the cached pile)")
    parser.add_argument("--duration", type=float, default=float("inf"), help="simulated seconds (default: forever)")
    parser.add_argument("--headless", action="store_true", help="no meshcat")
    parser.add_argument("--test", action="store_true", help="a short run for CI (0.5 s simulated)")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        scenario = LoadScenario(args.scenario, scenario_text=args.scenario_text)
    except ScenarioError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    scenario.random_seed = args.seed
    meshcat = None
    if not args.headless:
        from pydrake.geometry import StartMeshcat

        meshcat = StartMeshcat()
        print(f"meshcat: open {meshcat.web_url()} in a browser", flush=True)
    try:
        harness = MakeStationHarness(scenario, meshcat=meshcat)
    except (ScenarioError, FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print("policies: none trained yet; the robot holds its home pose "
          "(sub-task training arrives with the learning stack)", flush=True)
    duration = 0.5 if args.test else args.duration
    if meshcat is not None and not args.test:
        harness.simulator.set_target_realtime_rate(1.0)
    start, steps = time.perf_counter(), 0
    try:
        while harness.context.get_time() < duration:
            harness.step()
            steps += 1
    except KeyboardInterrupt:
        pass
    wall = time.perf_counter() - start
    q = harness.objects.positions(harness.context)
    print(f"simulated {harness.context.get_time():.2f} s in {wall:.2f} s wall ({steps / max(wall, 1e-9):.0f} "
          f"control steps/s); {len(q)} objects, {len(harness.objects.frozen_names(harness.context))} frozen; "
          f"all finite: {bool(np.all(np.isfinite(q)))}", flush=True)
    return 0 if np.all(np.isfinite(q)) else 1


if __name__ == "__main__":
    sys.exit(main())
