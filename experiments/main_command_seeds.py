"""The README's main command measured over seeds: which of the assembly manual's blocks it places from each seed.

Each seed runs the chain exactly as ``scripts/simulate_chain.py --headless --seed S`` does (the shipped
checkpoints, 3 feasibility switches, the manual's blocks one after another in one scene, each until it is placed
or its episode limit), for the first ``--blocks`` blocks of the manual. A block counts as placed by the runner's
physical test (``ChainRunner.is_success``: within 2 cm and 0.2 rad of its goal, released and at rest).

    python experiments/main_command_seeds.py --seeds 0-31 --blocks 1 --workers 2 \\
        --out results/building_blocks/main_command_first_block.json
    python experiments/main_command_seeds.py --seeds 0-31 --workers 2 \\
        --out results/building_blocks/main_command_manual.json
    python experiments/main_command_seeds.py --seeds 0-31 --blocks 1 --piles tune   # tuning the chain
    python experiments/main_command_seeds.py --test     # one seed, the first block cut to 0.5 s, for CI

``--piles`` picks the piles: the held-out ones (default; nothing is tuned on them), 32 others kept for tuning the
chain (``scripts/generate_piles.py --count 32 --seed 1000``), or Search's 8 training piles.

When the retrieve cannot take a block out of the pile, the chain fetches another of its type, at most
``--refetches`` times (``evaluation/refetch.py``; 0 measures the first block alone).

Writes JSON: per block the seed, its index in the manual, type, the block fetched first and last, the refetches,
whether it was placed, its errors, simulated time and switches, the funnel of the last block fetched (on the
staging area when Orient first starts, upright when Grasp first starts, lifted when Insert first starts); and the
placed counts per manual step and the seeds that placed the whole manual (``manual_placed``). The record is
written after every seed (with ``seeds_done`` until the last), so a stopped run keeps what it finished. About
4 min per block on a core.
"""

import argparse
import json
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints" / "building_blocks"
#: The most seeds one run takes.
MAX_SEEDS = 1000
#: The funnel's upright (the block's z axis within 20 deg of world z) and lifted (0.1 m above its start) tests, as
#: ``experiments/retrieve_chain.py``'s.
UPRIGHT_DOT, LIFTED = float(np.cos(np.radians(20.0))), 0.1


#: The pile files ``--piles`` chooses from (``models/piles/``): seed S runs pile S modulo the file's count.
PILE_FILES = {"eval": "building_blocks_eval_piles.npz", "tune": "building_blocks_tune_piles.npz",
              "train": "building_blocks_piles.npz"}


def parse_seeds(text: str) -> list[int]:
    """``"0-31"``, ``"4,12"`` or a mix (``"0-3,9"``) -> the seeds, in order, each once."""
    from seqdex_drake.user_input import InputError, check_seed

    seeds: list[int] = []
    for part in text.split(","):
        try:
            low, _, high = part.strip().partition("-")
            span = range(int(low), int(high or low) + 1)
        except ValueError:
            raise InputError(f"--seeds: '{part}' is not a seed or a range like 0-31") from None
        if not span:
            raise InputError(f"--seeds: the range '{part}' is empty")
        check_seed(span[0], "--seeds")
        check_seed(span[-1], "--seeds")
        if len(seeds) + len(span) > MAX_SEEDS:
            raise InputError(f"--seeds: at most {MAX_SEEDS} seeds (about 1.5 min each per block)")
        for seed in span:
            if seed not in seeds:
                seeds.append(seed)
    return seeds


