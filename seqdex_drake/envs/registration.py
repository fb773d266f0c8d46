"""Gymnasium ids for the sub-task envs: ``gym.make("seqdex/Grasp-v0")`` after ``import seqdex_drake``.

Every sub-task of :mod:`seqdex_drake.tasks.registry` gets the id ``seqdex/<CamelCaseName>-v0``
(:data:`GYM_IDS`): ``seqdex/Search-v0``, ``Retrieve`` (scripted: its base acts, the action corrects it),
``Orient``, ``Grasp``, ``Insert``, ``ToolGrasp``, ``ToolReorient`` and the hand-over chain's ``Reach`` and
``Lower``. Registration is lazy (an entry point string): nothing is built until ``gym.make``.

The spec's ``max_episode_steps`` is the task's default ``episode_length``; the env also truncates itself at its
config's ``episode_length``, and :class:`~seqdex_drake.envs.wrappers.EpisodeLengthSync` (the spec's additional
wrapper) keeps the two equal. Keywords of ``gym.make`` (see :func:`make_subtask_env`)::

    gym.make("seqdex/Grasp-v0")                                   # default config, 150-step episodes
    gym.make("seqdex/Grasp-v0", max_episode_steps=50)             # 50-step episodes (env and TimeLimit)
    gym.make("seqdex/Grasp-v0", ema=0.5, object_types=[6, 7, 8])  # TaskConfig fields override the default
    gym.make("seqdex/Grasp-v0", config=my_config, max_episode_steps=my_config.episode_length)
    gym.make("seqdex/ToolGrasp-v0", preset="budget")             # the variant seqdex train --preset budget uses

Every task with a small-budget variant (``seqdex train --preset budget``) also gets ``seqdex/<Name>Budget-v0``
(:data:`BUDGET_GYM_IDS`): the budget config, with the action space reduced to the dims its policy sends (a
residual on a scripted base pins the hand's 16 dims: ``low == high`` there), by
:class:`~seqdex_drake.envs.wrappers.FreeActionsWrapper`::

    gym.make("seqdex/GraspBudget-v0")                             # Box(3,): the wrist residual

Wrist-only tasks (reach, lower) have 16 fixed action dims (``low == high``); wrap with
:class:`~seqdex_drake.envs.wrappers.FreeActionsWrapper` to expose only the free ones.
"""

import dataclasses

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from seqdex_drake.envs.wrappers import FreeActionsWrapper
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import REGISTRY, budget_config, default_config
from seqdex_drake.tasks.run_config import PRESETS  # The task variants of the ``preset`` keyword.

#: The id prefix of every sub-task env.
NAMESPACE = "seqdex"
#: The version suffix of the ids (bump it when an env's observation, action or reward changes meaning).
VERSION = 0
_ENTRY_POINT = "seqdex_drake.envs.registration:make_subtask_env"
_BUDGET_ENTRY_POINT = "seqdex_drake.envs.registration:make_budget_env"
#: The budget ids' own wrapper (their entry point applies it: the env checker then sees the reduced space).
_FREE = WrapperSpec(name="FreeActionsWrapper", entry_point="seqdex_drake.envs.wrappers:FreeActionsWrapper", kwargs={})
_SYNC = WrapperSpec(name="EpisodeLengthSync", entry_point="seqdex_drake.envs.wrappers:EpisodeLengthSync", kwargs={})


def gym_id(task: str) -> str:
    """The gymnasium id of sub-task ``task``, e.g. ``"tool_grasp"`` -> ``"seqdex/ToolGrasp-v0"``."""
    if task not in REGISTRY:
        raise ValueError(f"unknown task '{task}'; valid tasks: {', '.join(REGISTRY)}")
    return f"{NAMESPACE}/{''.join(part.capitalize() for part in task.split('_'))}-v{VERSION}"


