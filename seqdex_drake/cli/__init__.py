"""The ``seqdex`` command line (``seqdex train``, ``seqdex collect``) and what its subcommands share.

``main`` parses the arguments and dispatches; ``train`` and ``collect`` implement the subcommands. This module
holds the pieces the subcommands share: :class:`CliError` (:class:`~seqdex_drake.user_input.InputError`, a
user-facing failure: message, exit code, no traceback), the sub-task chains and ``--objects``. The task config a
run uses lives in the library (:mod:`seqdex_drake.tasks.run_config`); this package only parses and dispatches.

Exit codes: 0 success; 2 bad input (unknown task, missing or mismatched file, wrong flag combination, a number
out of range, an output path that cannot be written, a run directory in use); 1 a failure while running (e.g. a
simulator worker died); 128 + N a training stopped by signal N after saving its checkpoint (130 Ctrl-C, 143
SIGTERM).
"""

import dataclasses

from seqdex_drake.chaining.chain import ChainNames, LoadChain
from seqdex_drake.tasks import run_config
from seqdex_drake.tasks.residual import BASE_TASKS, RESIDUAL_BASES
from seqdex_drake.user_input import MAX_SEED, check_creatable, check_seed  # noqa: F401 (the subcommands' checks)
from seqdex_drake.user_input import InputError as CliError


def _chain_links() -> list[tuple[str, str]]:
    """Every (stage, next stage) pair of the chains in ``diagrams/chains.yaml``, in file order, without repeats."""
    links = []
    for name in ChainNames():
        stages = LoadChain(name).stages
        links += [link for link in zip(stages, stages[1:], strict=False) if link not in links]
    return links


#: The sub-tasks that follow each one in the chains of ``diagrams/chains.yaml`` (Building Blocks: search ->
#: retrieve -> orient -> grasp -> insert, and its learned stages search -> orient; Tool Positioning: tool_grasp ->
#: tool_reorient; the hand-over chain: reach -> lower), first chain first. The last task of a chain has none.
NEXT_TASKS: dict[str, list[str]] = {}
#: The sub-tasks that precede each one (the inverse of :data:`NEXT_TASKS`): a terminal buffer from any of them
#: can start it.
PREVIOUS_TASKS: dict[str, list[str]] = {}
for _source, _target in _chain_links():
    NEXT_TASKS.setdefault(_source, []).append(_target)
    PREVIOUS_TASKS.setdefault(_target, []).append(_source)
#: The sub-task whose episodes ``seqdex collect`` collects a task's terminal states for: the first of its
#: :data:`NEXT_TASKS` (Search: the retrieve of the Building Blocks chain).
NEXT_TASK = {source: targets[0] for source, targets in NEXT_TASKS.items()}

#: ``--objects``' help (``seqdex rollout``, ``seqdex collect``).
#: ``--trigger``'s help (``seqdex evaluate``, ``seqdex simulate``): ``SwitcherParams.trigger``'s values.
TRIGGER_HELP = ("when the switcher scores the next stages between decisions: next (c^{i+1} every tick, the paper's), "
                "any_later, or decision (only at a stage's end); default: the task's "
                "(evaluation/chain_settings.SWITCH_TRIGGER)")
OBJECTS_HELP = ("draw the reset's object from these only: block types 1 .. 8 (6-8 unseen in training), or tools "
                "hammer, spatula, spoon (default: the task's, the trained ones)")


def with_objects(config, task: str, objects: list[str] | None, starts=None):
    """``config`` drawing its reset's object from ``objects`` (``--objects``; as-is without it): :class:`CliError`
    for unknown names, a task without objects to choose, or hand-offs ``starts`` (which fix the object)."""
    if objects is not None and starts is not None:
        raise CliError("--objects draws the reset's object; with --initial-states each hand-off fixes it")
    try:
        return run_config.with_objects(config, task, objects)
    except ValueError as error:
        raise CliError(f"--objects: {error}") from error


def with_base(config, task: str, base: str | None):
    """``config`` (sub-task ``task``'s) with residual base ``base`` (its hand actions too: a base sends whole
    actions), checked by name and task; ``config`` itself for None."""
    if base is None:
        return config
    if base not in RESIDUAL_BASES:
        raise CliError(f"--base {base!r}: unknown residual base; valid bases: {', '.join(RESIDUAL_BASES)}")
    if BASE_TASKS[base] != task:
        fitting = [name for name, owner in BASE_TASKS.items() if owner == task]
        raise CliError(f"--base {base} acts in the {BASE_TASKS[base]} env, not {task}'s; bases for {task}: "
                       f"{', '.join(fitting) or 'none'}")
    return dataclasses.replace(config, residual=base, hand_actions=False)
