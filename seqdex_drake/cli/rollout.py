"""``seqdex rollout``: evaluate a trained sub-task policy on its own env (any sub-task, a chain's last one included).

    seqdex rollout --task lower --checkpoint runs/lower/best.pt --episodes 100 [--seed 0] [--out results.json]
    seqdex rollout --task tool_grasp --zero-action --episodes 100   # the budget variant's scripted base alone

Episode ``i`` starts from ``env.reset(seed=seed + i)`` (the task's own initial-state distribution) and runs the
policy's mean action (:func:`~seqdex_drake.rl.policy_loading.load_policy`) in one in-process
:class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` until it terminates or truncates; it succeeded if ``success``
holds at its last step. With ``--initial-states B`` (a terminal buffer of the previous sub-task, ``seqdex
collect``) episode ``i`` starts instead from B's successful hand-off number ``(seed + i) mod N`` (N of them), as
forward initialization starts the sub-task: ``--seed 0 --episodes N`` plays each hand-off once. ``--scene``
runs the sub-task on another station scenario with those hand-offs (block Orient from Search's hand-offs in the
whole pile, where the chain runs it, instead of alone in the box). ``--objects`` draws the reset's object from
the named ones only (the unseen block types 6-8, say); every episode records its object, and the summary counts
episodes and successes per object kind. ``--reset-region staging`` puts Orient's and Grasp's block on the
staging area, the clear table where a block taken out of the pile is set down, instead of in the box.
The env is the task variant the policy was trained on (``--preset``, by default the one
recorded in the run's ``config.json`` beside the checkpoint). Prints the success rate and the mean return;
``--out`` also writes them with every episode's seed, return, length and outcome as JSON (the path is checked to
be writable before any rollout).
``--test``: episodes cut to a few steps, 2 episodes unless ``--episodes`` is given.
"""

import dataclasses
import json
import os
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from seqdex_drake.atomic import atomic_write
from seqdex_drake.cli import OBJECTS_HELP, CliError, check_creatable, check_seed, with_base, with_objects
from seqdex_drake.cli.train import load_initial_states
from seqdex_drake.env_state import EnvState
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.evaluation.subtask_episodes import run_episode, summarize
from seqdex_drake.rl.checkpoint import CheckpointError
from seqdex_drake.rl.policy_loading import load_policy
from seqdex_drake.scenario import LoadScenario, ScenarioError
from seqdex_drake.tasks.base import ResetError
from seqdex_drake.tasks.blocks_common import RESET_REGIONS
from seqdex_drake.tasks.registry import task_names
from seqdex_drake.tasks.run_config import PRESETS, observation_spec, run_preset, run_residual, task_config

#: Episodes rolled out when ``--episodes`` is not given (with and without ``--test``).
DEFAULT_EPISODES, TEST_EPISODES = 100, 2


def add_parser(commands) -> None:
    """Adds the ``rollout`` subcommand to the argparse subparsers object ``commands``."""
    tasks = task_names()
    parser = commands.add_parser("rollout", help="success rate and mean return of a trained sub-task policy",
                                 description="Deterministic rollouts of a trained sub-task policy in its own env "
                                 "(any sub-task, the last one of a chain included).")
    parser.add_argument("--task", required=True, choices=tasks, metavar="TASK",
                        help=f"the sub-task: {', '.join(tasks)}")
    parser.add_argument("--checkpoint", help="the policy checkpoint (default: <run-dir>/last.pt)")
    parser.add_argument("--run-dir", help="the training run directory (default: runs/<task>)")
    parser.add_argument("--episodes", type=int,
                        help=f"episodes to roll out (default: {DEFAULT_EPISODES}; {TEST_EPISODES} with --test)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode; episode i uses seed + i "
                        "(default: 0)")
    parser.add_argument("--preset", choices=PRESETS,
                        help="the task variant to roll out in: budget (the small-budget variant where the task has "
                             "one) or paper (default: the preset in the run's config.json beside the checkpoint, "
                             "else paper)")
    parser.add_argument("--zero-action", action="store_true",
                        help="roll out the zero action instead of a checkpoint: a reference, and for a task variant "
                             "with a residual base (TaskConfig.residual) its script alone (default preset: budget)")
    parser.add_argument("--base", metavar="NAME",
                        help="with --zero-action: run this residual base alone instead of the task variant's, e.g. "
                             "tool_pinch_script on tool_grasp (the bases: seqdex_drake.tasks.residual.RESIDUAL_BASES)")
    parser.add_argument("--initial-states", metavar="BUFFER",
                        help="start episode i from this terminal buffer's successful hand-off (seed + i) mod N "
                             "(seqdex collect --task <previous sub-task>), as forward initialization does")
    parser.add_argument("--scene", metavar="SCENARIO",
                        help="run the sub-task on another station scenario than its own, e.g. building_blocks/search "
                             "(Orient in the whole pile, as the chain runs it); needs --initial-states from a "
                             "sub-task of that scene (the task's own resets would not find their objects there)")
    parser.add_argument("--objects", nargs="+", metavar="NAME", help=OBJECTS_HELP)
    parser.add_argument("--reset-region", choices=RESET_REGIONS,
                        help="where Orient's and Grasp's resets put the block: box (where they train; the default) "
                             "or staging (the clear table area where a block taken out of the pile is set down)")
    parser.add_argument("--out", help="also write the results to this JSON file")
    parser.add_argument("--test", action="store_true", help="a tiny budget for smoke tests and CI")


