"""``seqdex train``: PPO on one sub-task's process vector env, in a run directory that can be resumed.

The run directory holds ``config.json`` (task, resolved :class:`~seqdex_drake.rl.config.PPOConfig` and
:class:`~seqdex_drake.tasks.base.TaskConfig`, initial-state buffer, test flag), ``scenario.yaml`` (the station
scenario, dumped), TensorBoard event files and the ``last.pt`` / ``best.pt`` checkpoints written by
:meth:`~seqdex_drake.rl.ppo.PPO.train`.

``--steps`` is the run's total step count (summed over envs). A resumed run continues from ``last.pt`` with
its counters, optimizer and RNG state until that total is reached; without ``--steps`` a run trains for
``PPOConfig.total_steps``, and under ``--test`` for one more update (``num_envs * horizon`` steps) than it has.

With ``--initial-states BUFFER`` every episode (first and automatic resets alike) starts from a successful
terminal state of the previous sub-task drawn from a :class:`~seqdex_drake.chaining.terminal_buffer.TerminalBuffer`
(forward initialization); the buffer's target task must be the trained task.

Every flag is checked before anything is created (a refused command leaves no run directory behind). One training
at a time holds a run directory (:mod:`seqdex_drake.cli.run_lock`: a second is refused, naming the first). SIGINT
(Ctrl-C) and SIGTERM stop a training cleanly: the update in progress finishes, ``last.pt`` is written, and the
command exits with 128 + the signal number; ``last.pt`` is also written every ``--checkpoint-seconds`` (default
``PPOConfig.checkpoint_seconds``). ``--resume`` on a run that stopped before its first checkpoint (``config.json``
but no ``last.pt``) starts it at step 0 with its saved config.
"""

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
from seqdex_drake.chaining.wrappers import InitialStateVectorEnv  # noqa: F401 (also imported from here by tests)
from seqdex_drake.cli import PREVIOUS_TASKS, CliError, check_creatable, check_seed
from seqdex_drake.cli.run_lock import RunLock
from seqdex_drake.env_state import SceneHandoffError
from seqdex_drake.envs.scene_handoff import check_carried
from seqdex_drake.envs.subtask_env import EnvState
from seqdex_drake.envs.vector import ProcessVectorEnv, WorkerError
from seqdex_drake.rl.checkpoint import CheckpointError
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.demonstrations import Demonstrations, behaviour_clone
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.stop_signals import StopSignals
from seqdex_drake.scenario import DumpScenario, ScenarioError
from seqdex_drake.tasks.run_config import config_dict, observation_spec, same_task_config, task_config

#: Network widths under ``--test`` (the paper's 1024-1024-512 MLPs are needlessly slow for a smoke run).
TEST_HIDDEN_SIZES = (64, 64)
#: Initial action std of a run that starts from behaviour cloning (``--demos``): the cloned grasp is delicate, and
#: the budget preset's 0.5 (a quarter of each hand joint's range) would rarely reproduce it.
DEMO_INIT_STD = 0.2
#: Envs under ``--test`` without ``--num-envs``.
TEST_NUM_ENVS = 2
#: Rollout length under ``--test``: one update of ``num_envs * TEST_HORIZON`` steps, whatever the preset.
TEST_HORIZON = 8


def load_initial_states(path: str, task: str):
    """The terminal buffer at ``path`` for starting ``task`` episodes; :class:`CliError` if it cannot be used."""
    sources = PREVIOUS_TASKS.get(task)
    if sources is None:
        raise CliError(f"{task} is the first sub-task of its chain; it starts from the scenario, not from a "
                       f"terminal buffer (drop --initial-states)")
    try:
        buffer = TerminalBuffer.load(path, expected_task=task,
                                     expected_source=sources[0] if len(sources) == 1 else None)
    except (FileNotFoundError, ValueError) as error:
        raise CliError(str(error)) from error
    source = buffer.source_task
    if source not in sources:
        raise CliError(f"terminal buffer {path} has source task {source!r}, but {task} follows "
                       f"{' or '.join(repr(s) for s in sources)} in its chains")
    if not buffer.successes.any():
        raise CliError(f"terminal buffer {path} has no successful {source} episodes to start {task} from; "
                       f"train {source} further and run seqdex collect --task {source} again")
    return buffer


