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
``budget_over_paper_wall_clock`` (training seconds, same steps). The last line printed is one JSON object. With
``--out F.json`` the object is also written there, with the curves as ``F.csv`` (one row per preset, seed and update)
and ``F.png`` (training success against env steps and wall-clock, one line per run); ``--plot-only`` redraws
those two from an existing ``F.json`` without training.

    python benchmarks/learning_per_sample.py [--task reach] [--presets-of tool_grasp] [--steps 40960]
        [--seeds 0 1 2] [--episodes 50] [--out results/learning_per_sample.json] [--test]
    python benchmarks/learning_per_sample.py --plot-only --out results/learning_per_sample.json
"""

import argparse
import csv
import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.envs.vector import ProcessVectorEnv
from seqdex_drake.evaluation.subtask_episodes import run_episode, summarize
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.policy_loading import load_policy
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.run_config import task_config

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


def write_curves(result: dict, out: Path) -> tuple[Path, Path]:
    """``out.csv`` and ``out.png`` from a result object (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    presets = [key for key in PRESETS if key in result]
    csv_path, png_path = out.with_suffix(".csv"), out.with_suffix(".png")
    with csv_path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["preset", "seed", "env_steps", "wall_clock_s", "success_rate", "episode_return"])
        for preset in presets:
            for run in result[preset]["runs"]:
                for row in run["curve"]:
                    writer.writerow([preset, run["seed"], int(row[0]), *(f"{value:.6g}" for value in row[1:])])
    figure, axes = pyplot.subplots(1, 2, figsize=(10, 4), sharey=True)
    colors = {"budget": "tab:green", "paper": "tab:purple"}
    for preset in presets:
        for k, run in enumerate(result[preset]["runs"]):
            curve = np.asarray(run["curve"], dtype=float).reshape(-1, 4)
            label = f"{preset} (eval {result[preset]['success_mean']:.2f})" if k == 0 else None
            axes[0].plot(curve[:, 0], curve[:, 2], color=colors[preset], alpha=0.8, label=label)
            axes[1].plot(curve[:, 1], curve[:, 2], color=colors[preset], alpha=0.8)
    axes[0].set_xlabel("env steps")
    axes[1].set_xlabel("wall-clock (s), 2 cores")
    axes[0].set_ylabel("training success (last 100 episodes)")
    axes[0].legend()
    for axis in axes:
        axis.grid(alpha=0.3)
    figure.suptitle(f"{result['task']}: {result['presets_of']}'s budget and paper PPO presets, "
                    f"seeds {', '.join(map(str, result['seeds']))}")
    figure.tight_layout()
    figure.savefig(png_path, dpi=100)
    pyplot.close(figure)
    return csv_path, png_path


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
    parser.add_argument("--plot-only", action="store_true", help="redraw the curves of --out's JSON; no training")
    args = parser.parse_args()
    if args.plot_only:
        if not args.out:
            parser.error("--plot-only needs --out, the JSON file of an earlier run")
        try:
            result = json.loads(Path(args.out).read_text())
        except (OSError, ValueError) as error:
            parser.error(f"--out {args.out}: not a result of this script ({error})")
        for path in write_curves(result, Path(args.out)):
            print(f"wrote {path}")
        return
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
        write_curves(result, Path(args.out))
    print(line)


if __name__ == "__main__":
    main()
