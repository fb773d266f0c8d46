"""The ``seqdex`` command line (``seqdex train``, ``seqdex collect``) and what its subcommands share.

``main`` parses the arguments and dispatches; ``train`` and ``collect`` implement the subcommands. This module
holds the shared pieces: :class:`CliError` (a user-facing failure: message, exit code, no traceback), the
sub-task chains, the task config a run uses (shortened episodes with ``--test``) and the observation spec
recorded in terminal buffers.

Exit codes: 0 success; 2 bad input (unknown task, missing or mismatched file, wrong flag combination);
1 a failure while running (e.g. a simulator worker died).
"""

import dataclasses
import json

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


def task_config(task: str, test: bool):
    """The :class:`~seqdex_drake.tasks.base.TaskConfig` of a run: the task's default, with episodes cut to
    :data:`TEST_EPISODE_LENGTH` steps under ``--test``."""
    from seqdex_drake.tasks.registry import default_config

    config = default_config(task)
    if test:
        config = dataclasses.replace(config, episode_length=min(config.episode_length, TEST_EPISODE_LENGTH))
    return config


def config_dict(config) -> dict:
    """A dataclass (nested ones included) as JSON-ready plain data (tuples become lists, numpy via ``tolist``)."""
    return json.loads(json.dumps(dataclasses.asdict(config), default=_plain))


def _plain(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
