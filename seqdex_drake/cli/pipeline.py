"""``seqdex pipeline``, ``seqdex feasibility`` and ``seqdex finetune``: the bi-directional pipeline for a chain.

    seqdex pipeline --chain handover --method seqdex [--stage-steps N] [--finetune-steps N] [--iterations M]
                    [--preset paper|budget] [--init TASK=CHECKPOINT ...] [--num-envs N]
    seqdex feasibility --run-dir RUN --task lower [--history H] [--no-temporal]
                       [--recollect [--intermediate N] [--knocked-out N] [--scene TASK=SCENARIO ...]]
                       [--d-model W] [--heads N] [--layers L] [--feedforward W]
    seqdex finetune --run-dir RUN

``pipeline`` runs a whole method (:mod:`seqdex_drake.chaining.pipeline`): forward initialization, backward
fine-tuning and the evaluation, or a baseline on the same phases and budget; ``--resume`` continues an
interrupted run where it stopped. ``--preset budget`` trains each stage's small-budget variant with the budget
PPO preset, and ``--init`` continues a stage's forward phase from a ``seqdex train`` run (``--stage-steps 0``
when every stage has one: the runs already trained count as the forward phase). ``feasibility`` (re)trains F
for one stage of a run from its saved transitions (collecting them first if needed), e.g. for the history
ablation (``--history 0/5/10/15`` writes ``feasibility/<task>_h<H>.pt``); ``--scene`` recollects with stages run
on another station scene than the one they trained on (Building Blocks: Orient and Grasp in the whole pile, as
the chain runs them: ``--scene orient=building_blocks/search --scene grasp=building_blocks/search``).
``finetune`` runs the backward passes of a run whose forward phase is done.
"""

import dataclasses
import sys
from pathlib import Path

from seqdex_drake.chaining.bidirectional import Pipeline
from seqdex_drake.chaining.chain import ChainError, ChainNames, LoadChain
from seqdex_drake.chaining.feasibility import LABELS, FeasibilityConfig
from seqdex_drake.chaining.pipeline import METHODS, PipelineConfig, PipelineError
from seqdex_drake.chaining.stage_envs import default_env_kit
from seqdex_drake.cli import CliError
from seqdex_drake.scenario import LoadScenario, ScenarioError
from seqdex_drake.tasks.registry import KNOCK_OUTS, task_names
from seqdex_drake.tasks.run_config import PRESETS

METHOD_HELP = ("seqdex (ours), seqdex_no_temporal (F without history), policy_seq (forward only), tstar "
               "(discriminator reward), vchain (next policy's critic as F), scratch (one PPO over the chain), "
               "curriculum (one PPO, start moved backward)")


