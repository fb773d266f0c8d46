"""``seqdex simulate``: run a whole Sequential Dexterity task in Drake, live in meshcat.

Building Blocks (default): the blocks of an assembly manual (``diagrams/manuals/``), one after another, each
Search -> Orient -> Grasp -> Insert onto its goal on the baseplate. Tool Positioning: the hammer, grasp ->
reorient. The sub-policies and feasibility functions come from a chain run directory (``--checkpoints``:
``stages/<task>/best.pt|last.pt``, ``feasibility/<task>.pt``); missing files mean untrained stages, which are
listed, and the chain still runs (untrained policies barely move the hand once the arm has approached).

In the browser, the row of cubes on the far edge of the table shows the running stage (coloured and raised),
the bars between them the feasibility scores c = F / h (green above the threshold slab c = 1); the control
panel ("Open Controls") shows the stage as text and the scores as read-only sliders
(``seqdex_drake/evaluation/display.py``).

    seqdex simulate                                                   # meshcat URL printed; Ctrl-C to stop
    seqdex simulate --manual mixed_shapes --checkpoints runs/chain
    seqdex simulate --task tool_positioning --record replay.html
    seqdex simulate --test --headless                                 # a short run for CI, exits 0

``python scripts/simulate_chain.py`` (the README's main command) takes the same flags.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat, MeshcatParams

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.cli import TRIGGER_HELP, CliError
from seqdex_drake.controller.switcher import TRIGGERS
from seqdex_drake.evaluation.runner import ChainRunError, ChainRunner, RunConfig
from seqdex_drake.manual import LoadManual, ManualError, goal_vector, pinch_conflicts
from seqdex_drake.scenario import ScenarioError
from seqdex_drake.user_input import MAX_SEED, check_creatable

#: Stage budgets (control ticks) and simulated seconds under --test.
TEST_STAGE_STEPS = 6
TEST_SECONDS = 1.0
#: Meshcat's ports: Drake aborts the process for a privileged one (below 1024); above 65535 would wrap.
MIN_PORT, MAX_PORT = 1024, 65535
#: The repository's shipped checkpoints, one folder per task family (``seqdex_drake/chaining/shipped.py``).
SHIPPED = Path(__file__).resolve().parents[2] / "checkpoints"


def add_parser(commands) -> None:
    """Adds the ``simulate`` subcommand to the argparse subparsers object ``commands``."""
    parser = commands.add_parser("simulate", help="run a whole task's chain in Drake, live in meshcat",
                                 description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=["building_blocks", "tool_positioning"], default="building_blocks")
    parser.add_argument("--manual", default="small_wall",
                        help="assembly manual: a YAML file or a name in diagrams/manuals/ (default: small_wall)")
    parser.add_argument("--checkpoints", metavar="DIR",
                        help="chain run directory or shipped checkpoint folder (default: checkpoints/<task> where "
                             "shipped, else all untrained)")
    parser.add_argument("--untrained", action="store_true", help="run untrained policies even where shipped")
    parser.add_argument("--seed", type=int, default=0, help="random seed (pile, tool yaw, untrained policies)")
    parser.add_argument("--max-switches", type=int, default=3, help="feasibility switches per object (default 3)")
    parser.add_argument("--trigger", choices=TRIGGERS, default="",
                        help=TRIGGER_HELP)
    parser.add_argument("--duration", type=float, default=float("inf"),
                        help="stop after this many simulated seconds (default: when the manual is done)")
    parser.add_argument("--headless", action="store_true", help="no meshcat")
    parser.add_argument("--port", type=int, default=7000,
                        help=f"meshcat port, {MIN_PORT}-{MAX_PORT}; a busy one falls back to a free one")
    parser.add_argument("--record", metavar="HTML", help="save a standalone HTML replay of the run")
    parser.add_argument("--test", action="store_true",
                        help=f"a short run for CI: {TEST_SECONDS} s simulated, {TEST_STAGE_STEPS}-tick stages, "
                             "small untrained networks; exits when done")


def start_meshcat(port: int):
    """A Meshcat on ``port``, or on Drake's first free port (7000-7099) when that one is taken."""
    try:
        return Meshcat(MeshcatParams(port=port))
    except RuntimeError:
        meshcat = Meshcat()
        print(f"meshcat: port {port} is busy; using port {meshcat.port()}", flush=True)
        return meshcat


def objects_to_run(args, runner, rng):
    """(label, start function) per object: the manual's steps, or the hammer."""
    if args.task == "tool_positioning":
        return [("tool 1/1: hammer", lambda: runner.start_tool(0, rng))]
    steps = args.manual_steps
    return [(f"block {k + 1}/{len(steps)}: type {step.block_type}",
             lambda step=step: runner.start_block(step.block_type, goal_vector(step))) for k, step in enumerate(steps)]


def check_args(args) -> None:
    """Refuses numbers out of range and a --record path that cannot be written, before anything is built."""
    if not 0 <= args.seed <= MAX_SEED:
        raise CliError(f"--seed must be in 0 .. {MAX_SEED}, got {args.seed}")
    if not MIN_PORT <= args.port <= MAX_PORT:
        raise CliError(f"--port must be in {MIN_PORT} .. {MAX_PORT}, got {args.port}")
    if not args.duration > 0:
        raise CliError(f"--duration must be > 0 simulated seconds, got {args.duration}")
    if args.max_switches < 0:
        raise CliError(f"--max-switches must be >= 0, got {args.max_switches}")
    if args.record and args.headless:
        raise CliError("--record needs meshcat; drop --headless")
    if args.record:
        check_creatable(args.record, "--record")


