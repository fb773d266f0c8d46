"""Seven chaining methods on the cheap hand-over chain (reach -> lower), several seeds: the evidence table.

    python benchmarks/chain_methods.py                       # 3 seeds; results/chain_methods.md records the runs
    python benchmarks/chain_methods.py --jobs 2              # two seeds at a time (one process each)
    python benchmarks/chain_methods.py --test                # a tiny budget, one seed (smoke test)

Per seed, Policy-Seq runs the whole pipeline first; ours (``seqdex``), ours w/o temporal, T-STAR and V-Chain
then take its forward phase (Algorithm 1's forward initialization is the same for all five: trained reach,
reach -> lower terminal buffer, lower trained from it; ours w/o temporal and T-STAR also take ours' rollouts
into lower, which come from those same policies) and run their own backward fine-tuning on the same budget;
RL-scratch and Curriculum RL train one policy over the whole chain with the same total PPO budget. Every run is
a ``seqdex pipeline`` run directory under ``--run-root`` (resumable: finished runs are read back, an
interrupted one continues). Wall-clock per method includes the shared forward phase. Evaluation: chain success
over ``--eval-episodes`` episodes with fixed per-stage time budgets (no switching), and for ours / ours w/o
temporal also with the feasibility switcher (at most 3 switches).

The last line printed is one JSON object with the per-method means.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Lower can reach its goal (4 cm above the block) in its 15 steps from at most this height (m), measured with a
#: scripted straight-down policy (success from 12.5 cm, not from 13 cm).
LOWER_REACH = 0.1275
HEIGHT_SEED = 50_000
SHARED_FORWARD = ("seqdex", "seqdex_no_temporal", "tstar", "vchain")
ORDER = ("seqdex", "seqdex_no_temporal", "tstar", "policy_seq", "vchain", "curriculum", "scratch")
LABELS = {"seqdex": "Ours", "seqdex_no_temporal": "Ours w/o temporal", "tstar": "T-STAR", "policy_seq": "Policy-Seq",
          "vchain": "V-Chain", "curriculum": "Curriculum RL", "scratch": "RL-scratch"}


def _config(args, method: str, seed: int):
    from seqdex_drake.chaining.pipeline import PipelineConfig

    if args.test:
        return PipelineConfig.tiny(chain="handover", method=method, seed=seed)
    return PipelineConfig(chain="handover", method=method, seed=seed, stage_steps=args.stage_steps,
                          finetune_steps=args.finetune_steps, transition_episodes=args.transition_episodes,
                          eval_episodes=args.eval_episodes, backend="serial", lambda2=args.lambda2,
                          iterations=args.iterations)


def run_seed(args, seed: int) -> None:
    """Runs (or reads back) every method for one seed."""
    from seqdex_drake.chaining.bidirectional import Pipeline
    from seqdex_drake.chaining.chain import LoadChain
    from seqdex_drake.chaining.stage_envs import default_env_kit

    chain = LoadChain("handover")
    env_kit = default_env_kit()

    def log(message: str) -> None:
        print(f"[seed {seed}] {message}", flush=True)

    directory = Path(args.run_root)
    pipelines = {}
    for method in ("policy_seq", *SHARED_FORWARD, "scratch", "curriculum"):
        if method != "policy_seq" and method not in args.methods:  # Policy-Seq is the others' forward phase.
            continue
        run_dir = directory / f"{method}_s{seed}"
        if (run_dir / "results.json").is_file():
            log(f"{method}: done earlier")
            pipelines[method] = (Pipeline.open(run_dir, log=log, env_kit=env_kit) if method in ("policy_seq", "seqdex")
                                 else None)
            continue
        resume = (run_dir / "pipeline.json").is_file()
        pipeline = Pipeline(chain, _config(args, method, seed), run_dir, resume=resume, log=log, env_kit=env_kit)
        if method in SHARED_FORWARD and not resume:  # F's and D's data: the same forward policies' rollouts.
            source = pipelines["seqdex"] if method in ("seqdex_no_temporal", "tstar") else pipelines["policy_seq"]
            pipeline.adopt_forward(source)
        results = pipeline.execute()
        pipelines[method] = pipeline
        log(f"{method}: success {results['success_rate']:.3f} (switcher {results['success_rate_switcher']}), "
            f"{results['wall_clock_s']:.0f} s")


def handover_heights(run_dir: Path, episodes: int = 20) -> dict | None:
    """Where the run's final Reach policy hands over: its deterministic episodes' mean hand-centre height above
    the block (cm) and the fraction that ends with x-y success *and* at most ``LOWER_REACH`` high, where Lower's
    15 steps can reach its goal (``tasks/handover_common``). Cached in the run directory; None for single-policy
    methods."""
    cache, policy = run_dir / "handover_heights.json", run_dir / "stages" / "reach" / "last.pt"
    if cache.is_file():
        return json.loads(cache.read_text())
    if not policy.is_file():
        return None
    from seqdex_drake.chaining.rollouts import deterministic_policy, run_stage
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.rl.ppo import PPO
    from seqdex_drake.tasks.handover_common import hand_center

    env, act = make_env("reach"), deterministic_policy(PPO.resume(policy))
    heights, usable = [], []
    for episode in range(episodes):
        result = run_stage(env, act, seed=HEIGHT_SEED + episode)
        heights.append(float(hand_center(env)[2] - env.object_position()[2]))
        usable.append(result.success and heights[-1] <= LOWER_REACH)
    value = {"height_cm": 100 * float(np.mean(heights)), "usable": float(np.mean(usable)), "episodes": episodes}
    cache.write_text(json.dumps(value))
    return value


def _table(args) -> tuple[str, dict]:
    rows, summary = [], {}
    seeds = range(args.seed, args.seed + args.seeds)
    for method in ORDER:
        results = [json.loads((Path(args.run_root) / f"{method}_s{s}" / "results.json").read_text()) for s in seeds
                   if (Path(args.run_root) / f"{method}_s{s}" / "results.json").is_file()]
        if not results:
            continue
        success = np.array([r["success_rate"] for r in results])
        switcher = [r["success_rate_switcher"] for r in results if r["success_rate_switcher"] is not None]
        seconds = np.array([r["wall_clock_s"] for r in results])
        steps = results[0]["ppo_steps"]
        heights = [h for h in (handover_heights(Path(args.run_root) / f"{method}_s{s}") for s in seeds
                               if (Path(args.run_root) / f"{method}_s{s}" / "results.json").is_file()) if h]
        summary[method] = {"success_mean": float(success.mean()), "success_std": float(success.std()),
                           "switcher_mean": float(np.mean(switcher)) if switcher else None,
                           "handover_height_cm": float(np.mean([h["height_cm"] for h in heights])) if heights else None,
                           "handover_usable": float(np.mean([h["usable"] for h in heights])) if heights else None,
                           "ppo_steps": steps, "wall_clock_s_mean": float(seconds.mean()), "seeds": len(results)}
        switch_text = f"{np.mean(switcher):.2f} ± {np.std(switcher):.2f}" if switcher else "–"
        height_text = (f"{np.mean([h['height_cm'] for h in heights]):.1f} | "
                       f"{np.mean([h['usable'] for h in heights]):.2f}") if heights else "– | –"
        rows.append(f"| {LABELS[method]} | {success.mean():.2f} ± {success.std():.2f} | {switch_text} | "
                    f"{height_text} | {steps} | {seconds.mean():.0f} | {len(results)} |")
    header = ("| Method | Chain success (sequential) | With the switcher (≤ 3 switches) | Reach hand-over height "
              "(cm) | Usable hand-overs | PPO steps | Wall-clock (s, mean) | Seeds |\n" + "|---" * 8 + "|")
    return header + "\n" + "\n".join(rows), summary


def _child_arguments(argv: list[str]) -> list[str]:
    """``argv`` without ``--jobs N`` / ``--jobs=N`` and ``--report-only``: what a per-seed process (and a rerun of
    the whole table) takes."""
    flags, skip = [], False
    for argument in argv:
        if skip or argument.startswith("--jobs") or argument == "--report-only":
            skip = argument == "--jobs" and not skip
            continue
        flags.append(argument)
    return flags


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--stage-steps", type=int, default=12_000)
    parser.add_argument("--finetune-steps", type=int, default=6_000)
    parser.add_argument("--transition-episodes", type=int, default=120)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--lambda2", type=float, default=1.0)
    parser.add_argument("--iterations", type=int, default=1, help="M, Algorithm 1's forward/backward passes")
    parser.add_argument("--jobs", type=int, default=1, help="seeds run at the same time (one process each)")
    parser.add_argument("--run-root", default=str(ROOT / "runs" / "chain_methods"))
    parser.add_argument("--out", default=str(ROOT / "runs" / "chain_methods.md"))
    parser.add_argument("--methods", type=lambda text: text.split(","), default=list(ORDER),
                        help="comma-separated methods to run (default: all seven; policy_seq always runs, it is the "
                             "shared forward phase), e.g. a lambda2 sweep of seqdex,seqdex_no_temporal,tstar,vchain")
    parser.add_argument("--report-only", action="store_true",
                        help="only tabulate the finished runs under --run-root (no training)")
    parser.add_argument("--only-seed", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--test", action="store_true", help="tiny budget, one seed, output under the run root")
    args = parser.parse_args()
    unknown = sorted(set(args.methods) - set(ORDER))
    if unknown:
        parser.error(f"unknown methods {unknown}; known: {', '.join(ORDER)}")
    if args.test:
        args.seeds, args.jobs = 1, 1
        args.out = str(Path(args.run_root) / "chain_methods_test.md")
    if args.only_seed is not None:
        run_seed(args, args.only_seed)
        return
    seeds = list(range(args.seed, args.seed + args.seeds))
    if args.report_only:
        pass
    elif args.jobs <= 1:
        for seed in seeds:
            run_seed(args, seed)
    else:
        flags = _child_arguments(sys.argv[1:])
        pending = list(seeds)
        running = []
        while pending or running:
            while pending and len(running) < args.jobs:
                running.append(subprocess.Popen([sys.executable, __file__, *flags, "--only-seed", str(pending.pop(0))]))
            time.sleep(5)
            for process in [p for p in running if p.poll() is not None]:
                running.remove(process)
                if process.returncode:
                    raise SystemExit(f"a seed's process failed with exit code {process.returncode}")
    table, summary = _table(args)
    budget = "tiny (--test)" if args.test else (f"stage_steps {args.stage_steps}, finetune_steps "
                                                 f"{args.finetune_steps}, transition_episodes "
                                                 f"{args.transition_episodes}, eval_episodes {args.eval_episodes}, "
                                                 f"iterations {args.iterations}")
    command = " ".join(["python benchmarks/chain_methods.py", *_child_arguments(sys.argv[1:])])
    text = (f"# Chaining methods on the hand-over chain (reach -> lower)\n\nMade by `{command}` ({len(seeds)} seeds "
            f"asked; {budget}, lambda2 {args.lambda2}; the Seeds column says how many finished). Reach hand-over "
            f"height: the final Reach policy's mean hand-centre height above the block at the hand-over over "
            f"{20} deterministic episodes per seed; usable hand-overs: the fraction with x-y success at most "
            f"{100 * LOWER_REACH:.1f} cm high, from where Lower's 15 steps reach its goal (single-policy methods: "
            f"–).\n\n{table}\n")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    print(text)
    print(json.dumps({"methods": summary, "seeds": len(seeds), "out": args.out}))


if __name__ == "__main__":
    main()