def add_parsers(commands) -> None:
    """Adds ``pipeline``, ``feasibility`` and ``finetune`` to the argparse subparsers object ``commands``."""
    pipeline = commands.add_parser("pipeline", help="run a whole chaining method (forward, backward, evaluation)",
                                   description="Forward initialization, backward fine-tuning and evaluation of a "
                                   "chain, or a baseline on the same budget. " + METHOD_HELP)
    pipeline.add_argument("--chain", required=True, choices=ChainNames(), metavar="CHAIN",
                          help=f"the chain: {', '.join(ChainNames())} (diagrams/chains.yaml)")
    pipeline.add_argument("--method", default="seqdex", choices=METHODS, metavar="METHOD", help=METHOD_HELP)
    pipeline.add_argument("--stage-steps", type=int, help="PPO steps per stage, forward phase")
    pipeline.add_argument("--finetune-steps", type=int, help="PPO steps per backward fine-tuning step")
    pipeline.add_argument("--iterations", type=int, help="M, the forward/backward passes (default 1)")
    pipeline.add_argument("--transition-episodes", type=int, help="rollouts per hand-over for buffers and F")
    pipeline.add_argument("--eval-episodes", type=int, help="chain episodes of the final evaluation")
    pipeline.add_argument("--lambda2", type=float, help="weight of the transition bonus (lambda1 is 1)")
    pipeline.add_argument("--feasibility-label", choices=LABELS,
                          help="what every F regresses: return (paper eq. 1, default) or success (0/1, h = 0.5)")
    pipeline.add_argument("--preset", choices=PRESETS, help="paper: each task's default MDP, the paper's PPO "
                          "(default); budget: each task's small-budget variant and PPO preset (seqdex train "
                          "--preset budget)")
    pipeline.add_argument("--init", action="append", default=[], metavar="TASK=CHECKPOINT",
                          help="continue stage TASK's forward phase from this checkpoint (a seqdex train run's "
                          "last.pt, same preset) for --stage-steps more steps (0 allowed); repeatable")
    pipeline.add_argument("--num-envs", type=int, help="envs of a PPO phase that starts from scratch (default 2)")
    pipeline.add_argument("--backend", choices=["process", "serial"], help="vector env of the PPO phases")
    pipeline.add_argument("--envs-per-worker", type=int,
                          help="process backend: envs per worker process (default: ceil(num envs / cores))")
    _common(pipeline, "continue the run in --run-dir where it stopped (same flags)")

    feasibility = commands.add_parser("feasibility", help="train a stage's transition feasibility function",
                                      description="Trains F for one stage of a pipeline run from the previous "
                                      "stage's terminal histories and this stage's returns.")
    feasibility.add_argument("--task", required=True, help="the stage whose F to train (not the first)")
    feasibility.add_argument("--history", type=int, default=10, help="H, observations per input (default 10)")
    feasibility.add_argument("--no-temporal", action="store_true", help="the MLP on the last observation")
    feasibility.add_argument("--label", choices=LABELS, help="what F regresses: return (paper eq. 1; h from the "
                             "successful returns) or success (0/1, the release's label; h = 0.5); default: the "
                             "run's --feasibility-label")
    feasibility.add_argument("--folds", type=int, default=0, metavar="K",
                             help="also report the out-of-fold R^2 and AUC of K stratified folds (K >= 2; K more "
                             "fits, the F written is the same)")
    feasibility.add_argument("--out", help="output file (default: feasibility/<task>.pt for H = 10, else "
                             "feasibility/<task>_h<H>.pt)")
    feasibility.add_argument("--recollect", action="store_true",
                             help="collect the transitions again with the run's current policies (e.g. after the "
                             "fine-tuning: the F the switcher deploys), replacing transitions/<task>.npz")
    feasibility.add_argument("--intermediate", type=int, default=0, metavar="N",
                             help="with --recollect: N more rollouts that hand over after a random number of the "
                             "previous stage's steps, so F also knows the states the switcher scores mid-stage")
    feasibility.add_argument("--knocked-out", type=int, default=0, metavar="N",
                             help="with --recollect: N more rollouts whose object is knocked out of the hand late in "
                             "the previous stage (tool Grasp: the tool back on the table), so F knows a dropped "
                             "object and the switcher goes back for it")
    feasibility.add_argument("--scene", action="append", default=[], metavar="TASK=SCENARIO",
                             help="with --recollect: run stage TASK (this one or an earlier one) on this station "
                             "scenario, e.g. orient=building_blocks/search (Orient in the whole pile, as the "
                             "chain runs it, instead of its training scene); repeatable")
    defaults = FeasibilityConfig()
    for flag, name, what in (("--d-model", "d_model", "embedding and attention width"),
                             ("--heads", "heads", "attention heads"), ("--layers", "layers", "encoder layers"),
                             ("--feedforward", "feedforward", "encoder feed-forward width")):
        feasibility.add_argument(flag, type=int, default=getattr(defaults, name),
                                 help=f"the attention F's {what} (default {getattr(defaults, name)})")
    _common(feasibility, "reuse the run's saved transitions (always done when present)", run_dir_required=True)

    finetune = commands.add_parser("finetune", help="backward fine-tuning of a run whose forward phase is done",
                                   description="Algorithm 1's backward passes: for i = K..2 fine-tune pi_{i-1} "
                                   "with lambda1 R + lambda2 F^i, then evaluate.")
    _common(finetune, "continue an interrupted fine-tuning", run_dir_required=True)


def _common(parser, resume_help: str, run_dir_required: bool = False) -> None:
    parser.add_argument("--run-dir", required=run_dir_required,
                        help="the pipeline run directory" + ("" if run_dir_required else
                                                              " (default: runs/<chain>_<method>_s<seed>)"))
    parser.add_argument("--seed", type=int, default=0, help="seed of the run (default: 0)")
    parser.add_argument("--resume", action="store_true", help=resume_help)
    parser.add_argument("--test", action="store_true", help="a tiny budget for smoke tests and CI")


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _summary(results: dict) -> str:
    switcher = results.get("success_rate_switcher")
    extra = "" if switcher is None else f", with the switcher {switcher:.3f}"
    return (f"{results['method']} on {results['chain']}: chain success {results['success_rate']:.3f}{extra} over "
            f"{results['evaluation']['sequential']['episodes']} episodes; {results['ppo_steps']} PPO steps, "
            f"{results['wall_clock_s']:.0f} s")


