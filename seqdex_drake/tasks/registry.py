"""The sub-task registry: names to modules; creation, scripts and tests are driven from here."""

import sys

from seqdex_drake.tasks import grasp, insert, lower, orient, reach, search, tool_grasp, tool_reorient
from seqdex_drake.tasks.base import Task, TaskConfig

#: name -> (default_config, Task class)
REGISTRY = {
    "search": (search.default_config, search.SearchTask),
    "orient": (orient.default_config, orient.OrientTask),
    "grasp": (grasp.default_config, grasp.GraspTask),
    "insert": (insert.default_config, insert.InsertTask),
    "tool_grasp": (tool_grasp.default_config, tool_grasp.ToolGraspTask),
    "tool_reorient": (tool_reorient.default_config, tool_reorient.ToolReorientTask),
    # The hand-over chain: a cheap two-stage chain for method comparisons (tasks/handover_common.py).
    "reach": (reach.default_config, reach.ReachTask),
    "lower": (lower.default_config, lower.LowerTask),
}


#: The paper's six sub-tasks (Building Blocks and Tool Positioning); the others serve the hand-over chain.
PAPER_TASKS = ("search", "orient", "grasp", "insert", "tool_grasp", "tool_reorient")


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


def make_env(name: str, config: TaskConfig | None = None, meshcat=None):
    """A :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` for sub-task ``name``."""
    from seqdex_drake.envs.subtask_env import SubtaskEnv

    return SubtaskEnv(make_task(name, config), meshcat=meshcat)


#: The observation layout of the paper's tables (``seqdex_drake.observation_layout``), for observation specs.
_BASE_LAYOUT = ("joint_q(23) joint_dq(23) fingertips(4x13) palm(13) object(13) previous_action(19) "
                "motor_torque(16)")


def observation_spec(name: str, dim: int):
    """The :class:`~seqdex_drake.chaining.spec.ObservationSpec` of sub-task ``name``'s observations of size
    ``dim`` (goal and pixel parts as the paper's table has), recorded in buffers, F files and checkpoints."""
    from seqdex_drake.chaining.spec import ObservationSpec
    from seqdex_drake.observation_layout import BASE_SIZE, GOAL_SIZE

    task_class = REGISTRY[name][1]
    extras = (" goal(14)" if task_class.goal else "") + (" target_pixels(1)" if task_class.pixels else "")
    paper_size = BASE_SIZE + (GOAL_SIZE if task_class.goal else 0) + (1 if task_class.pixels else 0)
    if dim == paper_size + 1:  # TaskConfig.observe_time: the episode's progress appended.
        extras += " progress(1)"
    return ObservationSpec(dim, f"{name}: {_BASE_LAYOUT}{extras}")
