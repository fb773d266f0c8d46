"""``seqdex``: the command line entry point.

Subcommands (most take ``--run-dir``, ``--seed``, ``--resume`` and ``--test``)::

    seqdex train --task grasp [--steps N] [--num-envs 2] [--initial-states BUFFER] [--checkpoint-seconds S]
    seqdex collect --task grasp --checkpoint RUN/last.pt --episodes N --out BUFFER [--keep-failures]
    seqdex pipeline --chain handover --method seqdex|seqdex_no_temporal|policy_seq|tstar|vchain|scratch|curriculum
    seqdex feasibility --run-dir RUN --task lower [--history H] [--no-temporal]
    seqdex finetune --run-dir RUN
    seqdex evaluate --task building_blocks|tool_positioning --run-dir RUN
    seqdex rollout --task lower --checkpoint RUN/last.pt --episodes N [--out results.json]
    seqdex ship --run-dir RUN [--out checkpoints/<chain>] [--force]
    seqdex simulate [--task building_blocks|tool_positioning] [--checkpoints DIR] [--headless]

``--test`` runs a tiny budget (episodes of a few steps, small networks, one PPO update, two collected
episodes) for smoke tests and CI. Bad input exits with status 2 and a one-line message (no traceback); see
:mod:`seqdex_drake.cli` for the exit codes. Also runnable as ``python -m seqdex_drake.cli.main``.
"""

import argparse
import sys
from collections.abc import Sequence

from seqdex_drake.cli import OBJECTS_HELP, CliError, collect, evaluate, pipeline, rollout, ship, simulate, train
from seqdex_drake.envs.vector import WorkerError
from seqdex_drake.tasks.registry import task_names
from seqdex_drake.tasks.run_config import PRESETS

#: The function that runs each subcommand.
RUNS = {"train": train.run, "collect": collect.run, "evaluate": evaluate.run, "rollout": rollout.run, "ship": ship.run,
        "simulate": simulate.run, "pipeline": pipeline.run_pipeline, "feasibility": pipeline.run_feasibility,
        "finetune": pipeline.run_finetune}


def _common(parser: argparse.ArgumentParser, tasks: list[str], resume_help: str) -> None:
    """Adds the options every subcommand takes."""
    parser.add_argument("--task", required=True, choices=tasks, metavar="TASK",
                        help=f"the sub-task: {', '.join(tasks)}")
    parser.add_argument("--run-dir", help="the run directory (default: runs/<task>)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the run (default: 0)")
    parser.add_argument("--resume", action="store_true", help=resume_help)
    parser.add_argument("--test", action="store_true", help="a tiny budget for smoke tests and CI")


def build_parser() -> argparse.ArgumentParser:
    """The ``seqdex`` argument parser with its subcommands."""
    tasks = task_names()
    parser = argparse.ArgumentParser(prog="seqdex", description="Sequential Dexterity on Drake: train sub-task "
                                     "policies and chain them.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    train = commands.add_parser("train", help="train a sub-task policy with PPO",
                                description="PPO on one sub-task's process vector env.")
    _common(train, tasks, "continue the run in --run-dir from its last.pt (same counters, optimizer, RNG)")
    train.add_argument("--steps", type=int,
                       help="total environment steps of the run (summed over envs); whole updates of num-envs x "
                            "horizon steps are run, so the run stops at the first multiple at or above it")
    train.add_argument("--num-envs", type=int,
                       help="parallel envs (default: the preset's, 32 for budget, 16 for paper)")
    train.add_argument("--preset", choices=PRESETS, default="budget",
                       help="budget (default): the small-budget task variant where the task has one (the release's "
                            "scripted phases) and PPO hyperparameters that fit two CPU cores; paper: the paper's MDP "
                            "and its PPO tables (for users with a cluster)")
    train.add_argument("--demos", metavar="FILE",
                       help="demonstrations (scripts/collect_demos.py): behaviour-clone the policy on them first, "
                            "then train PPO with the decaying DAPG term (weight --demo-coef)")
    train.add_argument("--demo-coef", type=float, default=0.1,
                       help="DAPG lambda0, the demonstration term's initial weight (default 0.1; with --demos)")
    train.add_argument("--envs-per-worker", type=int,
                       help="envs each worker process steps in turn (default: ceil(num-envs / cores), one process "
                            "per core); any value gives the same results")
    train.add_argument("--initial-states", metavar="BUFFER",
                       help="start episodes from the previous sub-task's terminal buffer (seqdex collect)")
    train.add_argument("--checkpoint-seconds", type=float, metavar="S",
                       help="also write last.pt after an update that ends S s or more after the last write "
                            "(default: PPOConfig.checkpoint_seconds, 300; inf: every checkpoint_every updates only); "
                            "Ctrl-C and SIGTERM always write it before exiting")

    collect = commands.add_parser("collect", help="roll out a trained policy into the next task's terminal buffer",
                                  description="Deterministic rollouts of a trained sub-task policy; successful "
                                  "terminal states go to a terminal buffer for the next sub-task.")
    _common(collect, tasks, "append to the existing --out buffer instead of replacing it")
    collect.add_argument("--checkpoint", help="the policy checkpoint (default: <run-dir>/last.pt)")
    collect.add_argument("--episodes", type=int, help="episodes to roll out (default: 100; 2 with --test)")
    collect.add_argument("--out", help="the buffer file (default: <run-dir>/terminal_<task>_to_<next>.npz)")
    collect.add_argument("--keep-failures", action="store_true", help="also record unsuccessful episodes")
    collect.add_argument("--objects", nargs="+", metavar="NAME", help=OBJECTS_HELP)
    collect.add_argument("--preset", choices=PRESETS,
                         help="the task variant the policy was trained on (default: the preset in the run's "
                              "config.json beside the checkpoint, else paper); e.g. budget for a shipped stage "
                              "checkpoint (checkpoints/<family>/stages/<task>/best.pt)")
    collect.add_argument("--zero-action", action="store_true",
                         help="roll out no policy: the zero action, i.e. a residual variant's script alone (default "
                              "preset: budget), e.g. the hand-offs of a scripted tool Grasp")
    collect.add_argument("--base", metavar="NAME",
                         help="with --zero-action: this residual base instead of the variant's (seqdex rollout --base)")

    pipeline.add_parsers(commands)
    evaluate.add_parser(commands)
    rollout.add_parser(commands)
    ship.add_parser(commands)
    simulate.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parses ``argv`` (default: ``sys.argv[1:]``), runs the subcommand and returns its exit code.

    Argument errors (an unknown task included) exit through argparse with status 2; a :class:`CliError`
    prints ``seqdex <command>: error: <message>`` to stderr and returns its code; a failed env worker
    (:class:`~seqdex_drake.envs.vector.WorkerError`, with the worker's traceback) returns 1.
    """
    args = build_parser().parse_args(argv)
    run = RUNS[args.command]
    try:
        return run(args)
    except CliError as error:
        print(f"seqdex {args.command}: error: {error}", file=sys.stderr)
        return error.code
    except WorkerError as error:  # A simulator worker failed: its own traceback is the useful part.
        print(f"seqdex {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"seqdex {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
