"""OSC QP solve time per control tick, measured in the closed loop around the Grasp station.

The arm starts at home and approaches random hover points over the work cell (2 s each, 60 Hz ticks);
every tick the controller updates its one MathematicalProgram and solves it with OsqpSolver. Prints the
mean, max, median and 99th percentile wall-clock time of ``OsqpSolver.Solve`` per tick, the mean and max of
the whole update (kinematics, dynamics, coefficient updates and solve), then one JSON line::

    {"osc_solve_ms_mean": ..., "osc_solve_ms_max": ..., ...}

    python benchmarks/osc_solve_time.py [--targets 10] [--seed 0] [--test]
"""

import argparse
import json
import time

import numpy as np
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from seqdex_drake import LoadScenario, MakeStation
from seqdex_drake.control.osc import AddOperationalSpaceController
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.scene.objects import SceneObjects


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=10, help="number of random targets (2 s each)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--test", action="store_true", help="2 targets of 0.5 s: checks the script runs")
    args = parser.parse_args()
    num_targets, duration = (2, 0.5) if args.test else (args.targets, 2.0)

    scenario = LoadScenario("building_blocks/grasp")
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario))
    osc = AddOperationalSpaceController(builder, station, scenario)
    target = builder.AddNamedSystem("target", ConstantVectorSource(np.zeros(3)))
    builder.Connect(target.get_output_port(), osc.GetInputPort("target_position"))
    hand = builder.AddNamedSystem("hand_hold", ConstantVectorSource(np.r_[ALLEGRO_OPEN_Q, np.zeros(16)]))
    builder.Connect(hand.get_output_port(), station.GetInputPort("allegro.desired_state"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    context = simulator.get_mutable_context()
    SceneObjects(station, scenario).park(context)
    plant = station.GetSubsystemByName("plant")
    franka = plant.GetModelInstanceByName("franka")

    rng = np.random.default_rng(args.seed)
    errors, solve_ms = [], []
    start = time.perf_counter()
    for _ in range(num_targets):
        p_WH = rng.uniform([0.05, -0.20, 0.80], [0.40, 0.30, 0.95])
        context.SetTime(0.0)
        plant_context = plant.GetMyMutableContextFromRoot(context)
        plant.SetPositions(plant_context, franka, np.asarray(scenario.robot.arm_home))
        plant.SetVelocities(plant_context, franka, np.zeros(7))
        target.get_mutable_source_value(target.GetMyMutableContextFromRoot(context)).SetFromVector(
            p_WH - [0.0, 0.0, osc.params.hover_height])
        simulator.Initialize()
        for tick in range(1, round(duration / scenario.control_period) + 1):
            before = osc.statistics.solve_seconds_total
            simulator.AdvanceTo(tick * scenario.control_period)
            solve_ms.append(1e3 * (osc.statistics.solve_seconds_total - before))
        q = station.GetOutputPort("franka.state").Eval(station.GetMyContextFromRoot(context))[:7]
        errors.append(np.linalg.norm(osc.controlled_point(q) - p_WH))
    wall = time.perf_counter() - start

    stats = osc.statistics
    figures = {
        "osc_solve_ms_mean": 1e3 * stats.solve_seconds_total / stats.ticks,
        "osc_solve_ms_max": 1e3 * stats.solve_seconds_max,
        "osc_solve_ms_p50": float(np.percentile(solve_ms, 50)),
        "osc_solve_ms_p99": float(np.percentile(solve_ms, 99)),
        "osc_update_ms_mean": 1e3 * stats.update_seconds_total / stats.ticks,
        "osc_update_ms_max": 1e3 * stats.update_seconds_max,
        "ticks": stats.ticks,
        "qp_failures": stats.failures,
        "final_error_mm_max": 1e3 * max(errors),
        "wall_s": wall,
    }
    print(f"{stats.ticks} ticks over {num_targets} targets ({wall:.1f} s wall)")
    print(f"OsqpSolver.Solve per tick: mean {figures['osc_solve_ms_mean']:.3f} ms, "
          f"max {figures['osc_solve_ms_max']:.3f} ms (median {figures['osc_solve_ms_p50']:.3f}, "
          f"99th percentile {figures['osc_solve_ms_p99']:.3f})")
    print(f"whole update per tick:     mean {figures['osc_update_ms_mean']:.3f} ms, "
          f"max {figures['osc_update_ms_max']:.3f} ms")
    print(f"QP failures {stats.failures}; largest hover-point error after {duration} s: "
          f"{figures['final_error_mm_max']:.2f} mm")
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in figures.items()}))


if __name__ == "__main__":
    main()