def load_demonstrations(path: str, task: str):
    """The demonstrations at ``path`` for training ``task``; :class:`CliError` if they cannot be used."""
    try:
        return Demonstrations.load(path, expected_task=task)
    except ValueError as error:
        raise CliError(str(error)) from error


def _saved_preset(run_dir: Path, default: str) -> str:
    """The preset recorded in ``run_dir/config.json`` (``paper`` for runs recorded before presets; ``default``
    if there is no readable record: the resume checks then say what is wrong)."""
    try:
        return json.loads((run_dir / "config.json").read_text()).get("preset", "paper")
    except (OSError, ValueError, AttributeError):
        return default


def _saved_demos(run_dir: Path):
    """The demonstrations file recorded in ``run_dir/config.json`` (None: none, or no readable record)."""
    try:
        return json.loads((run_dir / "config.json").read_text()).get("demos")
    except (OSError, ValueError, AttributeError):
        return None


def _check_state_layout(env, buffer, scenario: str) -> None:
    """Raises :class:`CliError` if the buffer's states cannot start the env's episodes: saved on another scene
    (another plant size) without the fields a hand-off across scenes carries (``envs/scene_handoff.py``)."""
    ours = env.get_states()[0]
    theirs = buffer.state(int(np.flatnonzero(buffer.successes)[0]), EnvState)
    if np.shape(ours.plant_positions) == np.shape(theirs.plant_positions):
        return
    try:
        check_carried(theirs, np.size(ours.plant_positions), scenario)
    except SceneHandoffError as error:
        raise CliError(f"the buffer's {buffer.source_task} states: {error}") from error


def _new_run(args, run_dir: Path, config) -> tuple:
    """The PPO config and saved run record of a fresh run; refuses to overwrite an existing run."""
    if (run_dir / "last.pt").exists():
        raise CliError(f"{run_dir} already holds a run (last.pt); continue it with --resume or pick another "
                       f"--run-dir")
    overrides = {"seed": args.seed}
    if args.num_envs is not None or args.test:  # A smoke test runs 2 envs unless told otherwise.
        overrides["num_envs"] = args.num_envs or TEST_NUM_ENVS
    if args.demos is not None:  # DAPG: the demonstration term, less exploration around the cloned policy.
        overrides.update(demo_coef=args.demo_coef, init_log_std=math.log(DEMO_INIT_STD))
    if args.test:
        overrides.update(actor_hidden_sizes=TEST_HIDDEN_SIZES, critic_hidden_sizes=TEST_HIDDEN_SIZES,
                         horizon=TEST_HORIZON)
    if args.steps is not None:
        overrides["total_steps"] = args.steps
    if args.checkpoint_seconds is not None:
        overrides["checkpoint_seconds"] = args.checkpoint_seconds
    # A residual on a scripted base (budget preset, no demonstrations) takes small, KL-bounded steps around it.
    ppo_config = PPOConfig.for_preset(args.task, args.preset, residual=bool(config.residual) and args.demos is None,
                                      **overrides)
    record = {"task": args.task, "test": args.test, "initial_states": args.initial_states, "preset": args.preset,
              "demos": args.demos, "ppo": ppo_config.to_dict(), "task_config": config_dict(config)}
    return ppo_config, record


def _no_run(args, run_dir: Path) -> CliError:
    return CliError(f"--resume: no checkpoint {run_dir / 'last.pt'}; start the run without --resume: "
                    f"seqdex train --task {args.task} --run-dir {run_dir}")


#: The keys of a run record (config.json) that resuming reads.
RECORD_KEYS = ("task", "test", "initial_states", "ppo", "task_config")


