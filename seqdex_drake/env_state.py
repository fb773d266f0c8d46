"""The sub-task env's restorable state (:class:`EnvState`): what ``SubtaskEnv.get_state`` returns, what
``reset(options={"initial_state": state})`` restores bit for bit, what the vector envs ship between processes and
what forward initialization's terminal buffers store field by field.

Why it sits at the bottom of the package, beside :mod:`seqdex_drake.atomic`: it is a plain dataclass of numpy
arrays, and besides the env (``envs/subtask_env.py``, which re-exports it) the chaining code rebuilds it from
terminal buffers (``chaining/wrappers.py``, ``chaining/bidirectional.py``), which must not import ``envs/``.
"""

import dataclasses

import numpy as np


@dataclasses.dataclass
class EnvState:
    """A restorable environment state (what forward initialization hands to the next sub-task)."""

    plant_positions: np.ndarray
    plant_velocities: np.ndarray
    objects: dict
    target_object: str
    goal: np.ndarray
    arm_target: np.ndarray
    hand_target: np.ndarray
    previous_action: np.ndarray
    task: str = ""
    """The sub-task that saved the state (a different one means a hand-off)."""
    arm_velocity_target: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(7))
    """The arm's desired joint velocities (the wrist command's feed-forward; zero at rest)."""
    time: float = 0.0
    """Simulation time of the state (s). The control period (1/60 s) is not a multiple of the plant step (2 ms),
    so which plant steps fall inside a control step depends on the time -- down to its rounding where a control
    boundary meets a plant step --; restoring it makes the continuation exact (0 for states saved without it)."""
    robot_positions: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """The arm's 7 and then the hand's 16 joint positions: with the four fields below, what a hand-off to a sub-task
    on another station scene carries over (``envs/scene_handoff.py``); empty in states saved without them."""
    robot_velocities: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """The arm's 7 and then the hand's 16 joint velocities."""
    target_positions: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """The target object's free-body positions [qw, qx, qy, qz, x, y, z] in the world."""
    target_velocities: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """The target object's spatial velocity in the world [wx, wy, wz, vx, vy, vz]."""


class SceneHandoffError(ValueError):
    """A state that cannot be carried over to another station scene; the message says why and what to do."""


def counterpart(name: str, names: list[str]) -> str:
    """The object of ``names`` (another scene's objects) standing for object ``name`` in a hand-off across scenes
    (``envs/scene_handoff.py``): itself, or that scene's one block of the same type (a pile's ``block_<type>_<k>``
    is ``block_<type>`` on the single-block scenes). Raises :class:`SceneHandoffError` if there is none."""
    if name in names:
        return name
    parts = name.split("_")
    if len(parts) >= 2 and parts[0] == "block" and "_".join(parts[:2]) in names:
        return "_".join(parts[:2])
    raise SceneHandoffError(f"the handed-over target object {name!r} has no counterpart in the next scene (its "
                            f"objects: {', '.join(names)}); chain sub-tasks whose scenes hold the same object types")


def check_handoff(source_names: list[str], target_names: list[str]) -> None:
    """Raises :class:`SceneHandoffError` unless every object of a scene (``source_names``) has a counterpart in the
    next sub-task's scene (``target_names``): whatever the first targets, its state can start the second."""
    for name in source_names:
        counterpart(name, target_names)
