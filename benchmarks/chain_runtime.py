"""Runtime of the chain controller: one 60 Hz tick of switcher + policies, and the real-time factor of a chain.

Part 1 (tick): 4 paper-size policies (actor MLPs [1024, 1024, 512], untrained weights; Search 160, Orient 159,
Grasp 159, Insert 173 inputs) all computing, plus the switcher with F^2..F^4 (the attention model, H = 10,
default width) on constant observations, stepped by a Drake Simulator; the wall time per tick is ``tick_ms``.
The chain itself runs only the executing stage's policy per tick (the others' ``active`` input is 0 and they
skip inference): ``tick_ms_chain`` times switcher + the same 4 policy systems with one computing, and
``tick_ms_shipped`` the same with the shipped tool-positioning networks (``--shipped``: its policies with their
progress inputs and scripted bases, its F; null when nothing is shipped) and the switcher's trigger the chain runs
with (``evaluation/chain_settings.SWITCH_TRIGGER``: the tool chain's F is scored where a stage ends, not every
tick); ``tick_ms_shipped_every_tick`` the same with F^{i+1} scored every tick (the paper's timing, ``--trigger
next``).
``policy_ms`` / ``feasibility_ms`` are single forward passes of the default numpy inference path
(``controller/inference.py``) repeated back to back (weights cache-resident), ``*_torch_ms`` the same through torch;
``tick_ms_torch`` is the 4-policy tick with ``inference="torch"``.

The memory floor: a batch-1 policy call reads every weight once, so 4 computing policies read
``policy_weights_mb`` x 4 per tick. ``memory_bandwidth_gbs`` is this process's read rate over a 64 MB array
(larger than the caches) and ``tick_floor_ms`` = 4 x weights / bandwidth, the least a 4-policy tick can cost
when the weights do not stay in cache between ticks (in the chain, physics runs between ticks).

Part 2 (real time): the ``building_blocks/grasp`` station with the chain controller (Orient, Grasp, Insert,
untrained paper-size policies, F^Grasp and F^Insert with H = 10), a block in the box, simulated for
``--seconds``; ``realtime_factor`` = simulated / wall seconds, without Meshcat and with it
(``realtime_factor_meshcat``, a fresh Meshcat per run; null when Meshcat cannot start).
``station_realtime_factor`` is the station with constant targets, for comparison. The runs alternate
``--repeats`` times and the best of each is kept (this shared machine's speed drifts by 20-30 % between runs).
Goals (reported, not asserted): tick <= 1 ms, real time >= 1.0.

Every figure is also given per process-CPU second (``*_cpu``): on a shared machine wall time includes waiting
for a core, CPU time does not (torch and numpy's BLAS run on one thread here, so CPU time is close to idle wall
time). ``load_average`` is the 1-minute load average when the script starts.

    python benchmarks/chain_runtime.py [--ticks 300] [--seconds 3] [--repeats 2] [--threads N] [--test]

The last line printed is one JSON object.
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from seqdex_drake import (
    ChainParams,
    ConnectChainController,
    LoadScenario,
    MakeChainController,
    MakeStation,
    SetChainTarget,
)
from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
from seqdex_drake.chaining.feasibility_io import FeasibilityFile
from seqdex_drake.controller.inference import FeasibilitySnapshot, PolicySnapshot, limit_blas_threads
from seqdex_drake.controller.policy import PolicyParams, PolicySystem
from seqdex_drake.controller.switcher import FeasibilitySwitcher, SwitcherParams
from seqdex_drake.observation_spec import ObservationSpec
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.scene.piles import BOX_CENTER
from seqdex_drake.tasks.blocks_common import resting_pose

PERIOD = 1.0 / 60.0
#: The shipped tool-positioning chain (``seqdex ship``).
SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints" / "tool_positioning"
SIZES = {"search": 160, "orient": 159, "grasp": 159, "insert": 173}


def untrained_f(source: str, target: str, obs_dim: int, history: int = 10) -> FeasibilityFile:
    """An untrained attention F (paper width, H = ``history``) with h = 1, for timing."""
    config = FeasibilityConfig(history=history)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = build_feasibility_model(obs_dim, config).eval()
    return FeasibilityFile(model, config, 1.0, ObservationSpec(obs_dim, source), source, target, {})


def time_tick(ticks: int, computing: int, seed: int = 0, inference: str = "numpy") -> tuple[float, float]:
    """Wall and process-CPU milliseconds per tick of switcher + 4 policy systems, the first ``computing`` of them
    active (the others' ``active`` input is 0: they hold the applied action without inference)."""
    tasks = list(SIZES)
    sizes = [SIZES[t] for t in tasks]
    feasibility = [None] + [untrained_f(tasks[i - 1], tasks[i], sizes[i - 1]) for i in range(1, len(tasks))]
    policies = [PolicySystem.untrained(size, seed=i, params=PolicyParams(PERIOD, inference=inference))
                for i, size in enumerate(sizes)]
    return _time_systems(feasibility, sizes, policies, computing, ticks, SwitcherParams(inference=inference), seed)


def time_shipped_tick(folder: str, family: str, ticks: int, trigger: str = "") -> tuple[float, float]:
    """:func:`time_tick` with a shipped chain's networks (``checkpoints/<family>``): its policies (each with its
    stage's progress input and scripted base) and F's, the first stage computing, and the switcher ``trigger``
    (default: the one the chain runs with, ``SWITCH_TRIGGER[family]``)."""
    from seqdex_drake.chaining.chain import LoadChain
    from seqdex_drake.chaining.chain_files import observation_sizes
    from seqdex_drake.chaining.feasibility_io import load_feasibility
    from seqdex_drake.chaining.shipped import load_shipped_chain
    from seqdex_drake.controller.chain_controller import StagePolicyParams
    from seqdex_drake.evaluation.chain_settings import SWITCH_TRIGGER
    from seqdex_drake.tasks.registry import is_scripted

    tasks = list(LoadChain(family).stages)
    chain = load_shipped_chain(folder, family, tasks, observation_sizes())
    sizes = [observation_sizes()[task] for task in tasks]
    params = [StagePolicyParams(config, PERIOD) for config in chain.configs]
    time_steps = tuple(p.time_steps for p in params)
    policies = [PolicySystem.scripted(size, p) if is_scripted(task) else  # Its base alone (inactive here).
                PolicySystem.untrained(size, seed=i, params=p) if path is None else
                PolicySystem.from_checkpoint(path, size, p)
                for i, (task, path, size, p) in enumerate(zip(tasks, chain.policies, sizes, params, strict=True))]
    feasibility = [None if path is None else load_feasibility(path) for path in chain.feasibility]
    return _time_systems(feasibility, sizes, policies, 1, ticks,
                         SwitcherParams(time_steps=time_steps, trigger=trigger or SWITCH_TRIGGER[family]))


def _time_systems(feasibility: list, sizes: list[int], policies: list, computing: int, ticks: int,
                  switcher_params: SwitcherParams, seed: int = 0) -> tuple[float, float]:
    builder = DiagramBuilder()
    rng = np.random.default_rng(seed)
    sources = [builder.AddSystem(ConstantVectorSource(rng.normal(size=size))) for size in sizes]
    budgets = [10**6] * len(sizes)
    switcher = builder.AddSystem(FeasibilitySwitcher(feasibility, sizes, budgets, PERIOD, switcher_params))
    for i in range(1, len(sizes)):
        if feasibility[i] is not None:
            builder.Connect(sources[i - 1].get_output_port(), switcher.GetInputPort(f"observation.{i - 1}"))
    for i, policy in enumerate(policies):
        policy = builder.AddSystem(policy)
        builder.Connect(sources[i].get_output_port(), policy.GetInputPort("observation"))
        active = builder.AddSystem(ConstantVectorSource([1.0 if i < computing else 0.0]))
        builder.Connect(active.get_output_port(), policy.GetInputPort("active"))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    simulator.AdvanceTo(10 * PERIOD)  # warm-up (allocations, first-call overheads)
    start, cpu_start = time.perf_counter(), time.process_time()
    simulator.AdvanceTo((10 + ticks) * PERIOD)
    return (time.perf_counter() - start) / ticks * 1e3, (time.process_time() - cpu_start) / ticks * 1e3


def memory_bandwidth_gbs(megabytes: int = 64, repeats: int = 5) -> float:
    """Read bandwidth (GB/s) of this process: the best of ``repeats`` sums over a float32 array of ``megabytes``."""
    data = np.ones(megabytes * 2**20 // 4, dtype=np.float32)
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        data.sum()
        best = min(best, time.perf_counter() - start)
    return data.nbytes / best / 1e9


def time_forward(module, make_input, repeats: int) -> float:
    """Wall milliseconds of one inference call (torch modules run under ``inference_mode``)."""
    x = make_input()
    with torch.inference_mode():
        for _ in range(5):
            module(x)
        start = time.perf_counter()
        for _ in range(repeats):
            module(x)
    return (time.perf_counter() - start) / repeats * 1e3


def realtime_factor(seconds: float, meshcat=None, chain: bool = True) -> tuple[float, float]:
    """Simulated / wall seconds and simulated / process-CPU seconds of the Grasp station with the chain
    controller (or with constant targets)."""
    scenario = LoadScenario("building_blocks/grasp")
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario, meshcat=meshcat))
    if chain:
        stages = [("orient", None), ("grasp", None), ("insert", None)]
        feasibility = [None, untrained_f("orient", "grasp", 159), untrained_f("grasp", "insert", 159)]
        controller = builder.AddNamedSystem("chain", MakeChainController(scenario, stages, feasibility,
                                                                         ChainParams(), meshcat=meshcat))
        ConnectChainController(builder, station, controller)
    else:
        arm = builder.AddSystem(ConstantVectorSource(np.r_[scenario.robot.arm_home, np.zeros(7)]))
        hand = builder.AddSystem(ConstantVectorSource(np.r_[ALLEGRO_OPEN_Q, np.zeros(16)]))
        builder.Connect(arm.get_output_port(), station.GetInputPort("franka.desired_state"))
        builder.Connect(hand.get_output_port(), station.GetInputPort("allegro.desired_state"))
    simulator = Simulator(builder.Build())
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    context = simulator.get_mutable_context()
    objects = SceneObjects(station, scenario)
    objects.park(context)
    objects.set_pose(context, "block_2", resting_pose(2, 0.0, 0.0, 0.3, BOX_CENTER[:2] + [0.03, 0.05]))
    if chain:
        plant = station.GetSubsystemByName("plant")
        body = plant.GetBodyByName("block", plant.GetModelInstanceByName("block_2"))
        SetChainTarget(controller, context, int(body.index()), goal=[0.45, 0.1, 0.65, 1.0, 0.0, 0.0, 0.0])
    simulator.Initialize()
    simulator.AdvanceTo(0.1)  # warm-up
    start, cpu_start = time.perf_counter(), time.process_time()
    simulator.AdvanceTo(0.1 + seconds)
    return seconds / (time.perf_counter() - start), seconds / (time.process_time() - cpu_start)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=300, help="ticks timed in part 1")
    parser.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per run in part 2")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch's default); the "
                        "chain controller sets 1 itself (ChainParams.torch_threads) for part 2")
    parser.add_argument("--no-meshcat", action="store_true", help="skip the runs with Meshcat")
    parser.add_argument("--repeats", type=int, default=2, help="part 2: alternating runs per figure, best kept")
    parser.add_argument("--test", action="store_true", help="a few ticks and 0.2 s: checks the script runs")
    parser.add_argument("--shipped", default=str(SHIPPED), metavar="DIR",
                        help="a shipped tool-positioning chain whose networks tick_ms_shipped times (default: "
                        "checkpoints/tool_positioning; skipped when absent)")
    args = parser.parse_args()
    ticks, seconds, repeats = (20, 0.2, 1) if args.test else (args.ticks, args.seconds, args.repeats)
    if args.threads:
        torch.set_num_threads(args.threads)
        blas_limited = limit_blas_threads(args.threads)
    else:
        blas_limited = False
    results = {"load_average": round(os.getloadavg()[0], 2), "torch_threads": torch.get_num_threads(),
               "blas_threads_set": blas_limited, "ticks": ticks, "sim_seconds": seconds, "repeats": repeats}

    policy = PolicySystem.untrained(159).model
    results["policy_ms"] = time_forward(PolicySnapshot(policy), lambda: np.zeros(159), 10 * ticks)
    results["policy_torch_ms"] = time_forward(policy.action_mean, lambda: torch.zeros(1, 159), 10 * ticks)
    f = untrained_f("orient", "grasp", 159).model
    results["feasibility_ms"] = time_forward(FeasibilitySnapshot(f), lambda: np.zeros((10, 159)), 10 * ticks)
    results["feasibility_torch_ms"] = time_forward(f, lambda: torch.zeros(1, 10, 159), 10 * ticks)
    weights = sum(p.numel() for p in policy.actor.parameters()) * 4
    results["policy_weights_mb"] = weights / 1e6
    results["memory_bandwidth_gbs"] = memory_bandwidth_gbs()
    results["tick_floor_ms"] = 4 * weights / (results["memory_bandwidth_gbs"] * 1e9) * 1e3
    results["tick_ms"], results["tick_cpu_ms"] = time_tick(ticks, computing=4)
    results["tick_ms_chain"], results["tick_cpu_ms_chain"] = time_tick(ticks, computing=1)
    results["tick_ms_torch"], results["tick_cpu_ms_torch"] = time_tick(ticks, computing=4, inference="torch")
    for key in ("tick_ms_shipped", "tick_cpu_ms_shipped", "tick_ms_shipped_every_tick",
                "tick_cpu_ms_shipped_every_tick"):
        results[key] = None
    if (Path(args.shipped) / "manifest.json").is_file():
        results["tick_ms_shipped"], results["tick_cpu_ms_shipped"] = time_shipped_tick(args.shipped,
                                                                                       "tool_positioning", ticks)
        results["tick_ms_shipped_every_tick"], results["tick_cpu_ms_shipped_every_tick"] = time_shipped_tick(
            args.shipped, "tool_positioning", ticks, trigger="next")
        print(f"tool positioning, shipped networks ({args.shipped}), as the chain runs: "
              f"{results['tick_ms_shipped']:.3f} ms wall, {results['tick_cpu_ms_shipped']:.3f} ms CPU (goal <= 1 ms); "
              f"with F scored every tick {results['tick_ms_shipped_every_tick']:.3f} ms wall", flush=True)
    print(f"load average {results['load_average']}; one tick, switcher (3 F, H=10) + 4 policies computing: "
          f"{results['tick_ms']:.3f} ms wall, {results['tick_cpu_ms']:.3f} ms CPU (goal <= 1 ms; memory floor "
          f"{results['tick_floor_ms']:.3f} ms: 4 x {results['policy_weights_mb']:.1f} MB of weights at "
          f"{results['memory_bandwidth_gbs']:.1f} GB/s); as the chain runs (1 of the 4 computing): "
          f"{results['tick_ms_chain']:.3f} ms wall, {results['tick_cpu_ms_chain']:.3f} ms CPU; torch path "
          f"(4 policies) {results['tick_ms_torch']:.3f} ms wall, {results['tick_cpu_ms_torch']:.3f} ms CPU; policy "
          f"forward {results['policy_ms']:.3f} ms (torch {results['policy_torch_ms']:.3f}), F forward "
          f"{results['feasibility_ms']:.3f} ms (torch {results['feasibility_torch_ms']:.3f}); torch threads "
          f"{results['torch_threads']}, BLAS threads set: {blas_limited}", flush=True)

    meshcat_factory = None
    if not args.no_meshcat:
        try:
            from pydrake.geometry import StartMeshcat

            StartMeshcat().Delete()  # Fails here (not mid-measurement) when Meshcat cannot start.
            meshcat_factory = StartMeshcat
        except RuntimeError as error:
            print(f"Meshcat did not start ({error}); skipping the Meshcat runs")
    runs = {"station_realtime_factor": lambda: realtime_factor(seconds, chain=False),
            "realtime_factor": lambda: realtime_factor(seconds)}
    if meshcat_factory is not None:  # A fresh Meshcat per run: a reused one keeps the earlier runs' scenes.
        runs["realtime_factor_meshcat"] = lambda: realtime_factor(seconds, meshcat=meshcat_factory())
    results["realtime_factor_meshcat"] = results["realtime_factor_meshcat_cpu"] = None
    for _ in range(repeats):  # Alternating, best kept: the machine's speed drifts between runs.
        for key, run in runs.items():
            wall, cpu = run()
            if results.get(key) is None or wall > results[key]:
                results[key], results[f"{key}_cpu"] = wall, cpu
    print(f"real-time factor over {seconds} s (best of {repeats}): station + chain {results['realtime_factor']:.3f} "
          f"wall, {results['realtime_factor_cpu']:.3f} by CPU time (goal >= 1.0); station with constant targets "
          f"{results['station_realtime_factor']:.3f} wall, {results['station_realtime_factor_cpu']:.3f} CPU",
          flush=True)
    if results["realtime_factor_meshcat"] is not None:
        print(f"with Meshcat: {results['realtime_factor_meshcat']:.3f} wall, "
              f"{results['realtime_factor_meshcat_cpu']:.3f} CPU")
    print(json.dumps({key: round(value, 4) if isinstance(value, float) else value for key, value in results.items()}))


if __name__ == "__main__":
    main()
