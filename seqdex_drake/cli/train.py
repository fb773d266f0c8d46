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
"""

import json
import sys
from pathlib import Path

import numpy as np

from seqdex_drake.chaining.wrappers import InitialStateVectorEnv  # noqa: F401 (also imported from here by tests)
from seqdex_drake.cli import PREVIOUS_TASK, CliError, config_dict, observation_spec, task_config

#: Network widths under ``--test`` (the paper's 1024-1024-512 MLPs are needlessly slow for a smoke run).
TEST_HIDDEN_SIZES = (64, 64)


def load_initial_states(path: str, task: str):
    """The terminal buffer at ``path`` for starting ``task`` episodes; :class:`CliError` if it cannot be used."""
    from seqdex_drake.chaining.terminal_buffer import TerminalBuffer

    source = PREVIOUS_TASK.get(task)
    if source is None:
        raise CliError(f"{task} is the first sub-task of its chain; it starts from the scenario, not from a "
                       f"terminal buffer (drop --initial-states)")
    try:
        buffer = TerminalBuffer.load(path, expected_task=task, expected_source=source)
    except (FileNotFoundError, ValueError) as error:
        raise CliError(str(error)) from error
    if not buffer.successes.any():
        raise CliError(f"terminal buffer {path} has no successful {source} episodes to start {task} from; "
                       f"train {source} further and run seqdex collect --task {source} again")
    return buffer


def _check_state_layout(env, buffer) -> None:
    """Raises :class:`CliError` if the buffer's states do not fit the env's plant (another scenario)."""
    from seqdex_drake.envs.subtask_env import EnvState

    ours = env.get_states()[0]
    theirs = buffer.state(int(np.flatnonzero(buffer.successes)[0]), EnvState)
    for field in ("plant_positions", "plant_velocities"):
        if np.shape(getattr(ours, field)) != np.shape(getattr(theirs, field)):
            raise CliError(f"the buffer's states have {field} of shape {np.shape(getattr(theirs, field))}, the "
                           f"{buffer.target_task} env has {np.shape(getattr(ours, field))}: another station")


def _new_run(args, run_dir: Path, config) -> tuple:
    """The PPO config and saved run record of a fresh run; refuses to overwrite an existing run."""
    from seqdex_drake.rl.config import PPOConfig

    if (run_dir / "last.pt").exists():
        raise CliError(f"{run_dir} already holds a run (last.pt); continue it with --resume or pick another "
                       f"--run-dir")
    overrides = {"seed": args.seed, "num_envs": args.num_envs}
    if args.test:
        overrides.update(actor_hidden_sizes=TEST_HIDDEN_SIZES, critic_hidden_sizes=TEST_HIDDEN_SIZES)
    if args.steps:
        overrides["total_steps"] = args.steps
    ppo_config = PPOConfig.for_task(args.task, **overrides)
    record = {"task": args.task, "test": args.test, "initial_states": args.initial_states,
              "ppo": ppo_config.to_dict(), "task_config": config_dict(config)}
    return ppo_config, record


def _saved_run(args, run_dir: Path, config) -> dict:
    """The run record of ``run_dir`` after checking it matches this command."""
    checkpoint, record_path = run_dir / "last.pt", run_dir / "config.json"
    if not checkpoint.is_file():
        raise CliError(f"--resume: no checkpoint {checkpoint}; start the run without --resume: "
                       f"seqdex train --task {args.task} --run-dir {run_dir}")
    if not record_path.is_file():
        raise CliError(f"--resume: {record_path} is missing; {run_dir} was not made by seqdex train")
    record = json.loads(record_path.read_text())
    if record["task"] != args.task:
        raise CliError(f"--resume: {run_dir} trains {record['task']}, not {args.task}")
    if record["task_config"] != config_dict(config):
        raise CliError(f"--resume: the task config differs from the one {run_dir} was started with (was it "
                       f"started {'without' if args.test else 'with'} --test?)")
    if args.initial_states is not None and args.initial_states != record["initial_states"]:
        raise CliError(f"--resume: {run_dir} was started with --initial-states {record['initial_states']}")
    return record


def run(args) -> int:
    """Runs ``seqdex train`` with the parsed ``args``; returns the exit code."""
    from seqdex_drake.envs.subtask_env import EnvState
    from seqdex_drake.envs.vector import ProcessVectorEnv
    from seqdex_drake.rl.checkpoint import CheckpointError
    from seqdex_drake.rl.ppo import PPO
    from seqdex_drake.scenario import DumpScenario, LoadScenario

    run_dir = Path(args.run_dir or f"runs/{args.task}")
    config = task_config(args.task, args.test)
    if args.resume:
        record = _saved_run(args, run_dir, config)
        try:
            ppo = PPO.resume(run_dir / "last.pt")
        except CheckpointError as error:
            raise CliError(str(error)) from error
        if args.seed != ppo.config.seed:
            print(f"seqdex train: resuming with the run's seed {ppo.config.seed} (--seed {args.seed} ignored)",
                  file=sys.stderr)
        ppo_config = ppo.config
    else:
        ppo_config, record = _new_run(args, run_dir, config)
        ppo = None
    buffer = None if record["initial_states"] is None else load_initial_states(record["initial_states"], args.task)
    if ppo is None:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.json").write_text(json.dumps(record, indent=2) + "\n")
        (run_dir / "scenario.yaml").write_text(DumpScenario(LoadScenario(config.scenario)))
    if args.envs_per_worker is not None and args.envs_per_worker < 1:
        raise CliError(f"--envs-per-worker must be >= 1, got {args.envs_per_worker}")
    vec_env = ProcessVectorEnv(args.task, ppo_config.num_envs, seed=ppo_config.seed, config=config,
                               envs_per_worker=args.envs_per_worker)  # None: one process per core.
    try:
        if buffer is not None:
            _check_state_layout(vec_env, buffer)
            vec_env = InitialStateVectorEnv(vec_env, buffer, ppo_config.seed, EnvState)
        if ppo is None:
            ppo = PPO.for_env(ppo_config, vec_env)
            ppo.obs_spec = observation_spec(args.task, vec_env.single_observation_space.shape[0]).to_dict()
        elif ppo.obs_dim != vec_env.single_observation_space.shape[0]:
            raise CliError(f"--resume: the checkpoint's policy reads {ppo.obs_dim} observations, the {args.task} "
                           f"env gives {vec_env.single_observation_space.shape[0]}")
        if args.steps:
            total = args.steps
        elif args.test:
            total = ppo.global_step + ppo.config.batch_size
        else:
            total = ppo.config.total_steps
        if ppo.global_step >= total:
            print(f"seqdex train: {run_dir} is already at {ppo.global_step} steps (>= {total}); pass a larger "
                  f"--steps to continue")
            return 0
        start = ppo.global_step
        metrics = ppo.train(vec_env, run_dir, total_steps=total, progress=sys.stderr.isatty())
    finally:
        vec_env.close()
    success = metrics.get("charts/success_rate", float("nan"))
    print(f"seqdex train: {args.task} steps {start} -> {ppo.global_step} ({ppo.num_updates} updates), "
          f"success rate {success:.3f}; checkpoint {run_dir / 'last.pt'}")
    return 0
