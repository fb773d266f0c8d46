"""Learning per sample: the ``budget`` and ``paper`` PPO presets trained on the same env, seeds and step budget.

``benchmarks/train_throughput.py`` shows that the budget preset trains about twice as many env steps per second as
the paper's (``train_over_env`` 0.9-1.0 against 0.5). A preset that trains faster per second but learns slower per
sample gains nothing; this script measures the per-sample side. For each preset (the PPO settings of
``--presets-of``'s sub-task, as ``seqdex train --preset budget|paper`` makes them) and each seed:

1. train PPO on ``--task``'s env (one process vector env, one worker per core, as ``seqdex train`` runs it) for
   ``--steps`` env steps, whole updates (the last one may overshoot), recording the windowed training success and
   return after every update (``curve``: env steps, wall-clock, success, return);
2. evaluate the final policy deterministically on ``--episodes`` episodes from seeds ``10_000 + seed * 1000 + k``
   (the same episodes for both presets): ``success`` and ``mean_return``.

Both presets run on the same env (``task_config(task, test, "paper")``), so only the PPO settings differ: network
sizes, transitions per update, gradient steps per transition, initial std, learning-rate rule and reward scale.
The default task is Reach (the hand-over chain's first stage, wrist only, 30-step episodes): it learns within tens of
thousands of steps, where tool Grasp's success stays at 0 for both presets (results/tool_positioning.md), so the
comparison has a signal on our budget. Per preset: ``success_mean`` / ``success_std`` over seeds; at the top level
``budget_minus_paper_success`` (the per-sample difference), its standard error over seeds, and
``budget_over_paper_wall_clock`` (training seconds, same steps). The last line printed is one JSON object.

    python benchmarks/learning_per_sample.py [--task reach] [--presets-of tool_grasp] [--steps 40960]
        [--seeds 0 1 2] [--episodes 50] [--out results/learning_per_sample.json] [--test]
"""

import argparse
import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.cli import task_config
from seqdex_drake.cli.rollout import run_episode, summarize
from seqdex_drake.envs.vector import ProcessVectorEnv
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.policy_loading import load_policy
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.registry import make_env

PRESETS = {"budget": PPOConfig.for_budget, "paper": PPOConfig.for_task}


def ppo_config(preset: str, presets_of: str, seed: int, test: bool) -> PPOConfig:
    """The PPO settings ``seqdex train --task presets_of --preset preset`` starts from, with ``seed``."""
    config = PRESETS[preset](presets_of, seed=seed)
    if test:  # A few steps: 2 envs, 4-step rollouts.
        config = dataclasses.replace(config, num_envs=2, horizon=4, num_minibatches=2)
    return config


def train_and_evaluate(task: str, preset: str, presets_of: str, seed: int, steps: int, episodes: int,
                       test: bool) -> dict:
    """One preset and seed: the training curve, the wall-clock and the deterministic evaluation."""
    env_config = task_config(task, test, "paper")
    config = ppo_config(preset, presets_of, seed, test)
    vec_env = ProcessVectorEnv(task, config.num_envs, seed=seed, config=env_config, envs_per_worker=None)
    curve = []
    try:
        ppo = PPO.for_env(config, vec_env)
        start = time.perf_counter()
        while ppo.global_step < steps:
            ppo.collect(vec_env)
            ppo.update()
            window = ppo.stats.window_metrics()
            curve.append([ppo.global_step, time.perf_counter() - start,
                          window.get("charts/success_rate", math.nan), window.get("charts/episode_return", math.nan)])
        wall_clock = time.perf_counter() - start
    finally:
        vec_env.close()
    with tempfile.TemporaryDirectory() as folder:  # Through the public loader, as a user evaluates a checkpoint.
        path = ppo.save(Path(folder) / "last.pt")
        policy = load_policy(path, deterministic=True)
    env = make_env(task, config=env_config)
    try:
        records = [run_episode(env, policy, 10_000 + seed * 1000 + k) for k in range(episodes)]
    finally:
        env.close()
    evaluation = summarize(records)
    return {"seed": seed, "env_steps": ppo.global_step, "updates": ppo.num_updates, "wall_clock_s": wall_clock,
            "batch": config.batch_size, "gradient_steps": ppo.num_updates * config.num_epochs * config.num_minibatches,
            "model_parameters": int(sum(p.numel() for p in ppo.model.parameters())),
            "success": evaluation["success_rate"], "mean_return": evaluation["mean_return"], "curve": curve}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="reach", help="the env both presets train on")
    parser.add_argument("--presets-of", default="tool_grasp", help="the sub-task whose budget / paper PPO settings")
    parser.add_argument("--steps", type=int, default=40_960, help="env steps per run (whole updates)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=50, help="deterministic evaluation episodes per run")
    parser.add_argument("--presets", default="budget,paper")
    parser.add_argument("--out", help="also write the JSON object here")
    parser.add_argument("--test", action="store_true", help="a few steps only (CI): 2 envs, 4-step rollouts")
    args = parser.parse_args()
    presets = args.presets.split(",")
    unknown = sorted(set(presets) - set(PRESETS))
    if unknown:
        parser.error(f"--presets: unknown {', '.join(unknown)}; choose from {', '.join(PRESETS)}")
    if args.steps < 1 or args.episodes < 1:
        parser.error(f"--steps and --episodes must be >= 1, got {args.steps} and {args.episodes}")
    if args.test:
        args.steps, args.episodes, args.seeds = 8, 2, args.seeds[:1]
    torch.set_num_threads(max(1, torch.get_num_threads()))
    result = {"task": args.task, "presets_of": args.presets_of, "steps": args.steps, "episodes": args.episodes,
              "seeds": args.seeds}
    for preset in presets:
        runs = []
        for seed in args.seeds:
            run = train_and_evaluate(args.task, preset, args.presets_of, seed, args.steps, args.episodes, args.test)
            print(f"{preset} seed {seed}: " + json.dumps({k: v for k, v in run.items() if k != "curve"}), flush=True)
            runs.append(run)
        successes = [run["success"] for run in runs]
        result[preset] = {"success_mean": float(np.mean(successes)), "success_std": float(np.std(successes)),
                          "wall_clock_s_mean": float(np.mean([run["wall_clock_s"] for run in runs])), "runs": runs}
    if {"budget", "paper"} <= set(presets):
        differences = [b["success"] - p["success"] for b, p in zip(result["budget"]["runs"], result["paper"]["runs"],
                                                                     strict=True)]
        result["budget_minus_paper_success"] = float(np.mean(differences))
        result["budget_minus_paper_success_sem"] = float(np.std(differences, ddof=1) / math.sqrt(len(differences))) \
            if len(differences) > 1 else math.nan
        result["budget_over_paper_wall_clock"] = result["budget"]["wall_clock_s_mean"] / \
            result["paper"]["wall_clock_s_mean"]
    line = json.dumps(result)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(line + "\n")
    print(line)


if __name__ == "__main__":
    main()
