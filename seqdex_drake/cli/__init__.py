"""The ``seqdex`` command line (``seqdex train``, ``seqdex collect``) and what its subcommands share.

``main`` parses the arguments and dispatches; ``train`` and ``collect`` implement the subcommands. This module
holds the shared pieces: :class:`CliError` (a user-facing failure: message, exit code, no traceback), the
sub-task chains, the task config a run uses (shortened episodes with ``--test``) and the observation spec
recorded in terminal buffers.

Exit codes: 0 success; 2 bad input (unknown task, missing or mismatched file, wrong flag combination, a number
out of range, an output path that cannot be written, a run directory in use); 1 a failure while running (e.g. a
simulator worker died); 128 + N a training stopped by signal N after saving its checkpoint (130 Ctrl-C, 143
SIGTERM).
"""

import dataclasses
import json
import os
import tempfile
from pathlib import Path

from seqdex_drake.tasks.registry import observation_spec  # noqa: F401 (re-exported for the subcommands)


def _chain_links() -> dict[str, str]:
    from seqdex_drake.chaining.chain import ChainNames, LoadChain

    links = {}
    for name in ChainNames():
        stages = LoadChain(name).stages
        links.update(zip(stages, stages[1:], strict=False))
    return links


#: The sub-task that follows each one in its chain of ``diagrams/chains.yaml`` (Building Blocks: search ->
#: orient -> grasp -> insert; Tool Positioning: tool_grasp -> tool_reorient; the hand-over chain: reach ->
#: lower). The last task of a chain has no entry.
NEXT_TASK = _chain_links()
#: The sub-task that precedes each one (the inverse of :data:`NEXT_TASK`).
PREVIOUS_TASK = {target: source for source, target in NEXT_TASK.items()}

#: Episode length of every sub-task under ``--test`` (a few seconds of simulation per run).
TEST_EPISODE_LENGTH = 6


class CliError(Exception):
    """A failure the user can fix: printed as ``seqdex <command>: error: <message>``, exit ``code``."""

    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = code


#: Seeds are used as numpy seeds (``seed + env index``, ``seed + step``): non-negative, within 32 bits.
MAX_SEED = 2**32 - 1


def check_seed(seed: int, flag: str = "--seed") -> None:
    """Raises :class:`CliError` unless ``0 <= seed <= MAX_SEED``."""
    if not 0 <= seed <= MAX_SEED:
        raise CliError(f"{flag} must be in 0 .. {MAX_SEED}, got {seed}")


def check_creatable(path: str | os.PathLike, flag: str, directory: bool = False) -> None:
    """Raises :class:`CliError` unless a file (``directory``: a directory) can be written at ``path``.

    Checked up front and creating nothing: an existing ``path`` must be of the right kind, the nearest existing
    ancestor must be a directory (not a file), and a temporary file must be creatable in it (a real test, so
    read-only file systems and permissions count, also for root). Files are written atomically (a temporary file
    next to them, then a rename), so a file's directory must be writable, not the file itself.
    """
    path = nearest = Path(path)
    try:
        if path.is_dir() and not directory:
            raise CliError(f"{flag} {path} is a directory; name a file")
        if path.exists() and directory and not path.is_dir():
            raise CliError(f"{flag} {path} is a file, not a directory; pick another {flag}")
        nearest = path if directory and path.is_dir() else path.parent
        while not nearest.exists() and nearest != nearest.parent:
            nearest = nearest.parent
        if not nearest.is_dir():
            raise CliError(f"{flag} {path}: {nearest} is a file, not a directory; pick another {flag}")
        with tempfile.TemporaryFile(dir=nearest):
            pass
    except OSError as error:
        raise CliError(f"{flag} {path}: cannot write in {nearest} ({error.strerror or error}); pick a writable "
                       f"{flag}") from error


def task_config(task: str, test: bool, preset: str = "paper", residual: bool = True):
    """The :class:`~seqdex_drake.tasks.base.TaskConfig` of a run: the task's default (``preset="budget"``: its
    small-budget variant where it has one), with episodes cut to :data:`TEST_EPISODE_LENGTH` steps under
    ``--test``. ``residual=False`` drops the variant's residual base (``TaskConfig.residual``) and gives the
    policy the whole action space back: a policy that sends whole actions, as demonstrations hold them
    (``seqdex train --demos``, ``scripts/collect_demos.py``)."""
    from seqdex_drake.tasks.registry import budget_config, default_config

    config = budget_config(task) if preset == "budget" else default_config(task)
    if not residual and config.residual:
        config = dataclasses.replace(config, residual="", hand_actions=True)
    if test:
        config = dataclasses.replace(config, episode_length=min(config.episode_length, TEST_EPISODE_LENGTH))
    return config


def config_dict(config) -> dict:
    """A dataclass (nested ones included) as JSON-ready plain data (tuples become lists, numpy via ``tolist``)."""
    return json.loads(json.dumps(dataclasses.asdict(config), default=_plain))


def same_task_config(current: dict, recorded: dict) -> bool:
    """Whether a recorded task config (``config_dict`` of a ``TaskConfig``, in a run record or a manifest) is
    ``current``: equal field by field, where a field the record lacks (one added to ``TaskConfig`` since it was
    written) counts as equal only if ``current`` leaves it at its default."""
    from seqdex_drake.tasks.base import TaskConfig

    if set(recorded) - set(current):
        return False
    defaults = config_dict(TaskConfig())
    return all(current[key] == (recorded[key] if key in recorded else defaults.get(key)) for key in current)


def _plain(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


#: ``--objects``' help (``seqdex rollout``, ``seqdex collect``).
OBJECTS_HELP = ("draw the reset's object from these only: block types 1 .. 8 (6-8 unseen in training), or tools "
                "hammer, spatula, spoon (default: the task's, the trained ones)")


def with_objects(config, task: str, objects: list[str] | None, starts=None):
    """``config`` drawing its reset's object from ``objects`` (``--objects``; as-is without it); :class:`CliError`
    for unknown names, a task without objects to choose, or hand-offs ``starts`` (which fix the object)."""
    if objects is None:
        return config
    from seqdex_drake.modeling.catalog import object_keys

    if starts is not None:
        raise CliError("--objects draws the reset's object; with --initial-states each hand-off fixes it")
    family = config.scenario.split("/")[0]
    if family not in ("building_blocks", "tool_positioning"):
        raise CliError(f"--objects: the {task} task has one object, nothing to choose")
    try:
        keys = object_keys(family, objects)
    except ValueError as error:
        raise CliError(f"--objects: {error}") from error
    return dataclasses.replace(config, object_types=[int(key) for key in keys])
