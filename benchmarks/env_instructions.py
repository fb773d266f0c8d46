"""The env's own cost per step in CPU instructions and cache misses, counted by Valgrind's callgrind: figures that
do not drift.

``env_throughput.py`` times env / raw, but on a shared machine single tasks move by several per cent between
runs. Instruction counts do not: per sub-task, the env is reset (seed 0), stepped a few times, and then
``--steps`` steps with zero actions are counted, split into the instructions inside ``Simulator::AdvanceTo``
(the physics, which the raw loop runs too) and those outside it (the env's own code: the IK, the observation,
the reward and success test, the wake check, Python and pybind glue). ``outside_fraction`` = outside / total is
what the env's code adds in instructions. It is not the time it adds: that code runs right after the physics,
with its code and data evicted from the caches, at a fraction of the physics' instructions per cycle (see
docs/performance.md, "How the env time is spent"). So callgrind also simulates the caches, with a last level
the size of this machine's per-core L2 (``--LL``, 512 KB, 8-way; L1 32 KB each): ``outside_l2_misses`` counts the lines
the env's code (instructions and data) brings in from beyond that L2 per step, most of them lines the physics evicted
(``outside_l2_instruction_misses`` of them code). That, not the instruction count, is what cold env code costs in
time, ~100-300 cycles a line; an estimate that weighs each by 100 cycles is ``outside_cycles_estimate`` (each L1
miss 10, each instruction 1). The counts exclude what switching the counting on and off costs (an empty window,
measured first).

The script runs itself under ``valgrind --tool=callgrind`` with instrumentation off, switches it on around each
task's counted steps (``callgrind_control``), dumps one profile per task and reads the totals with
``callgrind_annotate``. It needs Valgrind (``apt install valgrind``) and is slow: ~1 min to start, then about
100x the steps' run time. The last line is one JSON object with ``per_step`` (per task: ``total``,
``advance_to``, ``outside``, ``outside_fraction``, ``outside_l1_misses``, ``outside_l2_misses``,
``outside_l2_instruction_misses``, ``outside_cycles_estimate``) and ``outside_min`` / ``outside_max`` (of
``outside_fraction``) over the tasks.

    python benchmarks/env_instructions.py [--tasks grasp tool_grasp ...] [--steps 10] [--test]
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

ADVANCE_TO = "drake::systems::Simulator<double>::AdvanceTo(double const&)"
TOOLS = ("valgrind", "callgrind_control", "callgrind_annotate")
WARMUP_STEPS = 5
CALIBRATION = "calibration"


def _child(tasks: list[str], steps: int) -> None:
    """Under callgrind: for each task, counts ``steps`` env steps and dumps a profile named after the task."""
    import numpy as np

    from seqdex_drake.envs.subtask_env import make_env

    def control(*args: str) -> None:
        subprocess.run(["callgrind_control", *args, str(os.getpid())], check=True, stdout=subprocess.DEVNULL)

    control("--instr=on")  # An empty window: what switching on and dumping costs, subtracted from each task's.
    control(f"--dump={CALIBRATION}")
    control("--instr=off")
    for name in tasks:
        env = make_env(name)
        env.reset(seed=0)
        action = np.zeros(env.action_space.shape)
        for _ in range(WARMUP_STEPS):
            env.step(action)
        control("--zero")  # Each dump from zero (with the cache simulation, later dumps' totals come out wrong).
        control("--instr=on")
        for _ in range(steps):
            env.step(action)
        control(f"--dump={name}")
        control("--instr=off")


EVENTS = ("Ir", "I1mr", "D1mr", "D1mw", "ILmr", "DLmr", "DLmw")
"""Callgrind's events with ``--cache-sim=yes``: instructions, L1 misses (instruction, data read, data write) and
last-level misses (the same three)."""
CACHES = ("--I1=32768,8,64", "--D1=32768,8,64", "--LL=524288,8,64")
"""The simulated caches: 32 KB L1s and, as the last level, the 512 KB per-core L2 of the development machine."""


def _counts(profile: str) -> tuple[dict, dict]:
    """({event: total}, {event: inside Simulator::AdvanceTo}) of one callgrind dump."""
    report = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", profile],
                            capture_output=True, text=True, check=True).stdout
    header = next((line.split(":", 1)[1].split() for line in report.splitlines()
                   if line.startswith("Events shown:")), None)
    if header is None or any(event not in header for event in EVENTS):
        raise RuntimeError(f"callgrind_annotate shows no {EVENTS} for {profile}: was the cache simulated?")

    def values(line: str) -> dict:
        cells = re.findall(r"(?:([\d,]+) \(\s*[\d.]+%\)|(\.))", line)  # "1,234 (5.6%)" or "." (zero).
        numbers = [int(a.replace(",", "")) if a else 0 for a, _ in cells]
        return dict(zip(header, numbers, strict=False))

    totals = next((values(line) for line in report.splitlines() if "PROGRAM TOTALS" in line), None)
    inside = [values(line) for line in report.splitlines() if ADVANCE_TO in line]
    if totals is None or not inside:
        raise RuntimeError(f"no {ADVANCE_TO} in {profile}: was the env stepped?")
    return totals, max(inside, key=lambda v: v["Ir"])


def _outside(totals: dict, inside: dict, switching: dict, steps: int) -> dict:
    """Per step: instructions (total, inside AdvanceTo, outside) and the outside part's cache misses."""
    out = {e: (totals[e] - switching.get(e, 0) - inside[e]) / steps for e in EVENTS}
    total = (totals["Ir"] - switching.get("Ir", 0)) / steps
    l1, l2 = out["I1mr"] + out["D1mr"] + out["D1mw"], out["ILmr"] + out["DLmr"] + out["DLmw"]
    return {"total": round(total), "advance_to": round(inside["Ir"] / steps), "outside": round(out["Ir"]),
            "outside_fraction": round(out["Ir"] / total, 4), "outside_l1_misses": round(l1),
            "outside_l2_misses": round(l2), "outside_l2_instruction_misses": round(out["ILmr"]),
            "outside_cycles_estimate": round(out["Ir"] + 10 * l1 + 100 * l2)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=None, help="sub-tasks (default: the paper's six)")
    parser.add_argument("--steps", type=int, default=10, help="counted env steps per task")
    parser.add_argument("--test", action="store_true", help="a tiny run (tool_grasp, 2 steps)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.test:
        args.tasks, args.steps = args.tasks or ["tool_grasp"], 2
    from seqdex_drake.tasks.registry import PAPER_TASKS, task_names

    tasks = list(args.tasks or PAPER_TASKS)
    unknown = [t for t in tasks if t not in task_names()]
    if unknown:
        parser.error(f"unknown tasks {unknown}; valid: {', '.join(task_names())}")
    if args.steps < 1:
        parser.error("--steps must be at least 1")
    if args.child:
        _child(tasks, args.steps)
        return
    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    if missing:
        sys.exit(f"env_instructions.py needs Valgrind's {', '.join(missing)}: install valgrind "
                 "(e.g. apt install valgrind) and run it again")
    with tempfile.TemporaryDirectory() as out:
        command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--cache-sim=yes", *CACHES,
                   f"--callgrind-out-file={out}/cg",
                   sys.executable, os.path.abspath(__file__), "--child", "--steps", str(args.steps), "--tasks", *tasks]
        done = subprocess.run(command, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
        if done.returncode != 0:
            sys.exit(f"the counted run failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
        dumps = {}
        for path in os.listdir(out):
            with open(os.path.join(out, path)) as f:
                trigger = next((line.split("Trigger: dump ", 1)[1].strip() for line in f
                                if line.startswith("desc: Trigger: dump ")), None)
            if trigger in (*tasks, CALIBRATION):
                dumps[trigger] = os.path.join(out, path)
        if CALIBRATION not in dumps:
            sys.exit("no calibration profile was dumped")
        with open(dumps[CALIBRATION]) as f:
            events, totals = None, None
            for line in f:
                if line.startswith("events:"):
                    events = line.split()[1:]
                elif line.startswith("totals:"):
                    totals = [int(x) for x in line.split()[1:]]
            switching = dict(zip(events or (), totals or (), strict=False))
        per_step = {}
        for name in tasks:
            if name not in dumps:
                sys.exit(f"no profile was dumped for {name}")
            per_step[name] = _outside(*_counts(dumps[name]), switching, args.steps)
            print(f"{name:14s} per env step {per_step[name]}", flush=True)
    fractions = [r["outside_fraction"] for r in per_step.values()]
    print(json.dumps({"per_step": per_step, "steps": args.steps, "outside_min": min(fractions),
                      "outside_max": max(fractions), "args": vars(args)}))


if __name__ == "__main__":
    main()
