"""How firmly Grasp's jaw pinch holds its block: per digit, the contact force on the lifted block at the episode's
end, and the block's tilt through the lift (Grasp's own env, the script alone or a shipped policy).

The pinch is three fingertips on two faces: index and middle on the block's far face, the thumb on the near one. A
block held so resists turning about the line through the thumb and one finger only while the other finger presses;
where it barely touches, the block pivots in the pinch under the hand's accelerations (seen in the whole chain:
blocks turned over on their way to the baseplate, ``results/building_blocks.md``)::

    python experiments/grasp_hold_forces.py --seeds 0-15 --types 5 --out runs/grasp_hold/type5.json
    python experiments/grasp_hold_forces.py --seeds 100-139 \
        --checkpoint checkpoints/building_blocks/stages/grasp/best.pt

One line per episode (its seed, the block type, success, the least cos(tilt) from step 60 on, the forces in N),
then the summary: lifted, lifted with tilt at most 18 deg throughout, and the median force per digit.
"""

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
#: Tilt (deg) a lifted block may have for Insert: more, and the carry's turn or the studs seldom make up for it.
MAX_TILT_DEG = 18.0
#: The lift starts at step 48 (``ScriptedBlockGrasp.lift_at``); from here on the block should be off the table.
LIFTED_FROM_STEP = 60
DIGITS = ("index", "middle", "ring", "thumb")


def digit_forces(env) -> dict[str, float]:
    """Summed contact force magnitudes (N) on the target block, per hand digit (its links) and others by body."""
    body = int(env.objects.bodies[env.objects.index(env.target_object)].index())
    results = env.plant.get_contact_results_output_port().Eval(env.plant_context)
    forces: dict[str, float] = {}
    for k in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(k)
        a, b = int(info.bodyA_index()), int(info.bodyB_index())
        if body not in (a, b):
            continue
        name = env.plant.get_body(info.bodyB_index() if a == body else info.bodyA_index()).name()
        key = next((digit for digit in DIGITS if name.startswith(digit)), name)
        forces[key] = forces.get(key, 0.0) + float(np.linalg.norm(info.contact_force()))
    return {key: round(value, 3) for key, value in sorted(forces.items())}


def run_episode(env, policy, seed: int) -> dict:
    """One Grasp episode from ``env.reset(seed=seed)`` with ``policy`` (observation -> correction)."""
    observation, _ = env.reset(seed=seed)
    ups, info = [], {}
    for step in range(env.config.episode_length):
        observation, _, terminated, truncated, info = env.step(policy(observation))
        if step >= LIFTED_FROM_STEP:
            ups.append(float(env.object_pose().rotation().matrix()[2, 2]))
        if terminated or truncated:
            break
    least_up = min(ups) if ups else float("nan")
    success = bool(info.get("success", False))
    return {"seed": seed, "block": env.target_object, "success": success, "least_up": round(least_up, 4),
            "upright": bool(success and least_up >= np.cos(np.radians(MAX_TILT_DEG))), "forces": digit_forces(env)}


def summarize(rows: list[dict]) -> dict:
    """Counts and the median force per digit over the lifted episodes (0 where a digit does not touch)."""
    lifted = [row for row in rows if row["success"]]
    medians = {digit: round(float(np.median([row["forces"].get(digit, 0.0) for row in lifted])), 3)
               for digit in ("index", "middle", "thumb")} if lifted else {}
    return {"episodes": len(rows), "lifted": len(lifted), "upright": sum(row["upright"] for row in rows),
            "max_tilt_deg": MAX_TILT_DEG, "median_force_lifted": medians}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-15", help="episode seeds, e.g. 0-15 or 3,5,9 (default 0-15)")
    parser.add_argument("--types", default="1,2,3,4,5", help="block types the resets draw (default: 1-5)")
    parser.add_argument("--region", default="staging", choices=("staging", "box"),
                        help="where the block stands (default: the staging area, where the chain's Grasp runs)")
    parser.add_argument("--checkpoint", default=None, help="a Grasp checkpoint (default: the script alone)")
    parser.add_argument("--out", default=None, help="write the episodes and the summary to this JSON file")
    args = parser.parse_args(argv)
    from main_command_seeds import parse_seeds

    from seqdex_drake.atomic import atomic_write
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.tasks.registry import budget_config
    from seqdex_drake.user_input import InputError, check_creatable

    try:
        seeds = parse_seeds(args.seeds)
        types = [int(t) for t in args.types.split(",")]
        if not types or any(t not in range(1, 9) for t in types):
            raise InputError(f"--types takes block types 1-8, e.g. 1,2,3; got {args.types}")
        if args.checkpoint is not None and not Path(args.checkpoint).is_file():
            raise InputError(f"--checkpoint {args.checkpoint} is not a file (give a Grasp checkpoint, e.g. "
                             f"checkpoints/building_blocks/stages/grasp/best.pt)")
        if args.out:
            check_creatable(Path(args.out), "--out")
    except (InputError, ValueError) as error:
        print(f"grasp_hold_forces: error: {error}", file=sys.stderr)
        return 2
    config = dataclasses.replace(budget_config("grasp"), reset_region=args.region, object_types=types)
    env = make_env("grasp", config)
    if args.checkpoint is None:
        zeros = np.zeros(env.action_space.shape, dtype=np.float32)
        policy = lambda observation: zeros  # noqa: E731 - the script alone: zero corrections.
    else:
        from seqdex_drake import load_policy
        from seqdex_drake.rl.checkpoint import CheckpointError

        try:
            policy = load_policy(args.checkpoint, task="grasp")
        except (CheckpointError, ValueError) as error:
            print(f"grasp_hold_forces: error: --checkpoint {args.checkpoint}: {error}", file=sys.stderr)
            return 2
    rows = []
    for seed in seeds:
        rows.append(run_episode(env, policy, seed))
        print(json.dumps(rows[-1]), flush=True)
    summary = summarize(rows)
    print(json.dumps(summary), flush=True)
    if args.out:
        record = {"seeds": args.seeds, "types": types, "region": args.region,
                  "checkpoint": args.checkpoint or "the script alone", "summary": summary, "episodes": rows}
        atomic_write(Path(args.out), lambda file: file.write((json.dumps(record, indent=1) + "\n").encode()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
