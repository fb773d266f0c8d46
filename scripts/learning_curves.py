"""Learning curves of training runs as CSV + PNG: success rate and return against env steps and wall-clock.

    python scripts/learning_curves.py --run-dir runs/tool_grasp --out results/curves/tool_grasp
    python scripts/learning_curves.py --run-dir runs/chain/phases/finetune_1_grasp --out results/curves/chain_grasp
    python scripts/learning_curves.py --test            # a tiny run of the toy env, for CI

Reads the TensorBoard events that ``seqdex train`` writes (``seqdex_drake/evaluation/learning_curves.py``).
"""

import argparse
import sys
import tempfile
from pathlib import Path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", help="a seqdex train run directory")
    parser.add_argument("--out", help="output path without suffix (.csv and .png are written)")
    parser.add_argument("--title", default="", help="figure title (default: the run directory's name)")
    parser.add_argument("--test", action="store_true", help="train the toy env for 3 updates and plot it")
    args = parser.parse_args(argv)
    from seqdex_drake.evaluation.learning_curves import write_curve

    if args.test:
        from seqdex_drake.rl.config import PPOConfig
        from seqdex_drake.rl.ppo import PPO
        from seqdex_drake.rl.toy_env import TargetVectorEnv

        work = Path(tempfile.mkdtemp(prefix="curves_"))
        config = PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), num_envs=4, horizon=16)
        PPO(config, 3, 1, [-1.0], [1.0]).train(TargetVectorEnv(num_envs=4), work / "run", total_steps=192,
                                               progress=False)
        args.run_dir, args.out = str(work / "run"), str(work / "curve")
    if not args.run_dir or not args.out:
        parser.error("--run-dir and --out are required (or --test)")
    try:
        csv_path, png_path = write_curve(args.run_dir, args.out, args.title)
    except ValueError as error:
        print(f"learning_curves: error: {error}", file=sys.stderr)
        return 2
    print(f"learning_curves: wrote {csv_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
