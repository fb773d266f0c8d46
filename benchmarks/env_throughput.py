"""Environment throughput: env steps/s against the raw simulator, and the process vector env with 1 and 2 workers.

Single process, per registered sub-task: the env is reset (seed 0), stepped a few times with zero actions, and its
state saved. From that state, ``env_steps_per_s`` times ``SubtaskEnv.step`` with zero actions (IK, observation,
reward terms, wake check) for about ``--seconds``; then, from the same state, ``raw_steps_per_s`` times the same
number of control periods with ``env.simulator.AdvanceTo`` alone, one call per period (no env code), replaying what
the env did between its calls, off the clock: the targets each env step wrote, and the frozen sets where the env
woke or re-froze objects (Search's pile). Both runs then simulate exactly the same trajectory
(``raw_replays_env_exactly`` checks that they end in bit-identical states), and env / raw is the cost of the env's
own code alone. (Earlier versions held the last targets and ran no wake check, so the two runs moved differently:
Orient's raw loop came out slower than the env, Search's kept disturbed blocks frozen and cheap.)
The two are interleaved in chunks of ``CHUNK_STEPS`` (10) control steps: the env steps a chunk from the chunk's
start state, the raw loop replays that chunk from the same state, and the next chunk starts where the env's ended;
this runs for about ``--seconds`` of env time and at least ``--min-steps`` steps (default 40: Search, at ~5 steps
per second, got only 2 chunks per repeat before session 10, and its ratio moved by 0.06 between runs), within one
episode, ``--repeats`` times from the saved state, and the times are summed.
Ratios of sums over finely interleaved chunks, so that the machine's speed, which drifts by 20-30 % within
minutes here, weighs on both sides alike. (Best-of-N rates did not: the best of each side could come from
different minutes. Session 6 alternated whole 3 s runs, still long enough for single tasks to move by 0.1.)
``raw_with_tactile_solve_steps_per_s`` adds to the raw loop only the motor-tactile read (the hand's net
actuation); ``env_over_raw_ceiling`` = that rate / raw is the most
the env/raw ratio can reach with these observations, however cheap the rest of the env step. With the scenarios'
sampled output ports the read returns the last plant step's torques and costs nothing (ceiling ~1); with
``use_sampled_output_ports: false`` it forces one extra discrete contact solve per step.

Vector env (grasp, or every sub-task with ``--all``): ``ProcessVectorEnv`` with 1 and 2 workers, alternating,
on the same envs, so that both do the same work: one env per worker (2 envs: 1 worker hosting both against 2
workers hosting one each), and ``--envs-per-worker`` envs per worker (default 8: 16 envs, PPO's default
``num_envs``, in 1 worker against 2 workers of 8). Env ``i`` is seeded ``i`` in every layout and steps zero
actions, so the two layouts simulate the same trajectories and the speedup is the time ratio for the same work.
(Until session 10 the 1-worker side hosted only 8 envs, seeds 0-7, against 2 x 8 with seeds 0-15: a different
workload, whose second half could be costlier or cheaper; ``weak_scaling_speedup_<k>_envs_per_worker`` still
reports that comparison, 2 x k against 1 x k.) Each layout runs about ``--vector-steps`` env steps per env slot
(automatic resets included), alternating ``--repeats`` times, summed; steps/s counts env steps (envs x vector
steps). ``inprocess_steps_per_s`` is a plain env stepped the same way in this process. The 2 x k layout is timed
twice: with lock-step ``step`` calls, where every step waits for the slower worker, and as PPO steps it by default
(``PPOConfig.grouped_rollouts``): rollouts of the sub-task's PPO horizon (grasp: 8) in which each worker's group
steps on through ``step_async`` / ``step_wait`` as soon as its previous step is in, the groups meeting at the end
of each rollout (``workers_2_grouped_..._steps_per_s``, ``two_worker_speedup_grouped_...``).
``other_processes_busy_cores`` is how many cores other processes kept busy meanwhile (from /proc): a 2-worker
speedup on 2 cores is only meaningful when it is near 0.
``sync_bound_speedup`` is what the per-step times allow a synchronous vector env: envs seeded 0 and 1 (the two
workers' seeds) are stepped in this process, step by step timed, and a vector step is taken to last as long as the
slower env's step on perfectly parallel cores (episodes differ in cost, so one env often waits for the other).
``raw_two_process_speedup`` is the other reference for the 2-worker figure: the same sub-task's raw ``AdvanceTo``
loop in 2 processes at once against 1 (summed rates), no env code and no pipes: what the machine itself lets two
simulations gain (shared caches and memory bandwidth, clock boost).

Search against Grasp (``search_env_over_grasp_env``, goal >= 0.25): both envs in this process, stepped with
uniform random actions (an untrained policy digging in the pile: the training workload, where the hand wakes
blocks) and interleaved in chunks of 5 Search steps and a matched number of Grasp steps, so that the machine's
drift weighs on both alike; ``--search-steps`` Search steps per repeat.

The last line is one JSON object; ``env_over_raw_min`` is the smallest env/raw ratio over the paper's six
sub-tasks measured (goal >= 0.90; ``env_over_raw_min_all_tasks`` includes the hand-over chain's Reach and Lower,
whose ~2 ms of physics per step make any Python step code weigh more), ``two_worker_speedup`` the 2-worker
over the 1-worker rate for grasp, on 2 x ``--envs-per-worker`` envs, with grouped rollouts as PPO steps them
(goal >= 1.8 on 2 cores; ``two_worker_speedup_lockstep`` the same with lock-step ``step`` calls,
``two_worker_speedup_1_env_per_worker`` lock-step on 2 envs, one per worker), and ``failed`` maps a sub-task
whose env could not be built or stepped to its error (it is left out of the minimum).

    python benchmarks/env_throughput.py [--seconds 3] [--repeats 3] [--min-steps 40] [--vector-steps 300]
                                        [--search-steps 60]
                                        [--envs-per-worker 8]
                                        [--all] [--test]
"""