class Funnel:
    """Where a block got to, from the object as each stage first started: taken out of the pile onto the staging
    area when Orient starts (with a retrieve stage; its centre over the area and resting on the table, the
    retrieve's own test ``tasks/retrieve.block_staged``), upright when Grasp starts, lifted when Insert starts."""

    def __init__(self):
        self.entries: dict[str, tuple] = {}
        self.start_z, self.refetches = None, 0

    def record(self, runner) -> bool:
        from seqdex_drake.tasks.retrieve import block_staged
        from seqdex_drake.tasks.search import block_type_of

        X = runner.object_pose()
        if runner.refetches != self.refetches:  # Another block fetched: its own funnel.
            self.entries, self.start_z, self.refetches = {}, None, runner.refetches
        if self.start_z is None:
            self.start_z = float(X.translation()[2])
        stage = runner.tasks[int(runner.chain_output("active_stage")[0])]
        if stage not in self.entries:
            self.entries[stage] = (block_staged(X, block_type_of(runner.target)), float(X.rotation().matrix()[2, 2]),
                                   float(X.translation()[2]) - self.start_z)
        return True

    def summary(self) -> dict:
        orient, grasp, insert = (self.entries.get(stage) for stage in ("orient", "grasp", "insert"))
        return {"staged_at_orient": bool(orient and orient[0]),
                "upright_at_grasp": bool(grasp and grasp[1] >= UPRIGHT_DOT),
                "lifted_at_insert": bool(insert and insert[2] >= LIFTED)}


def worker_machine() -> str:
    """The numerics of a worker process (``numerics.machine``): the workers run the episodes, and they are pinned
    even where this process is not (pinning sets the environment the workers start in)."""
    from seqdex_drake import numerics

    return numerics.machine()


def recorded_path(path: str) -> str:
    """``path`` relative to the repository when inside it (records name the same checkpoints on every machine)."""
    resolved = Path(path).resolve()
    return str(resolved.relative_to(ROOT)) if resolved.is_relative_to(ROOT) else path


