"""The retrieve in the whole-chain scene, then the shipped chain from Orient: what the chain places once the target
is taken out of the pile and set down alone on the staging area.

Each episode (seeded by ``--seed`` and its number) restores a cached pile of the chain's scene (the 32 held-out
piles, ``building_blocks_eval_piles.npz``; ``--piles train`` for the 8 Search trained on, where the retrieve was
tuned), takes the episode's block type (1-5 by turns), picks the block of that type easiest to take out
(``tasks/blocks_common.retrieve_order``), hovers the open hand 3 cm over its neighbourhood and runs the scripted
retrieve (``tasks/scripted/block_retrieve_script.py``) in a Search env on the chain's scene. If the block was set
down on the staging area, the scene (pile, block, robot) goes to the shipped chain (``evaluation/runner.ChainRunner``,
sequential: Search one control step, then the approach, Orient, Grasp, the carry and Insert, each on its budget)
to a stud-aligned goal on the baseplate. Recorded per episode: the retrieve's outcome and steps, the funnel
(upright when Grasp starts, lifted at least 0.1 m when Insert starts, placed) and the wall-clock.

    python experiments/retrieve_chain.py --episodes 0-19 --out runs/retrieve/a.json     # one core each
    python experiments/retrieve_chain.py --episodes 20-39 --out runs/retrieve/b.json
    python experiments/retrieve_chain.py --summary runs/retrieve/a.json runs/retrieve/b.json
    python experiments/retrieve_chain.py --piles train --retrieve-only --episodes 0-39   # the retrieve alone
    python experiments/retrieve_chain.py --test            # one retrieve cut to 30 steps, no chain: for CI

About 2 minutes per episode on a core (the retrieve about 1, the chain about 1).
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TYPES = (1, 2, 3, 4, 5)
PILES = {"eval": "package://seqdex_models/piles/building_blocks_eval_piles.npz",
         "train": "package://seqdex_models/piles/building_blocks_piles.npz"}
#: Upright at Grasp's start: the block's z axis within 20 deg of world z; lifted: 0.1 m above the table.
UPRIGHT_DOT, LIFTED = float(np.cos(np.radians(20.0))), 0.1


def episode_range(text: str) -> list[int]:
    first, _, last = text.partition("-")
    first, last = int(first), int(last or first)
    if first < 0 or last < first:
        raise ValueError(f"--episodes must be A-B with 0 <= A <= B, got {text!r}")
    return list(range(first, last + 1))


def retrieve(env, q_pile: np.ndarray, block_type: int, steps: int, seed: int) -> dict:
    """Resets ``env`` (seed ``seed``: nothing of an earlier episode carries over), restores ``q_pile``, picks the
    block and runs the scripted retrieve; returns its record."""
    from seqdex_drake.modeling.blocks import BLOCK_SPECS
    from seqdex_drake.tasks.blocks_common import pick_keys
    from seqdex_drake.tasks.retrieve import start_retrieve
    from seqdex_drake.tasks.scripted.block_retrieve_script import ScriptedBlockRetrieve

    env.reset(seed=seed)
    names = env.objects.names
    row = names.index(start_retrieve(env, q_pile, block_type))  # The retrieve stage's own start (tasks/retrieve.py).
    blocks = [k for k, name in enumerate(names) if name.startswith("block_")]
    script = ScriptedBlockRetrieve(length=BLOCK_SPECS[block_type].footprint[0])
    observation, phase, step = env.observation(), "", 0
    for step in range(steps):
        phase = script.phase(observation, step)
        if phase in ("done", "give_up"):
            break
        observation, _, terminated, _, info = env.step(script.act(observation, step))
        if info.get("simulator_error") or terminated:  # A failed solve, or the block off the table.
            phase = "simulator_error" if info.get("simulator_error") else "left_table"
            break
    keys = pick_keys(q_pile[blocks], blocks.index(row))
    R = env.object_pose().rotation().matrix()
    return {"block": names[row], "tilt": round(keys["tilt"], 1), "covered": keys["covered"],
            "on_floor": keys["on_floor"], "retrieve_phase": phase, "retrieve_steps": step,
            "staged": phase == "done", "staged_at": np.round(env.object_position(), 4).tolist(),
            "staged_tilt": round(float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))), 1),
            "staged_on_end": bool(abs(R[2, 0]) > 0.7)}  # Its long axis within 45 deg of vertical.


def chain_from_orient(runner, env, name: str, block_type: int, goal: np.ndarray, time_limit: float) -> dict:
    """Copies ``env``'s scene into ``runner`` and runs the chain on ``name`` from Orient; returns the funnel."""
    for model in ("franka", "allegro"):
        source, target = env.plant.GetModelInstanceByName(model), runner.plant.GetModelInstanceByName(model)
        runner.plant.SetPositions(runner.plant_context, target, env.plant.GetPositions(env.plant_context, source))
        runner.plant.SetVelocities(runner.plant_context, target,
                                   np.zeros(runner.plant.num_velocities(target)))
    runner.objects.set_positions(runner.context, env.objects.positions(env.context),
                                 frozen=env.objects.frozen_mask(env.context))
    runner.objects.forget_motion()  # Nothing of the previous episode decides what wakes or sleeps.
    runner.start_block(block_type, goal, name=name)
    entries: dict[str, list[float]] = {}
    z0 = float(runner.object_pose().translation()[2])

    def record(r) -> bool:
        stage = r.tasks[int(r.chain_output("active_stage")[0])]
        if stage not in entries:
            X = r.object_pose()
            entries[stage] = [float(X.rotation().matrix()[2, 2]), float(X.translation()[2] - z0)]
        return True

    outcome = runner.run(time_limit, on_tick=record)
    return {"up_z_at_orient": round(entries.get("orient", [float("nan")])[0], 3),
            "upright_at_grasp": bool(entries.get("grasp", [0.0])[0] >= UPRIGHT_DOT),
            "lifted_at_insert": bool(entries.get("insert", [0.0, 0.0])[1] >= LIFTED),
            "placed": bool(outcome.success), "position_error": round(float(outcome.position_error), 4),
            "simulator_error": outcome.simulator_error}