import argparse
import dataclasses
import json
import multiprocessing
import os
import time

import numpy as np

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.envs.vector import ProcessVectorEnv
from seqdex_drake.rl.config import PAPER_TASK_HYPERPARAMETERS, PPOConfig
from seqdex_drake.tasks.registry import PAPER_TASKS, default_config, task_names

WARMUP_STEPS = 5
CHUNK_STEPS = 10
"""Env steps per interleaved chunk of the single-process measurement (each followed by its raw replay)."""


def _sources(env) -> list:
    """The env's command source (arm and hand desired states, previous action) with its context."""
    return [(env._command_source, env._command_source.GetMyMutableContextFromRoot(env.context))]


def _time_env(env, state, seconds: float, max_steps: int) -> tuple[int, float, list]:
    """Steps with zero actions from ``state`` for about ``seconds``; returns (steps, elapsed s in ``step``, what
    each step left for :func:`_time_raw` to replay: the targets it wrote and the frozen-object mask after it)."""
    env.reset(options={"initial_state": state})
    action, steps, elapsed, replay = np.zeros(env.action_space.shape), 0, 0.0, []
    sources = _sources(env)
    while steps < max_steps and (steps == 0 or elapsed < seconds):
        start = time.perf_counter()
        env.step(action)
        elapsed += time.perf_counter() - start
        replay.append(([source.get_source_value(context).CopyToVector() for source, context in sources],
                       env.objects.frozen_mask(env.context)))
        steps += 1
    replay.append(env.plant.GetPositionsAndVelocities(env.plant_context).copy())  # Where the env ended.
    return steps, elapsed, replay


def _time_raw(env, state, steps: int, replay: list | None = None, tactile: bool = False) -> tuple[float, bool]:
    """Elapsed s for ``steps`` control periods of ``Simulator.AdvanceTo`` alone, from ``state``, and whether the
    run ended exactly where the env's did.

    With ``replay`` (from :func:`_time_env`), each period first gets the targets the env wrote for it and the
    objects frozen as the env left them, both off the clock: the raw loop then simulates exactly the env's
    trajectory, so env / raw compares the same physics with and without the env's code (the IK, observation,
    reward, success test and wake check). Without it, the last targets are held. With ``tactile``, each period
    also pays what the motor-tactile observation costs on any env step: the hand's net actuation read at the
    new state (free with sampled output ports, else a discrete contact solve with the current targets).
    """
    env.reset(options={"initial_state": state})
    period = env.scenario.control_period
    sources = _sources(env)
    current, elapsed = env.objects.frozen_mask(env.context), 0.0
    for k in range(1, steps + 1):
        if replay is not None:
            for (source, context), value in zip(sources, replay[k - 1][0], strict=True):
                source.get_mutable_source_value(context).SetFromVector(value)
            if k > 1 and not np.array_equal(replay[k - 2][1], current):
                current = replay[k - 2][1]
                env.objects.set_frozen(env.context, current)
        start = time.perf_counter()
        env.simulator.AdvanceTo(env.context.get_time() + period)  # As env.step does (rounding decides steps).
        if tactile:
            env.hand_torque()
        elapsed += time.perf_counter() - start
    exact = replay is not None and np.array_equal(env.plant.GetPositionsAndVelocities(env.plant_context),
                                                  replay[-1])
    return elapsed, exact


