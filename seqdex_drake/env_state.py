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