def summary(paths: list[str]) -> dict:
    rows = [row for path in paths for row in json.loads(Path(path).read_text())["per_episode"]]
    keys = ("staged", "upright_at_grasp", "lifted_at_insert", "placed")
    counts = {key: sum(bool(row.get(key)) for row in rows) for key in keys}
    wall = sum(row["wall_s"] for row in rows)
    return {"episodes": len(rows), **counts, "wall_s": round(wall), "core_hours": round(wall / 3600, 2)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", default=str(ROOT / "checkpoints" / "building_blocks"),
                        help="shipped checkpoint folder (default: the shipped one)")
    parser.add_argument("--episodes", help="episode numbers A-B (default 0-19; 0 with --test)")
    parser.add_argument("--piles", choices=sorted(PILES), default="eval",
                        help="eval: the 32 held-out piles (default); train: the 8 Search trained on")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pile and goal draws (default 0)")
    parser.add_argument("--retrieve-steps", type=int, default=800, help="the retrieve's step budget (default 800)")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--summary", nargs="+", metavar="JSON", help="only print the counts of these results")
    parser.add_argument("--retrieve-only", action="store_true",
                        help="only the retrieve: no chain after it (what the staged count measures)")
    parser.add_argument("--test", action="store_true", help="retrieves cut to 30 steps and no chain, for CI")
    args = parser.parse_args(argv)
    from seqdex_drake.atomic import atomic_write
    from seqdex_drake.user_input import InputError, check_creatable, check_seed

    if args.summary:
        print(json.dumps(summary(args.summary)))
        return 0
    try:
        check_seed(args.seed)
        episodes = episode_range(args.episodes or ("0" if args.test else "0-19"))
        if args.out:
            check_creatable(args.out, "--out")
        if not Path(args.checkpoints).is_dir():
            raise InputError(f"--checkpoints {args.checkpoints} is not a directory")
    except (InputError, ValueError) as error:
        print(f"retrieve_chain: error: {error}", file=sys.stderr)
        return 2
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.evaluation.episodes import sample_goal
    from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
    from seqdex_drake.harness import ResolvePackageUrl
    from seqdex_drake.scene.piles import LoadPiles
    from seqdex_drake.tasks.search import default_config

    steps = 30 if args.test else args.retrieve_steps
    env = make_env("search", dataclasses.replace(default_config(), scenario="building_blocks/chain",
                                                 episode_length=steps + 1, ema=1.0))
    piles = LoadPiles(ResolvePackageUrl(PILES[args.piles]), env.objects.names)
    runner = None
    if not (args.test or args.retrieve_only):
        runner = ChainRunner(RunConfig(family="building_blocks", run_dir=args.checkpoints, max_switches=0,
                                       seed=args.seed, stage_steps=(1, 75, 150, 125),
                                       chain="building_blocks_policies"))
        yaws = runner.stage_configs[runner.tasks.index("insert")].goal_yaws_deg
    rows = []
    for episode in episodes:
        start = time.time()
        rng = np.random.default_rng([args.seed, episode])
        block_type = TYPES[episode % len(TYPES)]
        pile = int(rng.integers(len(piles)))
        row = {"episode": episode, "pile": pile, "block_type": block_type,
               **retrieve(env, piles[pile], block_type, steps, seed=int(rng.integers(1 << 30)))}
        goal = sample_goal(block_type, rng, yaws) if runner is not None else None
        if runner is not None and row["staged"]:
            row.update(chain_from_orient(runner, env, row["block"], block_type, goal, runner.episode_limit()))
        row["wall_s"] = round(time.time() - start, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    result = {"checkpoints": args.checkpoints, "piles": args.piles, "seed": args.seed,
              "retrieve_steps": steps, "per_episode": rows}
    if args.out:
        atomic_write(args.out, lambda file: file.write((json.dumps(result, indent=1) + "\n").encode()))
        print(f"retrieve_chain: wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
