"""``seqdex collect``: roll out a trained sub-task policy and write the next sub-task's terminal buffer.

Each episode runs the policy's mean action (deterministic) in one in-process
:class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` until it ends (no autoreset, so the state at the episode's end
is still there to record). A successful episode (``success`` at its last step) adds its final
:class:`~seqdex_drake.envs.subtask_env.EnvState`, its last H observations (left-padded for short episodes) and
its return to a :class:`~seqdex_drake.chaining.terminal_buffer.TerminalBuffer` with source = this task and
target = the next task of its chain; ``--keep-failures`` also records the unsuccessful ones (``success`` False).

The buffer is always written, also when no episode succeeded (then it is empty and the command says so; the
exit code is still 0). Its path is checked before the rollouts (an ``--out`` that cannot be written is refused up
front). ``--resume`` appends to the existing ``--out`` buffer instead of replacing it.
"""

from pathlib import Path

import numpy as np
import torch

from seqdex_drake.chaining.feasibility import pad_history
from seqdex_drake.chaining.terminal_buffer import HISTORY, TerminalBuffer
from seqdex_drake.cli import NEXT_TASK, CliError, check_creatable, check_seed, with_base, with_objects
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.rl.checkpoint import CheckpointError
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.run_config import observation_spec, run_preset, run_residual, task_config

#: Episodes rolled out under ``--test`` when ``--episodes`` is not given.
TEST_EPISODES = 2


def _load_policy(path: Path):
    """The PPO learner of checkpoint ``path``; :class:`CliError` if it is missing or unreadable."""
    if not path.is_file():
        raise CliError(f"checkpoint {path} does not exist; train the policy first (seqdex train --task ...) or "
                       f"pass --checkpoint RUN_DIR/last.pt")
    try:
        return PPO.resume(path)
    except CheckpointError as error:
        raise CliError(str(error)) from error


def _open_buffer(args, out: Path, target: str, scenario: str, spec):
    """A new buffer, or with ``--resume`` the one at ``out`` (checked to hold this chain step's states)."""
    if not args.resume:
        return TerminalBuffer(args.task, target, scenario, spec, HISTORY)
    try:
        buffer = TerminalBuffer.load(out, expected_task=target, expected_obs_spec=spec, expected_source=args.task,
                                     expected_scenario=scenario)
    except (FileNotFoundError, ValueError) as error:
        raise CliError(f"--resume: {error}") from error
    if buffer.history != HISTORY:
        raise CliError(f"--resume: {out} stores {buffer.history} observations per entry, this command {HISTORY}")
    return buffer


def rollout(env, ppo, seed: int) -> tuple[np.ndarray, float, bool]:
    """One deterministic episode from ``env.reset(seed=seed)``: its observations (T+1, d), return, success.
    ``ppo`` None sends the zero action (a residual variant's script alone).

    The env is left in the episode's final state.
    """
    low, high = env.action_space.low, env.action_space.high
    observation, info = env.reset(seed=seed)
    observations, episode_return = [observation], 0.0
    while True:
        if ppo is None:
            action = np.zeros(env.action_space.shape, dtype=np.float32)
        else:
            obs = torch.as_tensor(observation, dtype=torch.float32, device=ppo.device)[None]
            action = np.clip(ppo.act(obs, deterministic=True)[0][0].cpu().numpy(), low, high)
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        episode_return += reward
        if terminated or truncated:
            return np.stack(observations), episode_return, bool(info.get("success", False))


def run(args) -> int:
    """Runs ``seqdex collect`` with the parsed ``args``; returns the exit code."""
    target = NEXT_TASK.get(args.task)
    if target is None:
        raise CliError(f"{args.task} is the last sub-task of its chain: no later task starts from its terminal "
                       f"states, so there is nothing to collect")
    run_dir = Path(args.run_dir or f"runs/{args.task}")
    checkpoint = Path(args.checkpoint) if args.checkpoint else run_dir / "last.pt"
    out = Path(args.out) if args.out else run_dir / f"terminal_{args.task}_to_{target}.npz"
    episodes = args.episodes if args.episodes is not None else (TEST_EPISODES if args.test else 100)
    if episodes < 1:
        raise CliError(f"--episodes must be >= 1, got {episodes}")
    check_seed(args.seed)
    check_creatable(out, "--out")  # Before the rollouts, not after them.
    if args.zero_action:
        if args.checkpoint:
            raise CliError("--zero-action rolls out no policy; drop --checkpoint")
        preset = args.preset or "budget"
        config = with_base(with_objects(task_config(args.task, args.test, preset), args.task, args.objects),
                           args.task, args.base)
        env = make_env(args.task, config)
        spec = observation_spec(args.task, env.observation_space.shape[0])
        return _collect(args, None, env, config, spec, out, target, episodes)
    if args.base:
        raise CliError(f"--base {args.base} runs a residual base alone: add --zero-action (a checkpoint brings the "
                       f"base it was trained on)")
    ppo = _load_policy(checkpoint)

    # The variant the policy was trained on.
    preset = args.preset or run_preset(checkpoint)
    config = with_objects(task_config(args.task, args.test, preset, residual=run_residual(checkpoint)), args.task,
                          args.objects)
    env = make_env(args.task, config)
    dim = env.observation_space.shape[0]
    if ppo.obs_dim != dim or ppo.action_dim != env.action_space.shape[0]:
        raise CliError(f"checkpoint {checkpoint} is a policy for {ppo.obs_dim} observations / {ppo.action_dim} "
                       f"actions, the {args.task} env ({preset} preset) has {dim} / "
                       f"{env.action_space.shape[0]}: another task's run, or another preset (--preset)?")
    spec = observation_spec(args.task, dim)
    if ppo.obs_spec is not None and ppo.obs_spec.get("digest") != spec.digest:
        raise CliError(f"checkpoint {checkpoint} is a policy for '{ppo.obs_spec.get('description')}', but "
                       f"the {args.task} env gives '{spec.description}': another task's run?")
    ppo.model.eval()
    return _collect(args, ppo, env, config, spec, out, target, episodes)


def _collect(args, ppo, env, config, spec, out: Path, target: str, episodes: int) -> int:
    """Rolls out ``episodes`` episodes of ``ppo`` (None: the zero action) and writes ``target``'s buffer."""
    buffer = _open_buffer(args, out, target, config.scenario, spec)
    before = len(buffer)
    successes = 0
    for episode in range(episodes):
        observations, episode_return, success = rollout(env, ppo, args.seed + episode)
        successes += success
        if success or args.keep_failures:
            buffer.append(env.get_state(), pad_history(observations, HISTORY), episode_return, success)
    buffer.save(out)
    print(f"seqdex collect: {successes} successes out of {episodes} {args.task} episodes; wrote "
          f"{len(buffer) - before} entries ({len(buffer)} in all) for {target} to {out}")
    if successes == 0:
        print(f"seqdex collect: no successful episode: the {args.task} -> {target} buffer holds no successful "
              f"states (train {args.task} further before starting {target} from it)")
    return 0
