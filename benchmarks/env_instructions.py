"""The env's own cost per step in CPU instructions, counted by Valgrind's callgrind: a figure that does not drift.

``env_throughput.py`` times env / raw, but on a shared machine single tasks move by several per cent between
runs. Instruction counts do not: per sub-task, the env is reset (seed 0), stepped a few times, and then
``--steps`` steps with zero actions are counted, split into the instructions inside ``Simulator::AdvanceTo``
(the physics, which the raw loop runs too) and those outside it (the env's own code: the IK, the observation,
the reward and success test, the wake check, Python and pybind glue). ``outside_fraction`` = outside / total is
what the env's code adds in instructions. It is not the time it adds: that code runs right after the physics,
with its code and data evicted from the caches, at a fraction of the physics' instructions per cycle (see the
README's "Where the env time goes"). The counts exclude what switching the counting on and off costs (an
empty window, measured first).

The script runs itself under ``valgrind --tool=callgrind`` with instrumentation off, switches it on around each
task's counted steps (``callgrind_control``), dumps one profile per task and reads the totals with
``callgrind_annotate``. It needs Valgrind (``apt install valgrind``) and is slow: ~1 min to start, then about
50x the steps' run time. The last line is one JSON object with ``per_step`` (per task: ``total``,
``advance_to``, ``outside``, ``outside_fraction``) and ``outside_min`` / ``outside_max`` over the tasks.

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

    from seqdex_drake.tasks.registry import make_env

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
        control("--instr=on")
        for _ in range(steps):
            env.step(action)
        control(f"--dump={name}")
        control("--instr=off")


def _counts(profile: str) -> tuple[int, int]:
    """(total instructions, instructions inside Simulator::AdvanceTo) of one callgrind dump."""
    with open(profile) as f:
        total = next(int(line.split()[1]) for line in f if line.startswith("totals:"))
    report = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", profile],
                            capture_output=True, text=True, check=True).stdout
    inside = [int(m.group(1).replace(",", "")) for line in report.splitlines()
              if ADVANCE_TO in line and (m := re.match(r"\s*([\d,]+)", line))]
    if not inside:
        raise RuntimeError(f"no {ADVANCE_TO} in {profile}: was the env stepped?")
    return total, max(inside)


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
        command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}/cg",
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
            switching = next(int(line.split()[1]) for line in f if line.startswith("totals:"))
        per_step = {}
        for name in tasks:
            if name not in dumps:
                sys.exit(f"no profile was dumped for {name}")
            total, inside = _counts(dumps[name])
            total -= switching
            per_step[name] = {"total": round(total / args.steps), "advance_to": round(inside / args.steps),
                              "outside": round((total - inside) / args.steps),
                              "outside_fraction": round((total - inside) / total, 4)}
            print(f"{name:14s} instructions per env step {per_step[name]}", flush=True)
    fractions = [r["outside_fraction"] for r in per_step.values()]
    print(json.dumps({"per_step": per_step, "steps": args.steps, "outside_min": min(fractions),
                      "outside_max": max(fractions), "args": vars(args)}))


if __name__ == "__main__":
    main()
