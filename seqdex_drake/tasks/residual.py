"""Residual policies: a learned correction added to a scripted base controller (``../shared/TRAINING.md``).

Residual policy learning (Silver et al. 2018; Johannink et al. 2019) lets PPO start from what a script already
does: the applied action is ``clip(base(observation, step) + policy action, -1, 1)``, and the policy, whose last
layer starts near zero, only learns the correction. A sub-task opts in with ``TaskConfig.residual`` naming a
base from :data:`RESIDUAL_BASES`; the env (:class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`) adds the base to
every action it is given, and a deployed policy system
(``PolicySystem`` in ``controller/policy.py``, ``PolicyParams.residual``) adds it on its own tick count,
so training and the chain apply the same sum. The env's action space is then the correction: a gymnasium
client or :func:`seqdex_drake.load_policy` deals in corrections, and the env turns them into robot actions.

A base is a function of the observation (the env's policy observation, progress entry included) and the step
only, with no hidden state, so the env and a policy system that see the same observation at the same step
compute the same action. The residual is added before the scripted phases (``tasks/phases.py``), which still
override the wrist in the scripted lift.

Two optional hooks. A base whose rules need a fact about the episode's target that the observation lacks (the
retrieve needs the block's length; the observation does not carry the block's type) has ``for_object(name)``,
returning the base bound to that target (:func:`bind_base`); the env binds it when it sets its target, a deployed
policy system when the chain's target is set. A base that knows when its work is over has
``finished(observation, step)``; a scripted stage (``Task.scripted``) ends there rather than at its step budget.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from seqdex_drake.tasks.scripted.block_grasp_script import ScriptedBlockGrasp
from seqdex_drake.tasks.scripted.block_insert_script import ScriptedBlockInsert
from seqdex_drake.tasks.scripted.block_orient_script import ScriptedBlockOrient
from seqdex_drake.tasks.scripted.block_retrieve_script import ScriptedBlockRetrieve
from seqdex_drake.tasks.scripted.block_search_script import ScriptedBlockSearch
from seqdex_drake.tasks.scripted.tool_grasp_script import ScriptedToolGrasp
from seqdex_drake.tasks.scripted.tool_pinch_script import ScriptedToolPinch
from seqdex_drake.tasks.scripted.tool_reorient_gait import FingerGait


class BaseController(Protocol):
    """A scripted controller usable as a residual base: Markov in (observation, step)."""

    def act(self, observation, step: int) -> np.ndarray:
        """The 19-dim action in [-1, 1] for ``observation`` at episode step ``step`` (0 for the first)."""


def _tool_grasp_script() -> BaseController:
    return ScriptedToolGrasp()


def _tool_pinch_script() -> BaseController:
    return ScriptedToolPinch()


def _block_grasp_script() -> BaseController:
    return ScriptedBlockGrasp()


def _block_insert_script() -> BaseController:
    return ScriptedBlockInsert()


def _block_search_script() -> BaseController:
    return ScriptedBlockSearch()


def _block_orient_script() -> BaseController:
    return ScriptedBlockOrient()


def _block_retrieve_script() -> BaseController:
    return ScriptedBlockRetrieve()  # Unbound: bind_base gives it the target block (its length).


def _tool_reorient_gait() -> BaseController:
    return FingerGait()


#: Name -> factory of the scripted bases a ``TaskConfig.residual`` may name.
RESIDUAL_BASES: dict[str, Callable[[], BaseController]] = {
    "tool_grasp_script": _tool_grasp_script,  # The scripted hammer pickup (tasks/scripted/tool_grasp_script.py).
    "tool_pinch_script": _tool_pinch_script,  # The yaw-planned hammer pinch (tasks/scripted/tool_pinch_script.py).
    "tool_reorient_gait": _tool_reorient_gait,  # A searched open-loop finger gait (scripted/tool_reorient_gait.py).
    "block_grasp_script": _block_grasp_script,  # The scripted block pickup (tasks/scripted/block_grasp_script.py).
    "block_orient_script": _block_orient_script,  # The scripted fingertip roll (tasks/scripted/block_orient_script.py).
    "block_search_script": _block_search_script,  # The scripted search (tasks/scripted/block_search_script.py).
    "block_insert_script": _block_insert_script,  # The scripted block insertion (scripted/block_insert_script.py).
    "block_retrieve_script": _block_retrieve_script,  # Out of the pile (tasks/scripted/block_retrieve_script.py).
}

#: Base name -> the sub-task whose env it acts in (its observation layout and objects).
BASE_TASKS: dict[str, str] = {
    "tool_grasp_script": "tool_grasp", "tool_pinch_script": "tool_grasp", "tool_reorient_gait": "tool_reorient",
    "block_grasp_script": "grasp", "block_orient_script": "orient", "block_search_script": "search",
    "block_insert_script": "insert", "block_retrieve_script": "retrieve",
}


def make_base(name: str) -> BaseController:
    """The base controller ``name``; a ValueError lists the valid names."""
    if name not in RESIDUAL_BASES:
        raise ValueError(f"unknown residual base {name!r}; valid bases: {', '.join(RESIDUAL_BASES)} "
                         f"(or '' for no base)")
    return RESIDUAL_BASES[name]()


def bind_base(base: BaseController | None, object_name: str) -> BaseController | None:
    """``base`` bound to the episode's target ``object_name`` (its ``for_object``), or ``base`` itself when it has
    no such hook (or is None)."""
    bind = getattr(base, "for_object", None)
    return bind(object_name) if bind is not None else base


def base_finished(base: BaseController | None, observation, step: int) -> bool:
    """Whether ``base`` says its work is over at ``step`` (its ``finished``); False for bases without the hook."""
    finished = getattr(base, "finished", None)
    return bool(finished(observation, step)) if finished is not None else False


def apply_residual(base: BaseController | None, observation, step: int, action: list[float]) -> list[float]:
    """The action to apply at ``step``: ``clip(base(observation, step) + action, -1, 1)`` as a new list (the
    action unchanged, as a list, when ``base`` is None)."""
    if base is None:
        return list(action)
    scripted = np.asarray(base.act(observation, step), dtype=float).tolist()
    return [min(max(s + a, -1.0), 1.0) for s, a in zip(scripted, action, strict=True)]
