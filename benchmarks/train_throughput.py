"""Training throughput: PPO's env steps per second over the env's own rate, same task, same cores, one run.

For each PPO preset (``budget``, the ``seqdex train`` default; ``paper``, the paper's tables) on one sub-task:

1. ``env_steps_per_s``: the preset's process vector env (its ``num_envs``, one worker per core) stepped with
   random actions, grouped by worker as PPO's rollouts step it;
2. ``train_steps_per_s``: :meth:`PPO.collect` + :meth:`PPO.update` on the same vector env, end to end;
3. ``learner_fraction``: the share of the training time spent in :meth:`PPO.update` (the gradient steps).

``train_over_env`` = 2 / 1 (goal >= 0.8 for the default preset on tool grasp). Both are measured in this run,
alternating, so a noisy machine shifts both. The last line printed is one JSON object.

    python benchmarks/train_throughput.py [--task tool_grasp] [--updates 3] [--test]
"""

import argparse
import dataclasses
import json
import time

import numpy as np
import torch

from seqdex_drake.envs.vector import ProcessVectorEnv
from seqdex_drake.rl.config import RESIDUAL_HYPERPARAMETERS, PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.run_config import task_config


def _env_rate(vec_env, steps: int, seed: int) -> float:
    """Env steps per second of ``vec_env`` under random actions, ``steps`` vector steps."""
    rng = np.random.default_rng(seed)
    low, high = vec_env.single_action_space.low, vec_env.single_action_space.high
    vec_env.reset(seed=seed)
    start = time.perf_counter()
    for _ in range(steps):
        vec_env.step(rng.uniform(low, high, size=(len(vec_env), len(low))).astype(np.float32))
    return steps * len(vec_env) / (time.perf_counter() - start)


def measure(task: str, preset: str, updates: int, test: bool) -> dict:
    """The figures of one preset (see the module docstring)."""
    config = task_config(task, test, preset)
    make = PPOConfig.for_budget if preset == "budget" else PPOConfig.for_task
    # As seqdex train builds it: a budget run of a residual variant takes the residual hyperparameters.
    ppo_config = make(task, **(RESIDUAL_HYPERPARAMETERS if preset == "budget" and config.residual else {}))
    if test:  # A few steps: 2 envs, 4-step rollouts.
        ppo_config = dataclasses.replace(ppo_config, num_envs=2, horizon=4, num_minibatches=2)
    # One worker process per core, as seqdex train runs it.
    vec_env = ProcessVectorEnv(task, ppo_config.num_envs, seed=0, config=config, envs_per_worker=None)
    try:
        ppo = PPO.for_env(ppo_config, vec_env)
        ppo.collect(vec_env)  # Warm-up: worker start, first episodes, torch's first calls.
        ppo.update()
        env_rates, train_rates, learner = [], [], []
        for k in range(updates):
            env_rates.append(_env_rate(vec_env, ppo_config.horizon, seed=k))
            start = time.perf_counter()
            ppo.collect(vec_env)
            collected = time.perf_counter()
            ppo.update()
            end = time.perf_counter()
            train_rates.append(ppo_config.batch_size / (end - start))
            learner.append((end - collected) / (end - start))
    finally:
        vec_env.close()
    parameters = sum(p.numel() for p in ppo.model.parameters())
    env_rate, train_rate = float(np.median(env_rates)), float(np.median(train_rates))
    return {"num_envs": ppo_config.num_envs, "horizon": ppo_config.horizon, "batch": ppo_config.batch_size,
            "gradient_steps_per_update": ppo_config.num_epochs * ppo_config.num_minibatches,
            "model_parameters": int(parameters), "env_steps_per_s": env_rate, "train_steps_per_s": train_rate,
            "train_over_env": train_rate / env_rate, "learner_fraction": float(np.median(learner))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="tool_grasp")
    parser.add_argument("--updates", type=int, default=3, help="timed updates per preset (median reported)")
    parser.add_argument("--presets", default="budget,paper")
    parser.add_argument("--test", action="store_true", help="a few steps only (CI): 2 envs, 4-step rollouts")
    args = parser.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    result = {"task": args.task}
    for preset in args.presets.split(","):
        figures = measure(args.task, preset, 1 if args.test else args.updates, args.test)
        print(f"{preset}: {json.dumps(figures)}", flush=True)
        result[preset] = figures
    result["train_over_env"] = result[args.presets.split(",")[0]]["train_over_env"]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
