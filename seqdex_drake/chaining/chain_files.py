"""A chain run's files on disk: per stage its policy checkpoint and the feasibility function scoring the hand-off
into it (the layout ``seqdex pipeline`` writes and ``seqdex ship`` copies into ``checkpoints/<family>/``).

:func:`LoadChainCheckpoints` finds them for
:func:`~seqdex_drake.controller.chain_controller.MakeChainController` (it only looks for files: it needs neither torch
nor Drake); :func:`run_dir_configs` gives each stage's task config as its checkpoint was trained, and
:func:`observation_sizes` each task's observation size, which a shipped chain's files are checked against.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from pathlib import Path

from seqdex_drake.observation_layout import BASE_SIZE, GOAL_SIZE
from seqdex_drake.tasks.registry import REGISTRY
from seqdex_drake.tasks.run_config import PRESETS, run_preset, run_residual, task_config


@dataclasses.dataclass
class ChainCheckpoints:
    """What :func:`LoadChainCheckpoints` found; pass ``stages`` and ``feasibility`` to
    :func:`~seqdex_drake.controller.chain_controller.MakeChainController`."""

    tasks: list[str]
    """The chain's tasks, in order."""
    policies: list[Path | None]
    """Per stage, the policy checkpoint (``best.pt``, else ``last.pt``), or None (untrained, or a scripted stage:
    ``Task.scripted``, which has none)."""
    feasibility: list[Path | None]
    """Per stage, its feasibility file, or None (stage 0 never has one)."""
    missing: list[str]
    """One human-readable line per missing file (print them)."""

    @property
    def stages(self) -> list[tuple[str, Path | None]]:
        return list(zip(self.tasks, self.policies, strict=True))


def LoadChainCheckpoints(run_dir: str | os.PathLike, tasks: Sequence[str]) -> ChainCheckpoints:
    """Finds a chain run's files: ``<run_dir>/stages/<task>/best.pt`` (else ``last.pt``) per stage and
    ``<run_dir>/feasibility/<task>.pt`` (the F predicting ``<task>``'s return from the previous stage's
    history) for every stage after the first. Missing files are listed in ``missing``, not raised.

    Raises:
        FileNotFoundError: ``run_dir`` is not a directory.
        ValueError: an unknown task name (the message lists the registered ones) or an empty chain.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"chain run directory {run_dir} does not exist")
    tasks = [check_chain_task(task) for task in tasks]
    if not tasks:
        raise ValueError("a chain needs at least one task")
    policies, feasibility, missing = [], [], []
    for i, task in enumerate(tasks):
        candidates = [run_dir / "stages" / task / name for name in ("best.pt", "last.pt")]
        scripted = REGISTRY[task][1].scripted  # Its base acts alone: no checkpoint to find.
        found = None if scripted else next((path for path in candidates if path.is_file()), None)
        policies.append(found)
        if found is None and not scripted:
            missing.append(f"stage {i} ({task}): no policy checkpoint {candidates[0]} or {candidates[1].name}; "
                           f"the stage runs an untrained policy")
        path = run_dir / "feasibility" / f"{task}.pt"
        feasibility.append(path if i > 0 and path.is_file() else None)
        if i > 0 and not path.is_file():
            missing.append(f"stage {i} ({task}): no feasibility function {path}; switching into it follows the "
                           f"sequential rule (step budget / stage_success)")
    return ChainCheckpoints(tasks, policies, feasibility, missing)


def check_chain_task(task: str) -> str:
    """``task`` if it is a registered sub-task; ValueError listing the registered ones otherwise."""
    if task not in REGISTRY:
        raise ValueError(f"unknown task {task!r} in the chain; registered tasks: {', '.join(REGISTRY)}")
    return task


def observation_sizes() -> dict[str, int]:
    """Each registered task's observation size (the base layout plus its goal or pixel part)."""
    return {name: BASE_SIZE + (GOAL_SIZE if task.goal else 0) + (1 if task.pixels else 0)
            for name, (_, task) in REGISTRY.items()}


def run_dir_configs(run_dir: Path, tasks: list[str], checkpoints: list) -> list:
    """Each stage's task config as its checkpoint was trained (a policy trained on a budget variant runs with its
    scripted phases, progress input and residual base): the preset recorded by ``seqdex train`` in the
    ``config.json`` beside the checkpoint (a linked checkpoint: beside the file it links to), else the preset of
    the chain run's ``pipeline.json``, else the paper's; untrained stages take their preset the same way."""
    try:
        chain_preset = json.loads((run_dir / "pipeline.json").read_text())["config"]["preset"]
    except (OSError, ValueError, KeyError, TypeError):
        chain_preset = "paper"
    configs = []
    for task, checkpoint in zip(tasks, checkpoints, strict=True):
        trained = Path(checkpoint).resolve() if checkpoint is not None else None
        if trained is not None and (trained.parent / "config.json").is_file():
            configs.append(task_config(task, False, run_preset(trained), residual=run_residual(trained)))
        else:
            configs.append(task_config(task, False, chain_preset if chain_preset in PRESETS else "paper"))
    return configs
