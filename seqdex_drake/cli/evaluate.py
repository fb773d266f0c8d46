"""``seqdex evaluate``: success rates of a trained chain, its ablations and the feasibility pose scatter.

    seqdex evaluate --run-dir runs/chain [--task building_blocks|tool_positioning] [--episodes 10] [--seeds 3]
                    [--objects NAME ...] [--workers N] [--resume] [--skip-ablations] [--test]

Reads the chain run directory (``stages/<task>/best.pt|last.pt``, ``feasibility/<task>.pt``, optional
``feasibility/<task>_h<H>.pt``; missing files are untrained stages, listed in the tables' notes) and writes into
``<run-dir>/evaluation/`` (or ``--out``): ``table1_building_blocks.md|csv`` or ``table2_tool_positioning.md|csv``
(success per object, trained / unseen / all, mean ± std over seeds), ``ablation_switching.md|csv``,
``ablation_history.md|csv`` (settings whose F files are missing are skipped with a note),
``feasibility_pose_scatter.png|csv`` and ``episodes.jsonl`` (one record per episode; ``--resume`` continues a
run from it). ``--objects``: only these objects, in the table and the ablations (tools: hammer spatula spoon;
blocks: types 1 .. 8); the trained / unseen / all groups are over the objects that ran (a group without one is
"-"). ``--workers N``: the episodes run in N processes, the seeds split over them (at most one process per seed);
the records and tables are the same as with one. ``--test``: one seed (unless ``--seeds``), one episode per
object (unless ``--episodes``), 6-tick stages, 1 s episodes, small untrained networks, ablations on one object
(the first of ``--objects``).
"""

from pathlib import Path

from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.cli import TRIGGER_HELP, CliError
from seqdex_drake.controller.switcher import TRIGGERS
from seqdex_drake.evaluation.experiments import EvalConfig, Evaluation, history_available, progress_bar, total_episodes
from seqdex_drake.evaluation.parallel import EvaluationWorkerError
from seqdex_drake.evaluation.runner import ChainRunError
from seqdex_drake.modeling.catalog import object_keys

TEST_STAGE_STEPS = 6
TEST_SECONDS = 1.0


def add_parser(commands) -> None:
    """Adds the ``evaluate`` subcommand to the argparse subparsers object ``commands``."""
    parser = commands.add_parser("evaluate", help="success rates, ablations and feasibility scatter of a chain",
                                 description="Evaluate a chain run: paper Table 1/2 layout, switching and history "
                                 "ablations, feasibility pose scatter.")
    parser.add_argument("--task", choices=["building_blocks", "tool_positioning"], default="building_blocks",
                        help="the task family (default: building_blocks)")
    parser.add_argument("--run-dir", default="runs/chain", help="the chain run directory (default: runs/chain)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    parser.add_argument("--seeds", type=int, help="number of seeds, seed .. seed + n - 1 (default: 3; 1 with --test)")
    parser.add_argument("--episodes", type=int, help="episodes per object and seed (default: 10; 1 with --test)")
    parser.add_argument("--max-switches", type=int, default=3, help="switch cap of the main table (default: 3)")
    parser.add_argument("--out", help="output directory (default: <run-dir>/evaluation)")
    parser.add_argument("--label", default="", help="the main table's row name (default: ours (max N switches))")
    parser.add_argument("--skip-ablations", action="store_true", help="only the main table and the scatter")
    parser.add_argument("--objects", nargs="+", metavar="NAME",
                        help="only these objects: tools hammer, spatula, spoon; block types 1 .. 8 (default: all)")
    parser.add_argument("--workers", type=int, default=1,
                        help="processes running the episodes, seeds split over them (default: 1)")
    parser.add_argument("--resume", action="store_true", help="keep the episodes already in <out>/episodes.jsonl")
    parser.add_argument("--chain", default="",
                        help="another chain of the family's stages (diagrams/chains.yaml), e.g. "
                             "building_blocks_policies (without the scripted retrieve); default: the family's own")
    parser.add_argument("--trigger", choices=TRIGGERS, default="",
                        help=TRIGGER_HELP)
    parser.add_argument("--test", action="store_true", help="a tiny budget for smoke tests and CI")


def run(args) -> int:
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise CliError(f"run directory {run_dir} does not exist; train the chain first or pass --run-dir")
    episodes = args.episodes if args.episodes is not None else (1 if args.test else 10)
    seeds = args.seeds if args.seeds is not None else (1 if args.test else 3)
    if episodes < 1 or seeds < 1:
        raise CliError("--episodes and --seeds must be at least 1")
    if args.max_switches < 0:
        raise CliError("--max-switches must be >= 0")
    if args.workers < 1:
        raise CliError("--workers must be at least 1")
    try:
        objects = None if args.objects is None else object_keys(args.task, args.objects)
    except ValueError as error:
        raise CliError(f"--objects: {error}") from error
    try:
        stages = len(LoadChain(args.chain or args.task).stages)
    except ValueError as error:
        raise CliError(f"--chain: {error}") from error
    test_ablation = objects[:1] if objects else ((1,) if args.task == "building_blocks" else (0,))
    config = EvalConfig(
        family=args.task, run_dir=str(run_dir), out_dir=args.out or str(run_dir / "evaluation"), episodes=episodes,
        seeds=tuple(range(args.seed, args.seed + seeds)), max_switches=args.max_switches,
        stage_steps=(TEST_STAGE_STEPS,) * stages if args.test else None,
        time_limit=TEST_SECONDS if args.test else None,
        ablation_objects=test_ablation if args.test else None,
        untrained_hidden_sizes=(64, 64) if args.test else None, resume=args.resume, objects=objects,
        workers=args.workers, label=args.label, chain=args.chain, trigger=args.trigger)
    available = 0 if args.skip_ablations else history_available(config)
    total = total_episodes(config, available, ablations=not args.skip_ablations)
    bar = progress_bar(total, f"evaluate {args.task}")
    evaluation = Evaluation(config, progress=bar)
    written = []
    try:
        written += evaluation.main_table()
        written.append(evaluation.scatter())
        if not args.skip_ablations:
            written += evaluation.switching_ablation()
            written += evaluation.history_ablation()
    except ChainRunError as error:
        raise CliError(str(error)) from error
    except EvaluationWorkerError as error:
        raise CliError(str(error), code=1) from error
    finally:
        evaluation.close()
        bar.close()
    for path in written:
        print(path)
    return 0