def _load(args, checkpoint: Path):
    """The deterministic policy of ``checkpoint``; :class:`CliError` if it is missing or unreadable."""
    try:
        return load_policy(checkpoint, deterministic=True)
    except FileNotFoundError as error:
        raise CliError(f"{error}, or train one first: seqdex train --task {args.task}") from error
    except (CheckpointError, ValueError) as error:
        raise CliError(str(error)) from error


def _check(args, checkpoint: Path, policy, env) -> None:
    """Raises :class:`CliError` unless ``policy`` reads ``env``'s observations and acts in its action space."""
    try:
        policy.check_observation_spec(observation_spec(args.task, env.observation_space.shape[0]),
                                      f"the {args.task} env")
    except ValueError as error:
        raise CliError(str(error)) from error
    if policy.action_dim != env.action_space.shape[0]:
        raise CliError(f"checkpoint {checkpoint} is a policy for {policy.action_dim} actions, the {args.task} env "
                       f"has {env.action_space.shape[0]}")


def _hand_offs(args) -> list | None:
    """The successful hand-off states of ``--initial-states`` (as ``EnvState``), or None without it."""
    if args.initial_states is None:
        return None

    buffer = load_initial_states(args.initial_states, args.task)
    return [buffer.state(i, EnvState) for i in range(len(buffer)) if buffer.successes[i]]


def _scene(args) -> str | None:
    """``--scene``, checked: a scenario that loads, given with ``--initial-states``; None without it."""
    if args.scene is None:
        return None

    if args.initial_states is None:
        raise CliError(f"--scene {args.scene} needs --initial-states: the {args.task} task's own resets place their "
                       f"objects on its own scene")
    try:
        LoadScenario(args.scene)
    except (ScenarioError, OSError, ValueError) as error:
        raise CliError(f"--scene {args.scene}: {error}") from error
    return args.scene


def _on_scene(config, scene: str | None, region: str | None = None):
    config = config if region is None else dataclasses.replace(config, reset_region=region)
    return config if scene is None else dataclasses.replace(config, scenario=scene)


def run(args) -> int:
    """Runs ``seqdex rollout`` with the parsed ``args``; returns the exit code."""
    episodes = args.episodes if args.episodes is not None else (TEST_EPISODES if args.test else DEFAULT_EPISODES)
    if episodes < 1:
        raise CliError(f"--episodes must be >= 1, got {episodes}")
    checkpoint = Path(args.checkpoint) if args.checkpoint else Path(args.run_dir or f"runs/{args.task}") / "last.pt"
    check_seed(args.seed)
    check_seed(args.seed + episodes - 1, "--seed + --episodes - 1 (the last episode's seed)")
    out = Path(args.out) if args.out else None
    if out is not None:
        check_creatable(out, "--out")  # Before the rollouts, not after them.
    starts = _hand_offs(args)
    scene = _scene(args)
    if args.reset_region and (args.task not in ("orient", "grasp") or starts is not None):
        raise CliError("--reset-region places the block of Orient's and Grasp's own resets; "
                       f"{'--initial-states fix the start' if starts is not None else args.task + ' has none'}")
    if args.zero_action:  # No policy: the zero action (a residual variant's script alone).
        if args.checkpoint or args.run_dir:
            raise CliError("--zero-action rolls out no policy; drop --checkpoint / --run-dir")
        preset = args.preset or "budget"
        config = with_objects(_on_scene(task_config(args.task, args.test, preset), scene, args.reset_region),
                              args.task, args.objects, starts)
        config = with_base(config, args.task, args.base)
        env = make_env(args.task, config)
        zeros = np.zeros(env.action_space.shape, dtype=np.float32)
        policy, checkpoint = (lambda observation: zeros), "the zero action" + (
            f" (the {config.residual} base alone)" if config.residual else "")
    else:
        if args.base:
            raise CliError(f"--base {args.base} runs a residual base alone: add --zero-action (a checkpoint brings "
                           f"the base it was trained on)")
        preset = args.preset or run_preset(checkpoint)
        config = with_objects(_on_scene(task_config(args.task, args.test, preset,
                                                    residual=run_residual(checkpoint)), scene, args.reset_region),
                              args.task, args.objects, starts)
        policy = _load(args, checkpoint)
        env = make_env(args.task, config)
        _check(args, checkpoint, policy, env)
    try:
        records = [run_episode(env, policy, args.seed + episode,
                               None if starts is None else starts[(args.seed + episode) % len(starts)])
                   for episode in tqdm(range(episodes), desc=f"rollout {args.task}", unit="episode",
                                       disable=not sys.stderr.isatty())]
    except ResetError as error:  # Nothing is written: --out only after every episode.
        raise CliError(f"{args.task}: {error}") from error
    summary = summarize(records)
    print(f"seqdex rollout: {args.task}: success rate {summary['success_rate']:.3f} "
          f"({sum(record['success'] for record in records)}/{episodes}), mean return {summary['mean_return']:.3f} "
          f"(std {summary['std_return']:.3f}), mean length {summary['mean_length']:.1f} steps; policy {checkpoint}, "
          f"{preset} task variant")
    if out is not None:
        result = {"task": args.task, "checkpoint": os.fspath(checkpoint), "episodes": episodes, "seed": args.seed,
                  "preset": preset, "initial_states": args.initial_states, "scene": config.scenario,
                  "object_types": list(config.object_types), "reset_region": config.reset_region,
                  "test": bool(args.test),
                  "episode_length": config.episode_length,
                  "deterministic": True, **summary, "per_episode": records}
        atomic_write(out, lambda file: file.write((json.dumps(result, indent=2) + "\n").encode()))
        print(f"seqdex rollout: wrote {out}")
    return 0