def _saved_run(args, run_dir: Path, config) -> dict:
    """The run record of ``run_dir`` after checking it matches this command (a missing last.pt is allowed: the
    run stopped before its first checkpoint and starts again at step 0)."""
    checkpoint, record_path = run_dir / "last.pt", run_dir / "config.json"
    if not record_path.is_file():
        if not checkpoint.is_file():
            raise _no_run(args, run_dir)
        raise CliError(f"--resume: {record_path} is missing; {run_dir} was not made by seqdex train")
    try:
        record = json.loads(record_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise CliError(f"--resume: {record_path} is unreadable or truncated ({error}); restore it, or start afresh "
                       f"in another --run-dir") from error
    if not isinstance(record, dict) or any(key not in record for key in RECORD_KEYS):
        raise CliError(f"--resume: {record_path} is not a seqdex train run record (it needs the keys "
                       f"{', '.join(RECORD_KEYS)}); restore it, or start afresh in another --run-dir")
    if record["task"] != args.task:
        raise CliError(f"--resume: {run_dir} trains {record['task']}, not {args.task}")
    if not same_task_config(config_dict(config), record["task_config"]):
        raise CliError(f"--resume: the task config differs from the one {run_dir} was started with (was it "
                       f"started {'without' if args.test else 'with'} --test?)")
    if args.initial_states is not None and args.initial_states != record["initial_states"]:
        raise CliError(f"--resume: {run_dir} was started with --initial-states {record['initial_states']}")
    return record


def _resume_learner(args, run_dir: Path, record: dict) -> tuple:
    """(learner from last.pt or None, PPO config) of a resumed run; without last.pt the saved config's."""
    ppo = None
    if (run_dir / "last.pt").is_file():
        try:
            ppo = PPO.resume(run_dir / "last.pt")
        except CheckpointError as error:
            raise CliError(str(error)) from error
        ppo_config = ppo.config
    else:
        try:
            ppo_config = PPOConfig.from_dict(record["ppo"])
        except (ValueError, TypeError, AttributeError) as error:
            raise CliError(f"--resume: the PPO config in {run_dir / 'config.json'} is unusable ({error}); restore "
                           f"it, or start afresh in another --run-dir") from error
        print(f"seqdex train: --resume: {run_dir} has no checkpoint yet (it stopped before its first one); starting "
              f"it at step 0 with its saved config", file=sys.stderr)
    if args.seed != ppo_config.seed:
        print(f"seqdex train: resuming with the run's seed {ppo_config.seed} (--seed {args.seed} ignored)",
              file=sys.stderr)
    if args.checkpoint_seconds is not None:
        ppo_config = dataclasses.replace(ppo_config, checkpoint_seconds=args.checkpoint_seconds)
        if ppo is not None:
            ppo.config = ppo_config
    return ppo, ppo_config


def _write_record(run_dir: Path, record: dict, config) -> None:
    """Writes config.json and scenario.yaml (atomically: a crash leaves the old file or the new one)."""
    try:
        scenario = DumpScenario(config.load_scenario())
    except ScenarioError as error:
        raise CliError(str(error)) from error
    atomic_write(run_dir / "config.json", lambda file: file.write((json.dumps(record, indent=2) + "\n").encode()))
    atomic_write(run_dir / "scenario.yaml", lambda file: file.write(scenario.encode()))


def _check_args(args, run_dir: Path) -> None:
    """Refuses flags out of range and an unusable --run-dir before anything is created."""
    for flag, value in (("--steps", args.steps), ("--num-envs", args.num_envs),
                        ("--envs-per-worker", args.envs_per_worker)):
        if value is not None and value < 1:
            raise CliError(f"{flag} must be >= 1, got {value}")
    check_seed(args.seed)
    if args.checkpoint_seconds is not None and not args.checkpoint_seconds > 0:
        raise CliError(f"--checkpoint-seconds must be > 0 (inf: only every checkpoint_every updates), got "
                       f"{args.checkpoint_seconds}")
    check_creatable(run_dir, "--run-dir", directory=True)
    if args.resume and not run_dir.is_dir():
        raise _no_run(args, run_dir)


def _stopped(args, run_dir: Path, stop, ppo, trained: bool) -> int:
    """Reports a training stopped by SIGINT / SIGTERM; returns 128 + the signal's number."""
    if trained:
        what = (f"saved {run_dir / 'last.pt'} at step {ppo.global_step} ({ppo.num_updates} updates; "
                f"{ppo.stats.summary()})")
    elif ppo is not None and (run_dir / "last.pt").is_file():
        what = f"stopped before training; {run_dir / 'last.pt'} is unchanged at step {ppo.global_step}"
    else:
        what = "stopped before the first update; nothing to save"
    print(f"seqdex train: {stop.received}: {what}; continue with seqdex train --task {args.task} --run-dir "
          f"{run_dir} --resume", file=sys.stderr)
    return stop.exit_code


def run(args) -> int:
    """Runs ``seqdex train`` with the parsed ``args``; returns the exit code. The flags are checked before anything
    is created; the run directory is then locked for the run's life, and SIGINT / SIGTERM stop it cleanly."""
    run_dir = Path(args.run_dir or f"runs/{args.task}")
    _check_args(args, run_dir)
    with RunLock(run_dir, create=not args.resume), StopSignals() as stop:
        return _train(args, run_dir, stop)


def _train(args, run_dir: Path, stop) -> int:
    """``seqdex train`` in the locked ``run_dir``; ``stop`` records a SIGINT / SIGTERM received meanwhile."""
    if args.resume:  # The run's own preset (runs from before presets used the paper's).
        args.preset = _saved_preset(run_dir, args.preset)
    # A run with demonstrations trains whole actions (DAPG): no residual base, whatever the preset has.
    demos_run = args.demos is not None if not args.resume else _saved_demos(run_dir) is not None
    config = task_config(args.task, args.test, args.preset, residual=not demos_run)
    if args.resume:
        record = _saved_run(args, run_dir, config)
        ppo, ppo_config = _resume_learner(args, run_dir, record)  # ppo None: no checkpoint yet, step 0.
    else:
        ppo_config, record = _new_run(args, run_dir, config)
        ppo = None
    buffer = None if record["initial_states"] is None else load_initial_states(record["initial_states"], args.task)
    demos = None if record.get("demos") is None else load_demonstrations(record["demos"], args.task)
    if ppo is None:
        _write_record(run_dir, record, config)
    try:
        vec_env = ProcessVectorEnv(args.task, ppo_config.num_envs, seed=ppo_config.seed, config=config,
                                   envs_per_worker=args.envs_per_worker)  # None: one process per core.
    except WorkerError:
        if stop.received is None:
            raise
        return _stopped(args, run_dir, stop, ppo, trained=False)  # A terminal's Ctrl-C also ended the workers.
    try:
        if buffer is not None:
            _check_state_layout(vec_env, buffer, config.scenario)
            vec_env = InitialStateVectorEnv(vec_env, buffer, ppo_config.seed, EnvState)
        obs_dim = vec_env.single_observation_space.shape[0]
        if demos is not None and demos.observations.shape[1] != obs_dim:
            raise CliError(f"the demonstrations in {record['demos']} have observations of size "
                           f"{demos.observations.shape[1]}, the {args.task} env gives {obs_dim}")
        if ppo is None:
            ppo = PPO.for_env(ppo_config, vec_env)
            ppo.obs_spec = observation_spec(args.task, vec_env.single_observation_space.shape[0]).to_dict()
            if demos is not None:  # DAPG's warm start: behaviour cloning, the critic on the demos' returns.
                bc = behaviour_clone(ppo.model, demos, ppo.config.gamma, generator=ppo.generator)
                print(f"seqdex train: behaviour-cloned on {demos.num_episodes} demonstrations ({len(demos)} steps): "
                      f"action mse {bc['bc/actor_mse']:.4f}", file=sys.stderr)
        elif ppo.obs_dim != vec_env.single_observation_space.shape[0]:
            raise CliError(f"--resume: the checkpoint's policy reads {ppo.obs_dim} observations, the {args.task} "
                           f"env gives {vec_env.single_observation_space.shape[0]}")
        ppo.demos = demos
        if args.steps is not None:
            total = args.steps
        elif args.test:
            total = ppo.global_step + ppo.config.batch_size
        else:
            total = ppo.config.total_steps
        if ppo.global_step >= total:
            print(f"seqdex train: {run_dir} is already at {ppo.global_step} steps (>= {total}); pass a larger "
                  f"--steps to continue")
            return 0
        if stop.received is not None:
            return _stopped(args, run_dir, stop, ppo, trained=False)
        start = ppo.global_step
        batch = ppo.config.batch_size  # Whole updates: the run ends at the first multiple of the batch >= total.
        end = start + -(-(total - start) // batch) * batch
        print(f"seqdex train: training {args.task} in {run_dir}, steps {start} -> {end} (whole updates of {batch} "
              f"steps, --steps {total}); Ctrl-C or SIGTERM saves last.pt and stops", file=sys.stderr, flush=True)
        ppo.train(vec_env, run_dir, total_steps=total, progress=sys.stderr.isatty(), stop=stop)
    finally:
        vec_env.close()
    if stop.received is not None and ppo.global_step < total:
        return _stopped(args, run_dir, stop, ppo, trained=True)
    print(f"seqdex train: {args.task} steps {start} -> {ppo.global_step} ({ppo.num_updates} updates of "
          f"{ppo.config.batch_size} steps), "
          f"{ppo.stats.summary()}; checkpoint {run_dir / 'last.pt'}")
    return 0