def run_pipeline(args) -> int:
    overrides = {key: value for key, value in (
        ("stage_steps", args.stage_steps), ("finetune_steps", args.finetune_steps), ("iterations", args.iterations),
        ("transition_episodes", args.transition_episodes), ("eval_episodes", args.eval_episodes),
        ("lambda2", args.lambda2), ("backend", args.backend), ("envs_per_worker", args.envs_per_worker),
        ("num_envs", args.num_envs), ("preset", args.preset), ("feasibility_label", args.feasibility_label))
        if value is not None}
    init = _init_checkpoints(args.init)
    for key, value in overrides.items():
        if key in ("backend", "lambda2", "preset", "feasibility_label") or (
                key == "stage_steps" and value == 0 and init):
            continue
        if value < 1:
            raise CliError(f"--{key.replace('_', '-')} must be >= 1, got {value}")
    if init:
        overrides["init_checkpoints"] = init
    try:
        chain = LoadChain(args.chain, valid_tasks=task_names())
        strangers = sorted(set(init) - set(chain.stages))
        if strangers:
            raise CliError(f"--init names {', '.join(strangers)}, not a stage of {args.chain} "
                           f"({' -> '.join(chain.stages)})")
        if overrides.get("stage_steps") == 0 and set(init) != set(chain.stages):
            raise CliError(f"--stage-steps 0 leaves the stages without --init untrained "
                           f"({', '.join(t for t in chain.stages if t not in init)}); give each one a checkpoint")
        make = PipelineConfig.tiny if args.test else PipelineConfig
        config = make(chain=args.chain, method=args.method, seed=args.seed, **overrides)
        run_dir = Path(args.run_dir or f"runs/{args.chain}_{args.method}_s{args.seed}")
        pipeline = Pipeline(chain, config, run_dir, resume=args.resume, progress=sys.stderr.isatty(), log=_log,
                            env_kit=default_env_kit())
        results = pipeline.execute()
    except (ChainError, PipelineError, FileNotFoundError) as error:
        raise CliError(str(error)) from error
    except RuntimeError as error:  # A phase that cannot go on (no success to hand over, ...): not bad input.
        raise CliError(str(error), code=1) from error
    print(f"seqdex pipeline: {_summary(results)}; results in {run_dir / 'results.json'}")
    return 0


def _task_pairs(flag: str, values: list[str], form: str, example: str) -> dict[str, str]:
    """Repeated ``FLAG TASK=VALUE`` flags (``form`` names them, e.g. TASK=CHECKPOINT) as a dict; :class:`CliError`
    for a malformed one or a task named twice."""
    pairs = {}
    for value in values:
        task, sep, item = value.partition("=")
        if not sep or not task or not item:
            raise CliError(f"{flag} {value!r}: expected {form}, e.g. {flag} {example}")
        if task in pairs:
            raise CliError(f"{flag} names {task} twice")
        pairs[task] = item
    return pairs


def _init_checkpoints(values: list[str]) -> dict[str, str]:
    """``--init TASK=CHECKPOINT`` flags as a dict; :class:`CliError` for a malformed one or a missing file."""
    init = _task_pairs("--init", values, "TASK=CHECKPOINT", "tool_grasp=runs/x/last.pt")
    for task, path in init.items():
        if not Path(path).is_file():
            raise CliError(f"--init {task}: {path} does not exist")
    return init


def _open(args):
    try:
        return Pipeline.open(args.run_dir, progress=sys.stderr.isatty(), log=_log, env_kit=default_env_kit())
    except (ChainError, PipelineError) as error:
        raise CliError(str(error)) from error


def _scenes(values: list[str], stages: list[str], task: str, recollect: bool) -> dict[str, str]:
    """``--scene TASK=SCENARIO`` flags as a dict; :class:`CliError` for a malformed one, a stage that does not run
    in the collection (after ``task``, or not in the chain), a scenario that does not load, or no ``--recollect``."""
    if values and not recollect:
        raise CliError("--scene needs --recollect: it changes where the transitions are collected")
    scenes = _task_pairs("--scene", values, "TASK=SCENARIO", "orient=building_blocks/search")
    for stage, scene in scenes.items():
        if stage not in stages:
            raise CliError(f"--scene {stage}: not a stage the collection for {task} runs ({', '.join(stages)})")
        try:
            LoadScenario(scene)
        except (ScenarioError, OSError, ValueError, KeyError) as error:
            raise CliError(f"--scene {stage}: scenario {scene!r} does not load: {error}") from error
    return scenes