def run_seed(job: tuple) -> list[dict]:
    """The manual's first ``blocks`` blocks from ``seed`` (a fresh chain, as the main command builds it)."""
    seed, checkpoints, manual, blocks, max_switches, refetches, trigger, time_limit, piles = job
    from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
    from seqdex_drake.manual import LoadManual, goal_vector

    overrides = "" if piles == "eval" else f"pile_file: package://seqdex_models/piles/{PILE_FILES[piles]}\n"
    runner = ChainRunner(RunConfig(family="building_blocks", run_dir=checkpoints, max_switches=max_switches,
                                   refetches=refetches, trigger=trigger, seed=seed, scenario_overrides=overrides))
    rows = []
    for index, step in enumerate(LoadManual(manual).steps[:blocks]):
        start = time.perf_counter()
        name = runner.start_block(step.block_type, goal_vector(step))
        funnel = Funnel()
        outcome = runner.run(time_limit or runner.episode_limit(), on_tick=funnel.record)
        rows.append({"seed": seed, "step": index, "block_type": step.block_type, "block": name,
                     "refetches": outcome.refetches, "fetched": runner.target,
                     "placed": bool(outcome.success), "position_error": round(float(outcome.position_error), 4),
                     "rotation_error": round(float(outcome.rotation_error), 4), "time": round(outcome.time, 2),
                     "switches": int(outcome.switches), "simulator_error": outcome.simulator_error,
                     **funnel.summary(),
                     "wall_seconds": round(time.perf_counter() - start, 1)})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-31", help="seeds: a range 0-31, a list 4,12 or both (default 0-31)")
    parser.add_argument("--blocks", type=int, default=0, help="the manual's first N blocks (default: all)")
    parser.add_argument("--manual", default="small_wall", help="assembly manual (default: small_wall)")
    parser.add_argument("--checkpoints", default=str(SHIPPED), help="default: the shipped checkpoints")
    parser.add_argument("--max-switches", type=int, default=3, help="feasibility switches per block (default 3)")
    parser.add_argument("--refetches", type=int, default=0,
                        help="other blocks of the type fetched when the retrieve leaves one in the pile (default 0, "
                             "the main command's)")
    parser.add_argument("--trigger", default="", help="the switcher's trigger: next, any_later or decision "
                        "(``SwitcherParams.trigger``; default: the main command's)")
    parser.add_argument("--piles", default="eval",
                        help="the piles: eval, the held-out ones the main command uses (default); tune, 32 others "
                             "for tuning the chain; train, Search's 8 training piles")
    parser.add_argument("--workers", type=int, default=1, help="processes, one seed each at a time (default 1)")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--test", action="store_true", help="seed 0, the first block cut to 0.5 s, for CI")
    args = parser.parse_args(argv)
    from seqdex_drake.atomic import atomic_write
    from seqdex_drake.controller.switcher import TRIGGERS
    from seqdex_drake.evaluation.chain_settings import SWITCH_TRIGGER
    from seqdex_drake.manual import LoadManual, ManualError
    from seqdex_drake.user_input import InputError, check_creatable

    try:
        seeds = [0] if args.test else parse_seeds(args.seeds)
        steps = LoadManual(args.manual).steps
        blocks = 1 if args.test else (args.blocks or len(steps))
        if not 1 <= blocks <= len(steps):
            raise InputError(f"--blocks must be in 1 .. {len(steps)} (the manual's blocks), got {args.blocks}")
        if args.workers < 1:
            raise InputError(f"--workers must be >= 1, got {args.workers}")
        if args.max_switches < 0:
            raise InputError(f"--max-switches must be >= 0, got {args.max_switches}")
        if args.refetches < 0:
            raise InputError(f"--refetches must be >= 0, got {args.refetches}")
        if not (Path(args.checkpoints) / "manifest.json").is_file():
            raise InputError(f"--checkpoints {args.checkpoints} has no manifest.json (not a shipped checkpoint folder)")
        if args.piles not in PILE_FILES:
            raise InputError(f"--piles must be one of {', '.join(PILE_FILES)}, got '{args.piles}'")
        if args.trigger not in ("", *TRIGGERS):
            raise InputError(f"--trigger must be one of {', '.join(TRIGGERS)}, got '{args.trigger}'")
        if args.out:
            check_creatable(args.out, "--out")
    except (InputError, ManualError) as error:
        print(f"main_command_seeds: error: {error}", file=sys.stderr)
        return 2
    except (OSError, UnicodeDecodeError):  # A directory, an unreadable or a binary file.
        print(f"main_command_seeds: error: --manual {args.manual}: cannot read it as a YAML assembly manual",
              file=sys.stderr)
        return 2
    jobs = [(seed, args.checkpoints, args.manual, blocks, args.max_switches, args.refetches, args.trigger,
             0.5 if args.test else None, args.piles)
            for seed in seeds]
    machine = ""

    def write(rows: list[dict], done: bool) -> None:
        """The record (atomically; after every seed, so a stopped run keeps the seeds it finished)."""
        placed = [sum(row["placed"] for row in rows if row["step"] == k) for k in range(blocks)]
        result = {"checkpoints": recorded_path(args.checkpoints), "manual": args.manual, "piles": args.piles,
                  "max_switches": args.max_switches, "refetches": args.refetches,
                  "trigger": args.trigger or SWITCH_TRIGGER["building_blocks"], "seeds": seeds, "blocks": blocks,
                  **({} if done else {"seeds_done": sorted({row["seed"] for row in rows})}),
                  "placed_per_step": placed, "seeds_placing": sorted({row["seed"] for row in rows if row["placed"]}),
                  "manual_placed": sorted(seed for seed in {row["seed"] for row in rows}
                                          if sum(row["placed"] for row in rows if row["seed"] == seed) == blocks),
                  "machine": machine, "per_block": rows}
        atomic_write(args.out, lambda file: file.write((json.dumps(result, indent=2) + "\n").encode()))

    rows = []
    with get_context("spawn").Pool(min(args.workers, len(jobs))) as pool:
        machine = pool.apply(worker_machine)
        for seed_rows in pool.imap(run_seed, jobs):
            for row in seed_rows:
                print(f"seed {row['seed']} block {row['step'] + 1} (type {row['block_type']}, {row['block']}): "
                      f"{'PLACED' if row['placed'] else 'not placed'} after {row['time']:.2f} s, error "
                      f"{row['position_error'] * 100:.1f} cm {np.degrees(row['rotation_error']):.0f} deg "
                      f"({row['wall_seconds']:.0f} s wall)", flush=True)
            rows.extend(seed_rows)
            if args.out:
                write(rows, done=False)
    placed = [sum(row["placed"] for row in rows if row["step"] == k) for k in range(blocks)]
    seeds_placing = sorted({row["seed"] for row in rows if row["placed"]})
    print(f"main_command_seeds: placed per manual step {placed} of {len(seeds)} seeds; seeds placing a block: "
          f"{seeds_placing}")
    if args.out:
        write(rows, done=True)
        print(f"main_command_seeds: wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
