"""Grasp inside the pile, as if Orient had succeeded: the chain's Grasp measured on its own, in the whole-chain scene.

Each episode restores a cached pile, picks the target block as the chain does (``ChainRunner.start_block``: the
easiest block of a trained type 1-5, by turns), stands it upright where it lies (its long axis' yaw kept, its
bottom on the lowest point of its resting bounding box) and runs the shipped chain from Grasp: Search and Orient
get one control step each, no feasibility switch, then the approach, Grasp's 150 steps and Insert's entry. The
block counts as lifted if it is 0.30 m (Grasp's success lift) above its upright start when Insert starts.

    python experiments/grasp_in_pile.py --episodes 30 --out results/building_blocks/grasp_in_pile.json
    python experiments/grasp_in_pile.py --test          # one short episode, for CI

Writes JSON: per episode the pile, block, position, whether it stood (upright when Grasp started: tilt < 20 deg),
its rise at Insert's entry and whether it was lifted; and the counts. About 40 s per episode on a core.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TYPES = (1, 2, 3, 4, 5)
#: Grasp's success lift [m] (``tasks/grasp.py``: the paper's 0.30 m).
LIFT = 0.30
#: Upright: the block's z axis within this of world z [deg] (``tasks/blocks_common.accessibility_order``).
UPRIGHT_DEG = 20.0


def stand_upright(runner, name: str, block_type: int) -> np.ndarray:
    """Moves block ``name`` upright where it lies and returns its new position."""
    from seqdex_drake.modeling.blocks import BLOCK_SPECS
    from seqdex_drake.tasks.blocks_common import TOTAL_HEIGHT, resting_pose

    X = runner.object_pose()
    R = X.rotation().matrix()
    axis = R[:, 0] if np.linalg.norm(R[:2, 0]) > 0.5 else R[:, 1]  # The long axis, else (on an end) the width's.
    length, width = BLOCK_SPECS[block_type].footprint
    corners = np.array([[x, y, z] for x in (-length / 2, length / 2) for y in (-width / 2, width / 2)
                        for z in (0.0, TOTAL_HEIGHT)])
    floor = float(np.min(R @ corners.T, axis=1)[2] + X.translation()[2])
    X_up = resting_pose(block_type, 0.0, 0.0, float(np.arctan2(axis[1], axis[0])), X.translation()[:2], floor=floor)
    runner.objects.set_pose(runner.context, name, X_up, frozen=False)
    return X_up.translation()


def run_episode(runner, seed: int, episode: int, time_limit: float) -> dict:
    """One episode (seeded by ``seed, episode``): the block stood up in its pile, the chain from Grasp."""
    from seqdex_drake.evaluation.episodes import sample_goal

    runner.context.SetTime(0.0)
    rng = np.random.default_rng([seed, episode])
    block_type = TYPES[episode % len(TYPES)]
    pile = runner.restore_pile(int(rng.integers(1 << 30)))
    yaws = runner.stage_configs[runner.tasks.index("insert")].goal_yaws_deg
    name = runner.start_block(block_type, sample_goal(block_type, rng, yaws), reset_robot=True)
    p_start = stand_upright(runner, name, block_type)
    runner.restart()
    entries: dict[str, list[float]] = {}

    def record(r) -> bool:
        stage = r.tasks[int(r.chain_output("active_stage")[0])]
        if stage not in entries:
            X = r.object_pose()
            entries[stage] = [float(X.rotation().matrix()[2, 2]), float(X.translation()[2] - p_start[2])]
        return stage != "insert"

    runner.run(time_limit, on_tick=record)
    stood = entries.get("grasp", [0.0])[0] >= np.cos(np.radians(UPRIGHT_DEG))
    rise = entries.get("insert", [0.0, 0.0])[1]
    return {"episode": episode, "pile": pile, "block_type": block_type, "block": name,
            "position": np.round(p_start, 4).tolist(), "stood": bool(stood), "rise": round(rise, 4),
            "lifted": bool(stood and rise >= LIFT)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", default=str(ROOT / "checkpoints" / "building_blocks"),
                        help="shipped checkpoint folder or chain run directory (default: the shipped one)")
    parser.add_argument("--episodes", type=int, default=30, help="episodes (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pile and goal draws (default 0)")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--test", action="store_true", help="one episode of Grasp cut to 20 steps, for CI")
    args = parser.parse_args(argv)
    from seqdex_drake.atomic import atomic_write
    from seqdex_drake.evaluation.runner import ChainRunError, ChainRunner, RunConfig
    from seqdex_drake.user_input import InputError, check_creatable, check_seed

    try:
        check_seed(args.seed)
        if args.episodes < 1:
            raise InputError(f"--episodes must be >= 1, got {args.episodes}")
        if not Path(args.checkpoints).is_dir():
            raise InputError(f"--checkpoints {args.checkpoints} is not a directory")
        if args.out:
            check_creatable(args.out, "--out")
        grasp_steps = 20 if args.test else None
        runner = ChainRunner(RunConfig(family="building_blocks", run_dir=args.checkpoints, max_switches=0,
                                       seed=args.seed, stage_steps=(1, 1, grasp_steps or 150, 125),
                                       chain="building_blocks_policies"))
        if runner.untrained:
            raise InputError(f"untrained stages in {args.checkpoints}: {', '.join(runner.untrained)}")
    except (InputError, ChainRunError) as error:
        print(f"grasp_in_pile: error: {error}", file=sys.stderr)
        return 2
    episodes = 1 if args.test else args.episodes
    limit = runner.episode_limit()
    rows = []
    for episode in range(episodes):
        rows.append(run_episode(runner, args.seed, episode, limit))
        row = rows[-1]
        print(f"episode {episode}: pile {row['pile']}, type {row['block_type']} at {row['position']}: "
              f"{'stood' if row['stood'] else 'toppled'}, rise {row['rise']:.3f} m -> "
              f"{'lifted' if row['lifted'] else 'not lifted'}", flush=True)
    stood = sum(row["stood"] for row in rows)
    lifted = sum(row["lifted"] for row in rows)
    print(f"grasp_in_pile: {lifted} / {stood} upright blocks lifted ({episodes} episodes; {episodes - stood} "
          f"toppled when stood up)")
    if args.out:
        result = {"checkpoints": args.checkpoints, "seed": args.seed, "episodes": episodes, "stood": stood,
                  "lifted": lifted, "lift": LIFT, "per_episode": rows}
        atomic_write(args.out, lambda file: file.write((json.dumps(result, indent=2) + "\n").encode()))
        print(f"grasp_in_pile: wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
