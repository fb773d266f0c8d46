"""``seqdex ship``: a finished pipeline run's policies and feasibility functions, as a shipped checkpoint folder.

    seqdex ship --run-dir runs/tool_positioning_seqdex [--out checkpoints/tool_positioning] [--force]

Reads the run of ``seqdex pipeline`` in ``--run-dir`` (``pipeline.json``, ``stages/<task>/last.pt``,
``feasibility/<task>.pt``) and writes the folder of :mod:`seqdex_drake.chaining.shipped` (default
``checkpoints/<chain>``): each stage's policy for inference (its checkpoint without the optimizer's moments,
``chaining.shipped.inference_checkpoint``) with its normalizer, observation spec, preset and task config, the
env steps of its checkpoint and the wall-clock and core-hours of its training (the run it was initialized from,
``--init``, plus the pipeline's PPO phases of that stage), each F with its threshold h, the pipeline's config and
wall-clock, and the commit that made them. The folder is written next to its destination and moved in whole, so
an existing one is never left half-replaced; replacing one needs ``--force``.
"""

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

from seqdex_drake.chaining.chain_files import observation_sizes
from seqdex_drake.chaining.shipped import ShippedChainError, StageRecord, load_shipped_chain, ship_chain
from seqdex_drake.cli import CliError
from seqdex_drake.evaluation.learning_curves import read_curve

#: Cores a pipeline's PPO phases and ``seqdex train`` runs use on the machine this project trains on.
TRAINING_CORES = 2


def add_parser(commands) -> None:
    """Adds the ``ship`` subcommand to the argparse subparsers object ``commands``."""
    parser = commands.add_parser("ship", help="write a pipeline run's policies and F's as a shipped checkpoint folder",
                                 description="Copy a finished seqdex pipeline run's stage policies and feasibility "
                                 "functions into a checked folder (manifest with hashes, observation specs, task "
                                 "configs, env steps, wall-clock, commit) that simulate_chain.py and seqdex evaluate "
                                 "load.")
    parser.add_argument("--run-dir", required=True, help="the seqdex pipeline run directory")
    parser.add_argument("--out", help="the folder to write (default: checkpoints/<chain>)")
    parser.add_argument("--force", action="store_true", help="replace an existing folder at --out")
    parser.add_argument("--cores", type=int, default=TRAINING_CORES,
                        help=f"cores the training used, for core-hours (default {TRAINING_CORES})")


def _commit() -> str:
    try:
        result = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=12"], capture_output=True,
                                text=True, check=True, cwd=Path(__file__).resolve().parent)
    except (OSError, subprocess.CalledProcessError):
        return ""
    return result.stdout.strip()


def _initial_training_seconds(checkpoint: str) -> float:
    """Wall-clock of the ``seqdex train`` run that wrote ``checkpoint`` (its learning curve's last point)."""
    try:
        return float(read_curve(Path(checkpoint).parent)["wall_clock_s"][-1])
    except ValueError as error:
        raise CliError(f"--init checkpoint {checkpoint}: {error}; its training time cannot be reported") from error


def stage_records(run_dir: Path, record: dict, cores: int) -> list:
    """One :class:`~seqdex_drake.chaining.shipped.StageRecord` per stage of the pipeline run in ``run_dir``."""
    config, stages = record["config"], record["stages"]
    init = config.get("init_checkpoints") or {}
    records = []
    for index, task in enumerate(stages):
        policy = run_dir / "stages" / task / "last.pt"
        if not policy.is_file():
            raise CliError(f"{policy} is missing: the run's stage {task} has not been trained; finish the run "
                           f"(seqdex pipeline ... --resume) first")
        phases = (f"forward_{index}_{task}", "finetune_", "reforward_")
        seconds = sum(outcome.get("seconds", 0.0) for phase, outcome in record["done"].items()
                      if phase == phases[0] or (phase.startswith(phases[1:]) and phase.endswith(f"_{task}")))
        if task in init:
            seconds += _initial_training_seconds(init[task])
        records.append(StageRecord(task, policy, preset=config.get("preset", "paper"), wall_clock_s=seconds,
                                   cores=cores))
    return records


def run(args) -> int:
    run_dir = Path(args.run_dir)
    record_path = run_dir / "pipeline.json"
    if not record_path.is_file():
        raise CliError(f"{run_dir} holds no pipeline run ({record_path.name} is missing); ship the run directory "
                       f"of a seqdex pipeline")
    record = json.loads(record_path.read_text())
    config, stages = record["config"], record["stages"]
    if config.get("episode_length_cap", 0) > 0 or config.get("hidden_sizes"):
        raise CliError(f"{run_dir} is a --test run (shortened episodes, small networks): its policies do not fit the "
                       f"tasks as the chain runs them; ship a full run")
    if not (run_dir / "results.json").is_file():
        raise CliError(f"{run_dir}: the pipeline has not finished (no results.json); resume it first")
    if args.cores < 1:
        raise CliError(f"--cores must be >= 1, got {args.cores}")
    out = Path(args.out or f"checkpoints/{config['chain']}")
    if out.exists() and not args.force:
        raise CliError(f"{out} already exists; pass --force to replace it")
    feasibility = {task: run_dir / "feasibility" / f"{task}.pt" for task in stages[1:]
                   if (run_dir / "feasibility" / f"{task}.pt").is_file()}
    results = json.loads((run_dir / "results.json").read_text())
    extra = {"pipeline": {"run_dir": str(run_dir), "method": config["method"], "config": config,
                          "wall_clock_s": results.get("wall_clock_s"), "ppo_steps": results.get("ppo_steps"),
                          "success_rate": results.get("success_rate"),
                          "success_rate_switcher": results.get("success_rate_switcher")}}
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        ship_chain(staging, config["chain"], stage_records(run_dir, record, args.cores), feasibility,
                   commit=_commit(), extra=extra)
        load_shipped_chain(staging, config["chain"], stages, observation_sizes())  # What the users' load checks.
        old = out.with_name(f".{out.name}.old")
        if out.exists():
            shutil.rmtree(old, ignore_errors=True)
            out.rename(old)
        staging.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    except ShippedChainError as error:
        raise CliError(f"the shipped folder would not load: {error}") from error
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    manifest = json.loads((out / "manifest.json").read_text())
    for task, entry in manifest["stages"].items():
        print(f"{task}: {entry['env_steps']} env steps, {entry['wall_clock_s'] / 3600:.2f} h wall-clock, "
              f"{entry['core_hours']:.2f} core-hours")
    print(f"seqdex ship: wrote {out} ({len(manifest['stages'])} policies, {len(manifest['feasibility'])} F's, "
          f"commit {manifest['commit'] or 'unknown'})")
    return 0
