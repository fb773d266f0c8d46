"""Shipped chain checkpoints: a chain's trained policies and feasibility functions in one checked folder.

Layout (that of a chain run directory, so :func:`~seqdex_drake.chaining.chain_files.LoadChainCheckpoints`
also reads it, plus a manifest)::

    checkpoints/<chain>/manifest.json              format, version, chain, commit, per stage and per F: the file,
                                                   its SHA-256, observation spec, preset and task config, env steps,
                                                   wall-clock and core-hours of its training
    checkpoints/<chain>/stages/<task>/best.pt      the policy (its PPO checkpoint for inference: normalizer inside,
                                                   the optimizer's moments and the env state left out)
    checkpoints/<chain>/feasibility/<task>.pt      F predicting <task>'s return (with its threshold h)

A scripted stage (``Task.scripted``: its base acts alone) has no policy and no manifest entry; a folder shipped from
a run of the chain's learned stages alone (``building_blocks_policies``) loads as the chain (``building_blocks``).

:func:`ship_chain` writes one from training runs; :func:`load_shipped_chain` checks one before anything is built:
the manifest's format and version, every file present and whole (its hash), each policy's observation spec
against its stage's (another task's policy or another observation layout is refused, naming the file), and each
stage's recorded task config against the one the code builds for its preset (a policy trained with scripted
phases must be deployed with them). Every failure is a :class:`ShippedChainError` naming the file and the
mismatch.
"""

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.rl.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from seqdex_drake.tasks.registry import default_config, is_scripted
from seqdex_drake.tasks.run_config import config_dict, observation_spec, same_task_config, task_config

FORMAT = "seqdex_drake.shipped_chain"
VERSION = 1
MANIFEST = "manifest.json"


class ShippedChainError(ValueError):
    """A shipped checkpoint folder that cannot be used (missing, truncated or mismatched file)."""


@dataclasses.dataclass
class StageRecord:
    """One trained stage, as :func:`ship_chain` takes it."""

    task: str
    checkpoint: Path
    """Its PPO checkpoint (``best.pt`` or ``last.pt`` of a ``seqdex train`` run)."""
    preset: str = "budget"
    """The ``seqdex train --preset`` it was trained with (its task config)."""
    wall_clock_s: float = 0.0
    """Training wall-clock (s), from the run's learning curve."""
    cores: int = 2
    """Cores the training used (core-hours = wall-clock x cores)."""
    residual: bool = True
    """Whether it trained on its preset's residual base (``cli.task_config``; False: a run with ``--demos``)."""


@dataclasses.dataclass
class ShippedChain:
    """What :func:`load_shipped_chain` found, checked."""

    folder: Path
    tasks: list[str]
    policies: list[Path | None]
    feasibility: list[Path | None]
    configs: list
    """Per stage, the :class:`~seqdex_drake.tasks.base.TaskConfig` its policy was trained with."""
    manifest: dict

    @property
    def stages(self) -> list[tuple[str, Path | None]]:
        return list(zip(self.tasks, self.policies, strict=True))

    @property
    def missing(self) -> list[str]:
        return [f"stage {i} ({task}): not shipped in {self.folder}; the stage runs an untrained policy"
                for i, (task, policy) in enumerate(self.stages) if policy is None and not is_scripted(task)]


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as file:
        for chunk in iter(lambda: file.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def inference_checkpoint(state: dict) -> dict:
    """A PPO checkpoint ``state`` as a shipped policy keeps it: without the optimizer's per-parameter state (Adam's
    moments, twice the weights) and the saved env state, which only resuming training reads. The weights (the
    critic's too: ``PPO.resume`` and ``load_policy`` rebuild the whole actor-critic), normalizer, config, counters
    and RNG states stay, so both load it as before and act the same; training continued from it starts its
    optimizer afresh."""
    shipped = {key: value for key, value in state.items() if key != "env"}
    shipped["optimizer"] = {**state["optimizer"], "state": {}}
    return shipped


def _stage_config(task: str, preset: str, residual: bool = True):
    return task_config(task, False, preset, residual=residual)


def ship_chain(folder: str | Path, chain: str, stages: list[StageRecord], feasibility: dict[str, Path] | None = None,
               commit: str = "", extra: dict | None = None) -> Path:
    """Writes the stages' checkpoints for inference (:func:`inference_checkpoint`) and copies the F files (by
    target task) into ``folder``, and writes its manifest (``extra``: more top-level entries, e.g. the pipeline run
    it came from)."""
    folder = Path(folder)
    manifest = {"format": FORMAT, "version": VERSION, "chain": chain, "commit": commit, "stages": {},
                "feasibility": {}, **(extra or {})}
    for stage in stages:
        state = load_checkpoint(stage.checkpoint, map_location="cpu")
        target = folder / "stages" / stage.task / "best.pt"
        save_checkpoint(target, inference_checkpoint(state))
        manifest["stages"][stage.task] = {
            "file": str(target.relative_to(folder)), "sha256": _sha256(target), "obs_spec": state.get("obs_spec"),
            "preset": stage.preset, "residual": stage.residual,
            "task_config": config_dict(_stage_config(stage.task, stage.preset, stage.residual)),
            "env_steps": int(state["counters"]["global_step"]), "wall_clock_s": float(stage.wall_clock_s),
            "core_hours": float(stage.wall_clock_s) * stage.cores / 3600.0}
    for task, path in (feasibility or {}).items():
        target = folder / "feasibility" / f"{task}.pt"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, target)
        manifest["feasibility"][task] = {"file": str(target.relative_to(folder)), "sha256": _sha256(target)}
    return atomic_write(folder / MANIFEST, lambda file: file.write((json.dumps(manifest, indent=2) + "\n").encode()))