def run_feasibility(args) -> int:
    pipeline = _open(args)
    if args.task not in pipeline.stages:
        raise CliError(f"{args.task} is not a stage of the run's chain ({' -> '.join(pipeline.stages)})")
    index = pipeline.stages.index(args.task)
    if index == 0:
        raise CliError(f"{args.task} is the chain's first stage: no F^1 exists (F^i scores hand-overs into stage i)")
    if not 0 <= args.history <= 15:
        raise CliError(f"--history must be in 0..15 (the saved transitions hold 15 steps), got {args.history}")
    collecting = args.recollect or not pipeline.run.transitions(args.task).is_file()
    for task in pipeline.stages[:index + 1] if collecting else ():  # Saved transitions need no policy.
        if not pipeline.run.policy(task).is_file():
            raise CliError(f"{pipeline.run.policy(task)} is missing; run seqdex pipeline on {args.run_dir} first")
    if args.folds < 0 or args.folds == 1:
        raise CliError(f"--folds takes 0 (none) or K >= 2, got {args.folds}")
    for flag, count in (("--intermediate", args.intermediate), ("--knocked-out", args.knocked_out)):
        if count < 0 or (count and not args.recollect):
            raise CliError(f"{flag} takes a count >= 0 and needs --recollect")
    if args.knocked_out and pipeline.stages[index - 1] not in KNOCK_OUTS:
        raise CliError(f"--knocked-out: no knock-out is defined for {pipeline.stages[index - 1]}, the stage before "
                       f"{args.task} (defined for: {', '.join(KNOCK_OUTS)})")
    scenes = _scenes(args.scene, pipeline.stages[:index + 1], args.task, args.recollect)
    for task, scene in scenes.items():
        position = pipeline.stages.index(task)
        pipeline.task_configs[position] = dataclasses.replace(pipeline.task_configs[position], scenario=scene)
    architecture = {name: getattr(args, name) for name in ("d_model", "heads", "layers", "feedforward")}
    if min(architecture.values()) < 1:
        raise CliError(f"--d-model, --heads, --layers and --feedforward must be >= 1, got {architecture}")
    try:
        FeasibilityConfig(**architecture)
    except ValueError as error:
        raise CliError(f"bad F architecture: {error}") from error
    try:
        if args.recollect:  # Its own phase name: an interrupted recollection resumes, a finished one is kept.
            phase = f"transitions_recollect_{args.task}_i{args.intermediate}" + (
                f"_k{args.knocked_out}" if args.knocked_out else "") + "".join(
                f"_{task}@{scene.replace('/', '-')}" for task, scene in sorted(scenes.items()))
            pipeline.collect_transition_data(phase, index, intermediate=args.intermediate,
                                             knocked_out=args.knocked_out)
        elif not pipeline.run.transitions(args.task).is_file():
            pipeline.collect_transition_data(f"transitions_cli_{args.task}", index)
        temporal = not args.no_temporal and args.history > 0
        default = pipeline.run.feasibility(args.task)
        out = Path(args.out) if args.out else (default if temporal and args.history == 10 else
                                                default.with_name(f"{args.task}_h{args.history if temporal else 0}.pt"))
        try:
            outcome = pipeline.fit_feasibility(index, args.history, temporal, out, label=args.label,
                                               folds=args.folds, **architecture)
        except ValueError as error:  # The data cannot define F (e.g. no positive threshold h): nothing is written.
            raise CliError(f"F for {args.task} cannot be fitted from {pipeline.run.transitions(args.task)} (kept): "
                           f"{error}", code=1) from error
        # On the record, so what a shipped F was fitted on is known (seqdex ship copies pipeline.json's summary).
        pipeline.run.finish(f"feasibility_cli_{args.task}_h{outcome['history']}",
                            dict(outcome, out=str(out), recollected=args.recollect, intermediate=args.intermediate,
                                 knocked_out=args.knocked_out,
                                 scenes=scenes))
    except RuntimeError as error:
        raise CliError(str(error), code=1) from error
    print(f"seqdex feasibility: F for {args.task} (H = {outcome['history']}, {'attention' if temporal else 'MLP'}, "
          f"{outcome['label']} label), h = {outcome['threshold']:.4g}, validation R^2 {outcome['val_r2']:.3f}, "
          f"AUC {outcome['val_auc']:.3f} ({outcome['n_val']} hand-overs)"
          + (f"; {outcome['cv_folds']}-fold out-of-fold R^2 {outcome['cv_r2']:.3f}, AUC {outcome['cv_auc']:.3f} "
             f"({outcome['cv_n']} hand-overs)" if "cv_auc" in outcome else "") + f"; wrote {out}")
    return 0


def run_finetune(args) -> int:
    pipeline = _open(args)
    if pipeline.config.method not in ("seqdex", "seqdex_no_temporal", "policy_seq", "tstar", "vchain"):
        raise CliError(f"the run in {args.run_dir} is a {pipeline.config.method} run: it has no stages to fine-tune")
    try:
        pipeline.backward()  # Refuses a run whose forward phase is not done.
        results = pipeline.execute()  # Everything done is skipped: this evaluates and writes results.json.
    except RuntimeError as error:
        raise CliError(str(error), code=1) from error
    print(f"seqdex finetune: {_summary(results)}")
    return 0
