"""Training subprocess of ``tests/test_crash_resume.py``: PPO on the toy env, one JSON line per update.

    python tests/crash_resume_runner.py RUN_DIR LOG --updates N [--resume [--fresh-env]] [--pause SECONDS]

Writes ``{"update", "global_step", "num_episodes", "metrics"}`` to LOG (appended, flushed) after every update,
then sleeps ``--pause`` s (a window for the test to kill it). ``--resume`` continues from ``RUN_DIR/last.pt``.
"""

import argparse
import json
from pathlib import Path

import torch

from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv

NUM_ENVS, HORIZON = 4, 8


def config() -> PPOConfig:
    return PPOConfig(actor_hidden_sizes=(32, 32), critic_hidden_sizes=(32, 32), num_envs=NUM_ENVS, horizon=HORIZON,
                     num_minibatches=2, num_epochs=3, learning_rate=1e-3, seed=11, stats_window=8,
                     checkpoint_every=2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("log", type=Path)
    parser.add_argument("--updates", type=int, required=True)
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--pause", type=float, default=0.0)
    parser.add_argument("--fresh-env", action="store_true", help="resume without the checkpoint's env state")
    args = parser.parse_args()
    torch.set_num_threads(1)  # Same kernels in every run: results are bit-identical.
    env = TargetVectorEnv(num_envs=NUM_ENVS, episode_length=5, seed=2)  # 5 does not divide the horizon.
    ppo = PPO.resume(args.run_dir / "last.pt") if args.resume else PPO.for_env(config(), env)
    if args.fresh_env:
        ppo._saved_env_state = None  # The control: start fresh episodes instead of the saved ones.

    def log(learner: PPO, metrics: dict) -> None:
        record = {"update": learner.num_updates, "global_step": learner.global_step,
                  "num_episodes": learner.stats.num_episodes,
                  "metrics": {key: value for key, value in metrics.items() if key != "charts/SPS"}}
        with args.log.open("a") as file:
            file.write(json.dumps(record) + "\n")
        if args.pause:
            import time

            time.sleep(args.pause)

    ppo.train(env, args.run_dir, total_steps=args.updates * NUM_ENVS * HORIZON, callbacks=[log], progress=False)


if __name__ == "__main__":
    main()