def _checked_file(folder: Path, entry: dict, what: str) -> Path:
    path = folder / entry["file"]
    if not path.is_file():
        raise ShippedChainError(f"{path} is missing ({what}; listed in {folder / MANIFEST}); restore the folder")
    if _sha256(path) != entry["sha256"]:
        raise ShippedChainError(f"{path} does not match its hash in {folder / MANIFEST} ({what}): the file is "
                                f"truncated or was replaced; restore it")
    return path


def _learned_stages_of(shipped_chain, tasks: list[str]) -> bool:
    """Whether ``shipped_chain`` (a manifest's chain name) is the chain of ``tasks``' learned stages, the scripted
    ones left out (``building_blocks_policies`` for ``building_blocks``: the pipeline trains learned stages only)."""
    try:
        stages = LoadChain(str(shipped_chain)).stages
    except ValueError:
        return False
    return stages == [task for task in tasks if not is_scripted(task)]


def load_shipped_chain(folder: str | Path, chain: str, tasks: list[str], observation_sizes: dict[str, int]
                       ) -> ShippedChain:
    """Checks the shipped folder for ``chain`` (stages ``tasks``; ``observation_sizes`` per task) and returns its
    files and stage configs. A stage the manifest does not list runs untrained (``missing``)."""
    folder = Path(folder)
    path = folder / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError as error:
        raise ShippedChainError(f"{path} is missing: {folder} is not a shipped checkpoint folder") from error
    except (OSError, ValueError) as error:
        raise ShippedChainError(f"{path} cannot be read as JSON ({error}); restore it") from error
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise ShippedChainError(f"{path} is not a shipped-chain manifest")
    if manifest.get("version") != VERSION:
        raise ShippedChainError(f"{path} has version {manifest.get('version')}; this code reads version {VERSION}: "
                                f"use the code of commit {manifest.get('commit') or '(unknown)'} or re-ship")
    if manifest.get("chain") != chain and not _learned_stages_of(manifest.get("chain"), tasks):
        raise ShippedChainError(f"{path} holds the {manifest.get('chain')!r} chain, not {chain!r}")
    unknown = sorted(set(manifest["stages"]) - set(tasks))
    if unknown:
        raise ShippedChainError(f"{path} lists stages {unknown} that the {chain} chain ({', '.join(tasks)}) lacks")
    policies, configs, feasibility = [], [], []
    for task in tasks:
        entry = manifest["stages"].get(task)
        if entry is not None and is_scripted(task):
            raise ShippedChainError(f"{path} lists a policy for the {task} stage, which is scripted (its base acts "
                                    f"alone); remove the entry")
        if entry is None:
            policies.append(None)
            configs.append(default_config(task))
            continue
        file = _checked_file(folder, entry, f"the {task} policy")
        config = _stage_config(task, entry["preset"], bool(entry.get("residual", True)))
        expected = observation_spec(task, observation_sizes[task] + (1 if config.observe_time else 0)).to_dict()
        try:
            recorded = load_checkpoint(file, map_location="cpu").get("obs_spec")
        except CheckpointError as error:
            raise ShippedChainError(f"{file}: {error}") from error
        for where, spec in (("the manifest", entry.get("obs_spec")), ("the checkpoint", recorded)):
            if spec != expected:
                raise ShippedChainError(f"{file}: {where} records the observation spec {spec}, the {task} stage "
                                        f"reads {expected}: another task's policy or another observation layout")
        if not same_task_config(config_dict(config), entry["task_config"]):
            raise ShippedChainError(f"{file} was trained with a {task} task config (preset {entry['preset']}) that "
                                    f"differs from this code's; use the code of commit {manifest.get('commit')}")
        policies.append(file)
        configs.append(config)
    for i, task in enumerate(tasks):
        entry = manifest["feasibility"].get(task)
        feasibility.append(None if entry is None or i == 0 else _checked_file(folder, entry, f"F of {task}"))
    return ShippedChain(folder, list(tasks), policies, feasibility, configs, manifest)
