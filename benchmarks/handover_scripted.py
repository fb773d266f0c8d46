"""Scripted Lower policies on the hand-over chain: what a stage-2 policy could reach, for judging what PPO learned.

    python benchmarks/handover_scripted.py                                   # the height band of straight down
    python benchmarks/handover_scripted.py --buffer runs/chain_methods_s4/policy_seq_s0/buffers/reach_to_lower.npz
    python benchmarks/handover_scripted.py --buffer BUFFER --goal-height 0.10  # the pre-session-4 goal

Band: the hand centre placed over the block at heights from ``--low`` to ``--high`` (3 block placements each),
then Lower's episode with a straight-down action; prints the success fraction per height. Buffer: ``--episodes``
starts drawn from Reach's successful hand-overs in a terminal buffer (a pipeline run's ``buffers/``), each run
with three scripted policies: ``stay`` (zero action), ``down`` (straight down at full speed) and ``ideal`` (a
proportional step toward the goal point, clipped to one wrist step). ``--goal-height`` overrides Lower's goal
height above the block (its ``success_threshold[1]``). The last line is one JSON object.
"""

import argparse
import dataclasses
import json

import numpy as np

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.handover_common import hand_center, place_block_and_hand
from seqdex_drake.tasks.registry import default_config

STEP = 0.005  # Lower's wrist_step (m per step at action 1).


def _action(env, name: str, goal_height: float) -> np.ndarray:
    wrist = {"stay": np.zeros(3), "down": np.array([0.0, 0.0, -1.0])}.get(name)
    if wrist is None:  # ideal
        wrist = np.clip((env.object_position() + [0.0, 0.0, goal_height] - hand_center(env)) / STEP, -1.0, 1.0)
    return np.r_[np.zeros(16), wrist]


def _episode(env, name: str, goal_height: float) -> bool:
    info = {"success": False}
    for _ in range(env.config.episode_length):
        _, _, _, _, info = env.step(_action(env, name, goal_height))
    return bool(info["success"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buffer", help="a reach_to_lower terminal buffer; without it, the height band is measured")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--goal-height", type=float, default=None, help="Lower's goal height above the block (m)")
    parser.add_argument("--low", type=float, default=0.10)
    parser.add_argument("--high", type=float, default=0.14)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args(argv)
    config = default_config("lower")
    if args.goal_height is not None:
        config = dataclasses.replace(config, success_threshold=[config.success_threshold[0], args.goal_height])
    goal_height = config.success_threshold[1]
    env = make_env("lower", config)
    summary = {"goal_height": goal_height, "episode_length": config.episode_length}
    if args.buffer is None:
        band = {}
        for height in np.arange(args.low, args.high + 1e-9, 0.005):
            successes = []
            for placement in range(3):
                env.reset(seed=placement)
                place_block_and_hand(env, np.random.default_rng(placement), np.array([0.0, 0.0, height]),
                                     np.array([0.0, 0.0, height]))
                env.simulator.Initialize()
                successes.append(_episode(env, "down", goal_height))
            band[f"{height:.3f}"] = float(np.mean(successes))
            print(f"start {100 * height:.1f} cm above the block: straight-down success {band[f'{height:.3f}']:.2f}",
                  flush=True)
        summary["band"] = band
    else:
        from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
        from seqdex_drake.envs.subtask_env import EnvState

        buffer = TerminalBuffer.load(args.buffer, expected_task="lower")
        rng = np.random.default_rng(args.seed)
        starts = [buffer.sample(rng, EnvState, successful_only=True).state for _ in range(args.episodes)]
        for name in ("stay", "down", "ideal"):
            successes = []
            for state in starts:
                env.reset(options={"initial_state": state})
                successes.append(_episode(env, name, goal_height))
            summary[name] = float(np.mean(successes))
            print(f"{name:5s} success {summary[name]:.2f} over {len(starts)} hand-overs", flush=True)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