def run(args) -> int:
    """Runs ``seqdex simulate`` with the parsed ``args``; returns the exit code (1 if the state went non-finite)."""
    check_args(args)
    if args.task == "building_blocks":
        try:
            manual = LoadManual(args.manual)
        except ManualError as error:
            raise CliError(str(error)) from error
        except (OSError, UnicodeDecodeError) as error:  # A directory, an unreadable or a binary file.
            reason = "not a text file" if isinstance(error, UnicodeDecodeError) else (error.strerror or error)
            raise CliError(f"--manual {args.manual}: cannot read it as a YAML assembly manual ({reason})") from error
        args.manual_steps = manual.steps
        for problem in pinch_conflicts(manual):  # A valid structure the hand may still not build.
            print(f"seqdex simulate: warning: --manual {args.manual}: {problem}", file=sys.stderr)
    if args.checkpoints is not None and not Path(args.checkpoints).is_dir():
        what = "is a file, not a directory" if Path(args.checkpoints).exists() else "does not exist"
        raise CliError(f"--checkpoints {args.checkpoints} {what}; name a chain run directory or a shipped "
                       f"checkpoint folder (e.g. checkpoints/{args.task})")
    shipped = SHIPPED / args.task
    if args.checkpoints is None and not args.untrained and (shipped / "manifest.json").is_file():
        args.checkpoints = str(shipped)
        print(f"using the shipped checkpoints in {shipped} (--checkpoints DIR for others, --untrained for none)",
              flush=True)
    meshcat = None if args.headless else start_meshcat(args.port)
    if meshcat is not None:
        meshcat.SetCameraPose([1.45, -0.25, 1.35], [0.15, -0.05, 0.62])
        print(f"meshcat: open {meshcat.web_url()} in a browser", flush=True)
    config = RunConfig(family=args.task, run_dir=args.checkpoints, max_switches=args.max_switches, seed=args.seed,
                       trigger=args.trigger,
                       stage_steps=(TEST_STAGE_STEPS,) * len(LoadChain(args.task).stages) if args.test else None,
                       untrained_hidden_sizes=(64, 64) if args.test else None)
    print(f"building the {args.task} station and chain controller ...", flush=True)
    try:
        runner = ChainRunner(config, meshcat=meshcat)
    except (ChainRunError, ScenarioError) as error:
        raise CliError(str(error)) from error
    print(f"chain: {' -> '.join(runner.tasks)}", flush=True)
    if runner.untrained:
        print(f"untrained policies: {', '.join(runner.untrained)} (random initial weights; they will not "
              f"succeed)", flush=True)
        for line in runner.missing:
            print(f"  {line}", flush=True)
    else:
        scripted = [task for task, policy in zip(runner.tasks, runner.policies, strict=True) if policy.is_scripted]
        print("every stage has a trained policy" + (f" (scripted, no policy: {', '.join(scripted)})" if scripted
                                                   else ""), flush=True)
    if args.record:
        meshcat.StartRecording(set_visualizations_while_recording=True)
    duration = TEST_SECONDS if args.test else args.duration
    rng = np.random.default_rng(args.seed)
    start, successes, interrupted = time.perf_counter(), 0, False
    stage, fetched = [-1], [""]

    def on_tick(r) -> bool:
        if r.target != fetched[0]:
            print(f"  t={r.context.get_time():6.2f} s  {fetched[0]} not taken out of the pile; fetching {r.target}",
                  flush=True)
            fetched[0], stage[0] = r.target, -1
        active = int(r.chain_output("active_stage")[0])
        if active != stage[0]:
            scores = r.chain_output("feasibility_scores")
            shown = ", ".join(f"c[{t}]={c:.2f}" for t, c in zip(r.tasks, scores, strict=True) if np.isfinite(c))
            print(f"  t={r.context.get_time():6.2f} s  stage {active + 1}/{len(r.tasks)}: {r.tasks[active]}"
                  f"{'  (' + shown + ')' if shown else ''}", flush=True)
            stage[0] = active
        return r.context.get_time() < duration

    try:
        for label, begin in objects_to_run(args, runner, rng):
            if runner.context.get_time() >= duration:
                break
            try:
                name = begin()
            except ChainRunError as error:
                raise CliError(str(error)) from error
            stage[0], fetched[0] = -1, name
            print(f"{label} ({name})", flush=True)
            if meshcat is not None and not args.test:
                runner.simulator.set_target_realtime_rate(1.0)
            outcome = runner.run(runner.episode_limit(), on_tick=on_tick)
            successes += outcome.success
            runner.set_completed(successes)
            print(f"  {'placed' if outcome.success else 'not placed'} after {outcome.time:.2f} s "
                  f"(error {outcome.position_error * 100:.1f} cm, {np.degrees(outcome.rotation_error):.0f} deg; "
                  f"{outcome.switches} switch(es))", flush=True)
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - start
    q = runner.objects.positions(runner.context)
    finite = bool(np.all(np.isfinite(q)))
    print(f"simulated {runner.context.get_time():.2f} s in {wall:.1f} s wall; {successes} object(s) placed; "
          f"state finite: {finite}", flush=True)
    if args.record:
        meshcat.StopRecording()
        meshcat.PublishRecording()
        atomic_write(args.record, lambda file: file.write(meshcat.StaticHtml().encode()))
        print(f"replay written to {args.record} ({Path(args.record).stat().st_size / 1e6:.1f} MB)", flush=True)
    if meshcat is not None and not args.test and not interrupted:
        print(f"done; meshcat keeps serving at {meshcat.web_url()} until Ctrl-C", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    return 0 if finite else 1