def search_over_grasp(search_steps: int, repeats: int, chunk: int = 5, search_overrides: str = "") -> dict:
    """Search and Grasp env steps/s in this process, interleaved in chunks (``chunk`` Search steps, then as many
    Grasp steps as take about as long), with uniform random actions from seed 0, as an untrained policy digs:
    the training workload. Episodes run to their end and reset (seeds 0, 1, ...), both envs alike. Summed over
    ``repeats`` passes of ``search_steps`` Search steps; ``search_env_over_grasp_env`` is the rate ratio.
    ``search_overrides``: YAML over the Search scenario (``TaskConfig.scenario_overrides``), to measure settings."""
    search = dataclasses.replace(default_config("search"), scenario_overrides=search_overrides)
    envs = {"search": make_env("search", search), "grasp": make_env("grasp")}
    rngs = {name: np.random.default_rng(0) for name in envs}
    episodes = dict.fromkeys(envs, 0)
    for env in envs.values():
        env.reset(seed=0)
    steps, elapsed = dict.fromkeys(envs, 0), dict.fromkeys(envs, 0.0)

    def run(name: str, count: int) -> None:
        env = envs[name]
        start = time.perf_counter()
        for _ in range(count):
            _, _, terminated, truncated, _ = env.step(rngs[name].uniform(-1.0, 1.0, env.action_space.shape))
            if terminated or truncated:
                episodes[name] += 1
                env.reset(seed=episodes[name])
        elapsed[name] += time.perf_counter() - start
        steps[name] += count

    run("grasp", 2 * chunk)  # Warm-up of both (first-call costs), off the books.
    run("search", 1)
    steps, elapsed = dict.fromkeys(envs, 0), dict.fromkeys(envs, 0.0)
    grasp_chunk = 4 * chunk  # Re-sized after the first chunk so that both sides of a chunk take about as long.
    for _ in range(repeats):
        for _ in range(max(1, search_steps // chunk)):
            run("search", chunk)
            run("grasp", grasp_chunk)
            grasp_chunk = max(chunk, int(round(chunk * steps["grasp"] / elapsed["grasp"] * elapsed["search"]
                                               / steps["search"])))
    rates = {name: steps[name] / elapsed[name] for name in envs}
    return {"search_env_steps_per_s": round(rates["search"], 2), "grasp_env_steps_per_s": round(rates["grasp"], 2),
            "search_steps": steps["search"], "grasp_steps": steps["grasp"],
            "search_env_over_grasp_env": round(rates["search"] / rates["grasp"], 4)}


def single_process(name: str, seconds: float, repeats: int, min_steps: int = 0) -> dict:
    """Env and raw step rates of sub-task ``name`` in this process, over ``repeats`` alternating runs of about
    ``seconds`` each and at least ``min_steps`` steps (both within one episode)."""
    env = make_env(name)
    env.reset(seed=0)
    for _ in range(WARMUP_STEPS):
        env.step(np.zeros(env.action_space.shape))
    state = env.get_state()
    max_steps = env.config.episode_length - 1  # Stay inside one episode (no truncation).
    total_steps, env_time, raw_time, tactile_time, replays_exactly = 0, 0.0, 0.0, 0.0, True
    for _ in range(repeats):
        # In chunks of CHUNK_STEPS: the env steps from the chunk's start state, then the raw loop replays the same
        # chunk from the same state; the next chunk starts where the env's ended. Interleaved this finely, both
        # sides see the same machine speed, which drifts by 20-30 % within minutes here.
        chunk_state, steps, elapsed = state, 0, 0.0
        while steps < max_steps and (steps < max(1, min_steps) or elapsed < seconds):
            n, chunk_elapsed, replay = _time_env(env, chunk_state, seconds, min(CHUNK_STEPS, max_steps - steps))
            next_state = env.get_state()
            raw_elapsed, exact = _time_raw(env, chunk_state, n, replay)
            tactile_time += _time_raw(env, chunk_state, n, replay, tactile=True)[0]
            steps, elapsed, raw_time = steps + n, elapsed + chunk_elapsed, raw_time + raw_elapsed
            replays_exactly, chunk_state = replays_exactly and exact, next_state
        total_steps, env_time = total_steps + steps, env_time + elapsed
    return {"env_steps_per_s": round(total_steps / env_time, 1), "raw_steps_per_s": round(total_steps / raw_time, 1),
            "env_over_raw": round(raw_time / env_time, 3), "steps": total_steps,
            "raw_replays_env_exactly": replays_exactly,
            "raw_with_tactile_solve_steps_per_s": round(total_steps / tactile_time, 1),
            "env_over_raw_ceiling": round(raw_time / tactile_time, 3)}


def _cpu_seconds(pids: list[int]) -> tuple[float, float] | None:
    """(CPU seconds busy on the whole machine, CPU seconds used by ``pids``) from /proc; None where unavailable."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(x) for x in stat.readline().split()[1:9]]
        busy = sum(fields) - fields[3] - fields[4]  # All but idle and iowait.
        own = 0
        for pid in pids:
            with open(f"/proc/{pid}/stat") as stat:
                own += sum(int(x) for x in stat.read().rsplit(")", 1)[1].split()[11:13])  # utime, stime.
    except (OSError, ValueError):
        return None
    ticks = os.sysconf("SC_CLK_TCK")
    return busy / ticks, own / ticks


def _time_vector(vector_env: ProcessVectorEnv, steps: int) -> tuple[int, float, float | None]:
    """(env steps, elapsed s, CPU seconds other processes used meanwhile) over ``steps`` vector steps of zero
    actions."""
    actions = np.zeros((vector_env.num_envs, 19))
    pids = [os.getpid(), *sorted(set(vector_env.pids))]  # Envs of one worker share its process.
    before, start = _cpu_seconds(pids), time.perf_counter()
    for _ in range(steps):
        vector_env.step(actions)
    elapsed, after = time.perf_counter() - start, _cpu_seconds(pids)
    others = None if before is None or after is None else max(0.0, (after[0] - before[0]) - (after[1] - before[1]))
    return vector_env.num_envs * steps, elapsed, others


def _time_vector_grouped(vector_env: ProcessVectorEnv, steps: int, horizon: int) -> tuple[int, float, float | None]:
    """:func:`_time_vector` as PPO's grouped rollouts step (``PPOConfig.grouped_rollouts``): rollouts of
    ``horizon`` steps in which each worker's group steps on as soon as its previous step is in, the groups
    meeting only at the end of each rollout; about ``steps`` vector steps in all, zero actions."""
    groups = vector_env.step_groups
    actions = [np.zeros((len(group), 19)) for group in groups]
    rollouts = max(1, steps // horizon)
    pids = [os.getpid(), *sorted(set(vector_env.pids))]
    before, start = _cpu_seconds(pids), time.perf_counter()
    for _ in range(rollouts):
        progress = [0] * len(groups)
        for group, group_actions in enumerate(actions):
            vector_env.step_async(group, group_actions)
        running = len(groups)
        while running:
            group, _ = vector_env.step_wait()
            progress[group] += 1
            if progress[group] < horizon:
                vector_env.step_async(group, actions[group])
            else:
                running -= 1
    elapsed, after = time.perf_counter() - start, _cpu_seconds(pids)
    others = None if before is None or after is None else max(0.0, (after[0] - before[0]) - (after[1] - before[1]))
    return vector_env.num_envs * horizon * rollouts, elapsed, others


def _raw_worker(name: str, steps: int, barrier, results) -> None:
    """Builds sub-task ``name``'s env, waits for the others, then times ``steps`` raw control periods."""
    env = make_env(name)
    env.reset(seed=0)
    for _ in range(WARMUP_STEPS):
        env.step(np.zeros(env.action_space.shape))
    state = env.get_state()
    barrier.wait()
    results.put(steps / _time_raw(env, state, steps)[0])


def raw_parallel_speedup(name: str, steps: int, repeats: int) -> float:
    """How well the simulation itself scales over processes: the summed raw ``AdvanceTo`` rate of 2 processes
    running at once over that of 1 (means over ``repeats`` alternating runs). No env code and no inter-process
    traffic, so this is the most a 2-worker vector env can gain on this machine (shared caches, memory
    bandwidth, clocks)."""
    context = multiprocessing.get_context("spawn")
    summed = {1: 0.0, 2: 0.0}
    for _ in range(repeats):
        for count in (1, 2):
            barrier, results = context.Barrier(count), context.Queue()
            workers = [context.Process(target=_raw_worker, args=(name, steps, barrier, results))
                       for _ in range(count)]
            for worker in workers:
                worker.start()
            try:
                rate = sum(results.get(timeout=600) for _ in workers)
            finally:  # A worker that failed or hung must not outlive the benchmark.
                for worker in workers:
                    worker.join(timeout=60)
                    if worker.is_alive():
                        worker.kill()
            summed[count] += rate
    return summed[2] / summed[1]


def _step_durations(name: str, seed: int, steps: int) -> np.ndarray:
    """Seconds of each of ``steps`` zero-action steps (automatic resets included) of a sub-task env seeded
    ``seed``, in this process."""
    env = make_env(name)
    env.reset(seed=seed)
    durations = np.empty(steps)
    for k in range(steps):
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(np.zeros(19))
        if terminated or truncated:
            env.reset()
        durations[k] = time.perf_counter() - start
    return durations


def vector(name: str, steps: int, repeats: int, envs_per_worker: int) -> dict:
    """Env steps/s of the same 2k envs in 1 worker and in 2 workers of k, for k = 1 and ``envs_per_worker``, and
    of k envs in 1 worker (the weak-scaling reference; ``repeats`` alternating runs, summed), and in this
    process."""
    durations = [_step_durations(name, seed, steps) for seed in (0, 1)]  # The two workers' envs, in-process.
    inprocess = float(steps / durations[0].sum())
    # A synchronous vector step lasts as long as its slowest env's step: with 2 envs on 2 perfectly parallel
    # cores, throughput is 2 steps per max(t0, t1); one process steps both envs, one after the other.
    sync_bound = float((durations[0] + durations[1]).sum() / np.maximum(*durations).sum())
    ks = sorted({1, envs_per_worker})
    layouts = [layout for k in ks for layout in ((1, 2 * k), (2, k))]  # (workers, envs per worker)
    if envs_per_worker > 1:
        layouts.append((1, envs_per_worker))  # The weak-scaling reference: half the envs in 1 worker.
    layouts = list(dict.fromkeys(layouts))  # (1, 2) twice when envs_per_worker is 2.
    totals = {layout: [0, 0.0, 0.0] for layout in layouts}  # env steps, elapsed s, other processes' CPU s
    totals["grouped"] = [0, 0.0, 0.0]  # 2 workers of envs_per_worker, PPO's grouped rollouts
    horizon = PAPER_TASK_HYPERPARAMETERS.get(name, {}).get("horizon", PPOConfig.horizon)
    start = time.perf_counter()
    vector_envs = {}
    try:
        for workers, k in layouts:
            vector_envs[workers, k] = ProcessVectorEnv(name, workers * k, seed=0, envs_per_worker=k)
        startup = time.perf_counter() - start
        for vector_env in vector_envs.values():
            vector_env.reset()
            _time_vector(vector_env, WARMUP_STEPS)
        for _ in range(repeats):  # Alternating, summed: the machine's speed drifts alike for every layout.
            for layout, vector_env in [*vector_envs.items(), ("grouped", vector_envs[2, envs_per_worker])]:
                # The two layouts of one k host the same 2k envs: the same vector steps, the same trajectories.
                vector_steps = max(1, 2 * steps // vector_env.num_envs)
                env_steps, elapsed, others = (_time_vector_grouped(vector_env, vector_steps, horizon)
                                              if layout == "grouped" else _time_vector(vector_env, vector_steps))
                total = totals[layout]
                total[0], total[1] = total[0] + env_steps, total[1] + elapsed
                total[2] = None if others is None or total[2] is None else total[2] + others
    finally:
        for vector_env in vector_envs.values():
            vector_env.close()
    rates = {layout: total[0] / total[1] for layout, total in totals.items()}
    result = {"inprocess_steps_per_s": round(inprocess, 1), "sync_bound_speedup": round(sync_bound, 3)}
    for k in ks:
        suffix = "" if k == 1 else f"_{k}_envs_per_worker"
        result[f"workers_1{suffix}_steps_per_s"] = round(rates[1, 2 * k], 1)
        result[f"workers_2{suffix}_steps_per_s"] = round(rates[2, k], 1)
        result[f"two_worker_speedup{suffix or '_1_env_per_worker'}"] = round(rates[2, k] / rates[1, 2 * k], 3)
    suffix = "" if envs_per_worker == 1 else f"_{envs_per_worker}_envs_per_worker"
    result[f"workers_2_grouped{suffix}_steps_per_s"] = round(rates["grouped"], 1)
    result[f"two_worker_speedup_grouped{suffix}"] = round(rates["grouped"] / rates[1, 2 * envs_per_worker], 3)
    result["grouped_rollout_horizon"] = horizon
    if envs_per_worker > 1:
        result[f"weak_scaling_speedup_{envs_per_worker}_envs_per_worker"] = round(
            rates[2, envs_per_worker] / rates[1, envs_per_worker], 3)
    result.update({"startup_s_all_vector_envs": round(startup, 2), "vector_steps": steps,
                   "other_processes_busy_cores": {
                       layout if layout == "grouped" else "{}x{}".format(*layout):
                       None if t[2] is None else round(t[2] / t[1], 2) for layout, t in totals.items()}})
    return result


def _speedup(result: dict, envs_per_worker: int, grouped: bool = True) -> float:
    """The 2-worker speedup of a :func:`vector` result at ``envs_per_worker`` envs per worker, with PPO's grouped
    rollouts (``grouped``) or lock-step ``step`` calls."""
    suffix = "" if envs_per_worker == 1 else f"_{envs_per_worker}_envs_per_worker"
    if grouped:
        return result[f"two_worker_speedup_grouped{suffix}"]
    return result[f"two_worker_speedup{suffix or '_1_env_per_worker'}"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0, help="seconds per single-process env measurement")
    parser.add_argument("--repeats", type=int, default=3, help="alternating repeats, summed")
    parser.add_argument("--vector-steps", type=int, default=300, help="vector steps per vector measurement")
    parser.add_argument("--min-steps", type=int, default=40,
                        help="per repeat, at least this many env steps (within one episode): Search, at ~5 steps "
                             "per second, would otherwise be measured on 2 chunks per repeat")
    parser.add_argument("--tasks", nargs="*", default=None, help="sub-tasks for the single-process part")
    parser.add_argument("--all", action="store_true", help="vector part for every sub-task, not only grasp")
    parser.add_argument("--envs-per-worker", type=int, default=8,
                        help="envs each worker hosts in the batched vector layout (1 and this are measured); "
                             "default 8: PPO's default 16 envs on 2 workers")
    parser.add_argument("--search-steps", type=int, default=60,
                        help="Search env steps per repeat of the interleaved Search / Grasp measurement")
    parser.add_argument("--test", action="store_true", help="a tiny run (a few steps per measurement)")
    args = parser.parse_args(argv)
    if args.test:
        args.seconds, args.repeats, args.vector_steps, args.min_steps, args.search_steps = 0.05, 1, 5, 1, 5
    names = args.tasks or task_names()
    load_before = os.getloadavg()
    single, failed = {}, {}
    for name in names:
        try:
            single[name] = single_process(name, args.seconds, args.repeats, args.min_steps)
        except Exception as error:  # noqa: BLE001 - a broken sub-task is reported, the others still measured.
            failed[name] = f"{type(error).__name__}: {error}"
            print(f"{name:14s} FAILED {failed[name]}", flush=True)
            continue
        print(f"{name:14s} single process {single[name]}", flush=True)
    ratio = search_over_grasp(args.search_steps, args.repeats)
    print(f"search / grasp env steps (random actions, interleaved): {ratio}", flush=True)
    vector_names = list(single) if args.all else ["grasp"]
    vectors = {}
    for name in vector_names:
        vectors[name] = vector(name, args.vector_steps, args.repeats, args.envs_per_worker)
        vectors[name]["raw_two_process_speedup"] = round(raw_parallel_speedup(name, args.vector_steps,
                                                                              args.repeats), 3)
        print(f"{name:14s} vector env     {vectors[name]}", flush=True)
    summary = {
        "env_over_raw_min": min((r["env_over_raw"] for name, r in single.items() if name in PAPER_TASKS),
                                default=None),
        "env_over_raw_min_all_tasks": min((r["env_over_raw"] for r in single.values()), default=None),
        "two_worker_speedup": _speedup(vectors.get("grasp", next(iter(vectors.values()))), args.envs_per_worker),
        "two_worker_speedup_lockstep": _speedup(vectors.get("grasp", next(iter(vectors.values()))),
                                                args.envs_per_worker, grouped=False),
        "envs_per_worker": args.envs_per_worker,
        "search_env_over_grasp_env": ratio["search_env_over_grasp_env"], "search_over_grasp": ratio,
        "single_process": single, "vector": vectors, "failed": failed, "cpu_count": os.cpu_count(),
        "load_average_1min_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "args": vars(args),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