#: Sub-task name -> gymnasium id, for every registered sub-task.
GYM_IDS = {task: gym_id(task) for task in REGISTRY}
#: Sub-task name -> gymnasium id of its small-budget variant, for every sub-task that has one.
BUDGET_GYM_IDS = {task: gym_id(task).replace(f"-v{VERSION}", f"Budget-v{VERSION}") for task in REGISTRY
                  if budget_config(task) != default_config(task)}


def make_subtask_env(task: str, config=None, preset: str | None = None, meshcat=None, **overrides):
    """The entry point of the ``seqdex/*`` ids: a :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`.

    Args:
        task: the sub-task (set by the id's registered kwargs).
        config: a :class:`~seqdex_drake.tasks.base.TaskConfig` for this task (default: its ``default_config()``).
            Its ``episode_length`` must equal ``gym.make``'s ``max_episode_steps``.
        preset: instead of ``config``, the task variant ``seqdex train --preset`` trains on: ``"paper"`` (the
            default config) or ``"budget"`` (the small-budget variant where the task has one).
        meshcat: optional Meshcat to visualize the station in.
        overrides: :class:`~seqdex_drake.tasks.base.TaskConfig` fields replacing those of ``config`` (e.g.
            ``ema=0.5``, ``randomization=RandomizationConfig.paper()``).

    Raises:
        ValueError: ``config`` is not a TaskConfig of ``task``, both ``config`` and ``preset`` are given, the
            preset is unknown, or an override names no TaskConfig field.
    """
    # Start-up time: ``import seqdex_drake`` registers the ids without loading the env's systems.
    from seqdex_drake.envs.subtask_env import make_env

    if preset is not None:
        if config is not None:
            raise ValueError(f"gym.make('{gym_id(task)}') takes config= or preset=, not both")
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
        config = budget_config(task) if preset == "budget" else default_config(task)
    if config is None:
        config = default_config(task)
    elif not isinstance(config, TaskConfig):
        raise ValueError(f"config must be a TaskConfig (seqdex_drake.tasks.registry.default_config('{task}') "
                         f"and dataclasses.replace), got {type(config).__name__}")
    elif config.name != task:
        raise ValueError(f"the config is for sub-task {config.name!r}, not {task!r}; pass one made from "
                         f"seqdex_drake.tasks.registry.default_config('{task}') or make the other task's id")
    fields = {field.name for field in dataclasses.fields(TaskConfig)} - {"name"}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"unknown keyword(s) {unknown} for gym.make('{gym_id(task)}'): pass config=, preset=, "
                         f"meshcat= or TaskConfig fields ({', '.join(sorted(fields))})")
    # Always a copy: EpisodeLengthSync may set the copy's episode length, and the caller's config stays theirs.
    return make_env(task, dataclasses.replace(config, **overrides), meshcat=meshcat)


def make_budget_env(task: str, meshcat=None, **overrides):
    """The entry point of the ``seqdex/*Budget-v0`` ids: sub-task ``task``'s small-budget variant (``overrides``:
    TaskConfig fields, as for :func:`make_subtask_env`) with only the action dims its policy sends
    (:class:`~seqdex_drake.envs.wrappers.FreeActionsWrapper`)."""
    if task not in BUDGET_GYM_IDS:
        raise ValueError(f"sub-task {task!r} has no small-budget variant; its id is {gym_id(task)}")
    return FreeActionsWrapper(make_subtask_env(task, preset="budget", meshcat=meshcat, **overrides))


def register_envs() -> list[str]:
    """Registers every sub-task's id and every budget variant's with gymnasium (ids already registered are left
    alone); returns the ids."""
    for task, env_id in GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=_ENTRY_POINT, max_episode_steps=default_config(task).episode_length,
                         kwargs={"task": task}, additional_wrappers=(_SYNC,))
    for task, env_id in BUDGET_GYM_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=_BUDGET_ENTRY_POINT,
                         max_episode_steps=budget_config(task).episode_length, kwargs={"task": task},
                         additional_wrappers=(_FREE, _SYNC))
    return [*GYM_IDS.values(), *BUDGET_GYM_IDS.values()]
