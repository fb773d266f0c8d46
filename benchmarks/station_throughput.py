"""Station throughput: control steps (1/60 s) per second of one process, per scenario.

For each scenario the robot holds its home pose and the task objects rest in the box or on the table:

- Search: a cached 72-block pile; blocks farther than ``freeze.active_radius`` from a target block stay
  frozen (the shipped setting), and, for reference, the same pile with every block dynamic.
- Orient / Grasp / Insert: the target block resting in the box (on the board for Insert), others parked.
- Tool grasp / reorient: the hammer resting on the table, the other tools parked.

``control_steps_per_s`` steps with :meth:`StationHarness.step` (one ``AdvanceTo`` per control period plus
the wake check); ``advance_to_steps_per_s`` is a single ``Simulator.AdvanceTo`` over the same span.
The last line is one JSON object; ``search_over_grasp_ratio`` divides the Search rate by the Grasp rate
measured in this run (all-dynamic Drake gives about 0.025); the goal of 0.25 is on the env figure with a digging
hand, ``env_throughput.py``'s ``search_env_over_grasp_env``.

    python benchmarks/station_throughput.py [--seconds 2.0]
"""

import argparse
import json
import time

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw

from seqdex_drake import LoadScenario
from seqdex_drake.harness import MakeStationHarness

RESTING = {
    "orient": ("block_1", [0.25, 0.19, 0.6005]),
    "grasp": ("block_1", [0.25, 0.19, 0.6005]),
    "insert": ("block_1", [0.25, -0.30, 0.6185]),
    "tool_grasp": ("hammer", [0.29, 0.19, 0.6 + 0.034 / 2 + 0.0005]),
    "tool_reorient": ("hammer", [0.29, 0.19, 0.6 + 0.034 / 2 + 0.0005]),
}


def _harness(name: str, all_dynamic: bool = False):
    text = "{freeze: {enabled: false}}" if all_dynamic else "{}"
    scenario = LoadScenario(name, scenario_text=text)
    harness = MakeStationHarness(scenario)
    subtask = scenario.subtask
    if subtask == "search":
        q = harness.objects.positions(harness.context)
        target = int(np.argmin(np.linalg.norm(q[:, 4:6] - [0.25, 0.19], axis=1)))
        if not all_dynamic:
            harness.objects.freeze_far_from(harness.context, q[target, 4:])
    else:
        object_name, p = RESTING[subtask]
        rotation = RollPitchYaw(np.pi / 2, 0, 0) if object_name == "hammer" else RollPitchYaw(0, 0, 0)
        harness.objects.set_pose(harness.context, object_name, RigidTransform(rotation, p), frozen=False)
    harness.step(6)  # Let contacts form before timing.
    return harness


def measure(name: str, seconds: float, all_dynamic: bool = False) -> dict:
    harness = _harness(name, all_dynamic)
    steps = max(1, int(round(seconds / harness.scenario.control_period)))
    start = time.perf_counter()
    harness.step(steps)
    stepped = steps / (time.perf_counter() - start)
    t0 = harness.context.get_time()
    start = time.perf_counter()
    harness.simulator.AdvanceTo(t0 + steps * harness.scenario.control_period)
    raw = steps / (time.perf_counter() - start)
    frozen = len(harness.objects.frozen_names(harness.context))
    return {"control_steps_per_s": round(stepped, 1), "advance_to_steps_per_s": round(raw, 1),
            "objects": len(harness.objects.names), "frozen": frozen}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per measurement")
    parser.add_argument("--test", action="store_true", help="a quick run (0.2 s per scenario)")
    args = parser.parse_args(argv)
    seconds = 0.2 if args.test else args.seconds
    results = {}
    for name in ["building_blocks/search", "building_blocks/orient", "building_blocks/grasp",
                 "building_blocks/insert", "tool_positioning/tool_grasp", "tool_positioning/tool_reorient"]:
        results[name] = measure(name, seconds)
        print(f"{name:32s} {results[name]}", flush=True)
    results["building_blocks/search(all dynamic)"] = measure("building_blocks/search", seconds, all_dynamic=True)
    print(f"{'building_blocks/search(all dynamic)':32s} {results['building_blocks/search(all dynamic)']}")
    grasp = results["building_blocks/grasp"]["control_steps_per_s"]
    summary = {
        "search_over_grasp_ratio": round(results["building_blocks/search"]["control_steps_per_s"] / grasp, 3),
        "search_all_dynamic_over_grasp_ratio": round(
            results["building_blocks/search(all dynamic)"]["control_steps_per_s"] / grasp, 3),
        **{f"{k.split('/')[-1]}_steps_per_s": v["control_steps_per_s"] for k, v in results.items()},
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
