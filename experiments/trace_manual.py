"""Traces the main command's chain block by block: where the target block and the palm are, which stage runs, and
the retrieve's phase, every ``--every`` simulated seconds and at every change of stage or phase.

The chain is the one ``scripts/simulate_chain.py --headless --seed S`` runs (the shipped checkpoints, the default
manual, 3 feasibility switches), so a seed of ``experiments/main_command_seeds.py``'s record can be replayed to see
where its block was lost::

    python experiments/trace_manual.py --seed 7                  # every block of the manual, traced from block 2
    python experiments/trace_manual.py --seed 20 --from-block 1  # block 1 traced too
    python experiments/trace_manual.py --test                    # seed 0, 5 s of block 1, for CI

One line per sample: the block's index, the simulated time, the stage, the retrieve's phase and its step
(``tasks/scripted/block_retrieve_script.py``: grip, lift, regrip, transfer, lower, release, rise, done, give_up),
whether the approach controller or the stage's policy moves the arm,
the target's position and its z axis's world-z component (1 upright, 0 on a side, -1 upside down), whether the
freezer holds it, and the palm's position; then the block's outcome.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints" / "building_blocks"
#: Simulated seconds of block 1 that ``--test`` traces: Search and the start of the retrieve at seed 0.
TEST_SECONDS = 5.0


def retrieve_phase(runner, retrieve) -> str:
    """The retrieve's phase and step (``phase@step``) as its policy system sees it now."""
    context = retrieve.GetMyContextFromRoot(runner.context)
    observation = retrieve.GetInputPort("observation").Eval(context)
    ticks = retrieve.ticks(context)
    return f"{retrieve.scripted_base(context).phase(observation, ticks)}@{ticks}"


def trace(runner, block: int, every: float, duration: float) -> None:
    """Runs the runner's current object to its end (or ``duration`` s), printing a line per sample."""
    palm = runner.plant.GetBodyByName("palm")
    retrieve = runner.policies[runner.tasks.index("retrieve")] if "retrieve" in runner.tasks else None
    last = {"time": -np.inf, "stage": "", "phase": "", "approach": ""}
    start = runner.context.get_time()

    def on_tick(r) -> bool:
        t = r.context.get_time()
        stage = r.tasks[int(r.chain_output("active_stage")[0])]
        phase = retrieve_phase(r, retrieve) if stage == "retrieve" and retrieve is not None else ""
        approach = "approach" if r.chain_output("approach_active")[0] > 0.5 else "policy"
        if (t - last["time"] >= every or stage != last["stage"] or phase.split("@")[0] != last["phase"]
                or approach != last["approach"]):
            X_WB = r.object_pose()
            X_WP = r.plant.EvalBodyPoseInWorld(r.plant_context, palm)
            frozen = r.target in r.objects.frozen_names(r.context)
            print(f"block {block + 1} t={t:.2f} {stage:8s} {approach:8s} {phase:14s} "
                  f"block={np.round(X_WB.translation(), 3)} "
                  f"up={X_WB.rotation().matrix()[2, 2]:+.2f} frozen={int(frozen)} "
                  f"palm={np.round(X_WP.translation(), 3)}", flush=True)
            last.update(time=t, stage=stage, phase=phase.split("@")[0], approach=approach)
        return t - start < duration

    outcome = runner.run(runner.episode_limit(), on_tick=on_tick)
    print(f"block {block + 1} ({runner.target}): {'PLACED' if outcome.success else 'not placed'} after "
          f"{outcome.time:.2f} s, error {outcome.position_error * 100:.1f} cm "
          f"{np.degrees(outcome.rotation_error):.0f} deg, {outcome.switches} switch(es)", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="the main command's seed (default 0)")
    parser.add_argument("--manual", default="small_wall", help="assembly manual (default: small_wall)")
    parser.add_argument("--checkpoints", default=str(SHIPPED), help="default: the shipped checkpoints")
    parser.add_argument("--blocks", type=int, default=0, help="the manual's first N blocks (default: all)")
    parser.add_argument("--from-block", type=int, default=2,
                        help="trace from this block on (1-based; earlier blocks run untraced; default 2)")
    parser.add_argument("--every", type=float, default=0.5, help="seconds between samples (default 0.5)")
    parser.add_argument("--test", action="store_true",
                        help=f"seed 0, {TEST_SECONDS} s of block 1 traced (Search, then the retrieve), for CI")
    args = parser.parse_args(argv)
    from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
    from seqdex_drake.manual import LoadManual, ManualError, goal_vector
    from seqdex_drake.user_input import InputError, check_seed

    try:
        check_seed(args.seed, "--seed")
        steps = LoadManual(args.manual).steps
        blocks = 1 if args.test else (args.blocks or len(steps))
        first = 1 if args.test else args.from_block
        if not 1 <= blocks <= len(steps):
            raise InputError(f"--blocks must be in 1 .. {len(steps)} (the manual's blocks), got {args.blocks}")
        if not 1 <= first <= blocks:
            raise InputError(f"--from-block must be in 1 .. {blocks} (the blocks run), got {args.from_block}")
        if not args.every > 0:
            raise InputError(f"--every must be > 0 seconds, got {args.every}")
        if not (Path(args.checkpoints) / "manifest.json").is_file():
            raise InputError(f"--checkpoints {args.checkpoints} has no manifest.json (not a shipped checkpoint folder)")
    except (InputError, ManualError) as error:
        print(f"trace_manual: error: {error}", file=sys.stderr)
        return 2
    except (OSError, UnicodeDecodeError):
        print(f"trace_manual: error: --manual {args.manual}: cannot read it as a YAML assembly manual", file=sys.stderr)
        return 2
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=args.checkpoints, max_switches=3,
                                   seed=args.seed))
    for index, step in enumerate(steps[:blocks]):
        runner.start_block(step.block_type, goal_vector(step))
        if index + 1 >= first:
            trace(runner, index, args.every, TEST_SECONDS if args.test else np.inf)
        else:
            outcome = runner.run(runner.episode_limit())
            print(f"block {index + 1} ({runner.target}): {'PLACED' if outcome.success else 'not placed'} "
                  f"(untraced)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
