"""Chains: named, ordered lists of registered sub-tasks, loaded from typed YAML (``diagrams/chains.yaml``).

Nothing here knows about blocks or tools: a chain is data, and the stage names are checked against the task
registry only when a caller passes the valid names (``LoadChain(..., valid_tasks=task_names())``).
"""

import dataclasses
from pathlib import Path

from pydrake.common.yaml import yaml_load_typed

#: The chains shipped with the repository.
DEFAULT_CHAINS_FILE = Path(__file__).resolve().parents[2] / "diagrams" / "chains.yaml"


class ChainError(ValueError):
    """A chain that cannot be used: unknown name, unknown stage, too short; the message names the fix."""


@dataclasses.dataclass
class ChainSpec:
    """One chain of sub-tasks."""

    stages: list[str] = dataclasses.field(default_factory=list)
    """Registered sub-task names, first to last (K >= 2)."""
    name: str = ""
    """The chain's name in its file (filled in by :func:`LoadChain`)."""

    def index(self, task: str) -> int:
        if task not in self.stages:
            raise ChainError(f"{task} is not a stage of chain {self.name!r} ({' -> '.join(self.stages)})")
        return self.stages.index(task)

    def next_task(self, task: str) -> str | None:
        """The stage after ``task`` (None for the last one)."""
        i = self.index(task)
        return self.stages[i + 1] if i + 1 < len(self.stages) else None

    def previous_task(self, task: str) -> str | None:
        """The stage before ``task`` (None for the first one)."""
        i = self.index(task)
        return self.stages[i - 1] if i > 0 else None


@dataclasses.dataclass
class _ChainFile:
    chains: dict[str, ChainSpec] = dataclasses.field(default_factory=dict)


def _read(filename: Path) -> dict[str, ChainSpec]:
    if not Path(filename).is_file():
        raise ChainError(f"chain file {filename} does not exist")
    text = "chains:\n" + "".join(f"  {line}\n" for line in Path(filename).read_text().splitlines())
    try:
        return yaml_load_typed(schema=_ChainFile, data=text).chains
    except RuntimeError as error:  # Drake's typed YAML reports unknown keys and bad types this way.
        raise ChainError(f"{filename}: {error}") from error


def ChainNames(filename: str | Path | None = None) -> list[str]:
    """The chain names defined in ``filename`` (default: ``diagrams/chains.yaml``)."""
    return list(_read(Path(filename or DEFAULT_CHAINS_FILE)))


def LoadChain(name: str, filename: str | Path | None = None, valid_tasks: list[str] | None = None) -> ChainSpec:
    """Loads chain ``name`` from ``filename`` (default: ``diagrams/chains.yaml``).

    Args:
        name: the chain's key in the file.
        filename: a YAML file mapping chain names to ``{stages: [...]}``.
        valid_tasks: if given, every stage must be one of these (e.g. the task registry's names).

    Raises:
        ChainError: unknown chain (the message lists the valid ones), unknown stage, repeated stage, or fewer
            than two stages.
    """
    filename = Path(filename or DEFAULT_CHAINS_FILE)
    chains = _read(filename)
    if name not in chains:
        raise ChainError(f"unknown chain {name!r}; chains in {filename.name}: {', '.join(chains)}")
    spec = dataclasses.replace(chains[name], name=name)
    if len(spec.stages) < 2:
        raise ChainError(f"chain {name!r} has {len(spec.stages)} stage(s); a chain needs at least two")
    if len(set(spec.stages)) != len(spec.stages):
        raise ChainError(f"chain {name!r} repeats a stage ({' -> '.join(spec.stages)}); stages must be distinct")
    if valid_tasks is not None:
        unknown = [stage for stage in spec.stages if stage not in valid_tasks]
        if unknown:
            raise ChainError(f"chain {name!r} has unknown stage(s) {', '.join(unknown)}; valid sub-tasks: "
                             f"{', '.join(valid_tasks)}")
    return spec
