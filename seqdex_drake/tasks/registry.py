"""The sub-task registry: names to modules; creation, scripts and tests are driven from here."""

import sys

from seqdex_drake.tasks import (
    grasp,
    insert,
    lower,
    orient,
    reach,
    retrieve,
    search,
    tool_grasp,
    tool_reorient,
    tools_common,
)
from seqdex_drake.tasks.base import Task, TaskConfig

#: name -> (default_config, Task class)
REGISTRY = {
    "search": (search.default_config, search.SearchTask),
    # Scripted (Task.scripted): takes the block Search uncovered out of the pile (tasks/retrieve.py).
    "retrieve": (retrieve.default_config, retrieve.RetrieveTask),
    "orient": (orient.default_config, orient.OrientTask),
    "grasp": (grasp.default_config, grasp.GraspTask),
    "insert": (insert.default_config, insert.InsertTask),
    "tool_grasp": (tool_grasp.default_config, tool_grasp.ToolGraspTask),
    "tool_reorient": (tool_reorient.default_config, tool_reorient.ToolReorientTask),
    # The hand-over chain: a cheap two-stage chain for method comparisons (tasks/handover_common.py).
    "reach": (reach.default_config, reach.ReachTask),
    "lower": (lower.default_config, lower.LowerTask),
}

#: Sub-task -> how the object it holds at its end is knocked out of the hand (its F's knocked-out transitions,
#: ``seqdex feasibility --knocked-out``); the others have none.
KNOCK_OUTS = {"tool_grasp": tools_common.knock_out_tool}


#: The paper's six sub-tasks (Building Blocks and Tool Positioning); the others serve the hand-over chain.
PAPER_TASKS = ("search", "orient", "grasp", "insert", "tool_grasp", "tool_reorient")


def is_scripted(name: str) -> bool:
    """Whether sub-task ``name`` is a scripted stage (``Task.scripted``: nothing to train, no checkpoint)."""
    default_config(name)  # Validates the name.
    return bool(REGISTRY[name][1].scripted)


def task_names() -> list[str]:
    return list(REGISTRY)


def default_config(name: str) -> TaskConfig:
    """The default config of sub-task ``name``; unknown names raise a ValueError listing the valid ones."""
    if name not in REGISTRY:
        raise ValueError(f"unknown task '{name}'; valid tasks: {', '.join(REGISTRY)}")
    return REGISTRY[name][0]()


def budget_config(name: str) -> TaskConfig:
    """The small-budget variant of sub-task ``name`` (its module's ``budget_config()``: the release's scripted
    phases, shaping terms), or its default config where it has none."""
    config = default_config(name)  # Validates the name.
    budget = getattr(sys.modules[REGISTRY[name][0].__module__], "budget_config", None)
    return budget() if budget is not None else config


def make_task(name: str, config: TaskConfig | None = None) -> Task:
    """Creates the task ``name`` with ``config`` (default: its default_config())."""
    config = default_config(name) if config is None else config
    return REGISTRY[name][1](config)
