"""A periodic finger gait for tool Reorient: open-loop hand targets that roll a held tool about its handle.

Tool Reorient turns the hammer 180 deg about its handle in the hand. In-hand reorientation from scratch takes
1e8 or more env steps wherever it is reported (``../shared/TRAINING.md``); this gait is the scripted base a
residual policy corrects (``tasks/residual.py``, base ``"tool_reorient_gait"``), as the scripted pickup is for
tool Grasp. Each hand joint follows

    action_j(step) = clip(center_j + amplitude_j * sin(2 pi step / period + phase_j), -1, 1)

in the env's hand-action units (absolute targets scaled to the joint limits), and the wrist holds still (its three
action entries 0). Once the tool is within ``HOLD_BELOW`` of its goal orientation (the observation's goal error), the
gait stops: the hand repeats the previous step's hand action (the observation holds it), keeping its targets, until
the error grows again. The action depends on the observation and the step only, so it is a valid residual base
(Markov in both). Its 49 numbers (:class:`GaitParameters`) are not designed by hand:
``experiments/search_reorient_gait.py``
finds them by a cross-entropy search over episodes of the tool Reorient env itself, from tool Grasp's hand-off
states, and writes :data:`GAIT_FILE`, which this module reads.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from seqdex_drake.observation_layout import GOAL_ROTATION_ERROR, PREVIOUS_ACTION

#: The searched gait (written by experiments/search_reorient_gait.py; its header records the command and score).
GAIT_FILE = Path(__file__).with_name("tool_reorient_gait.json")
HAND_JOINTS = 16
#: Bounds of the period (policy steps): a cycle between 1/6 s and 2 s at 60 Hz.
PERIOD_RANGE = (10.0, 120.0)
#: Goal orientation error (rad) below which the gait stops and the hand holds (tool Reorient succeeds below 0.5).
HOLD_BELOW = 0.35


@dataclasses.dataclass(frozen=True)
class GaitParameters:
    """A gait's numbers: per hand joint a center, an amplitude and a phase; one period (policy steps)."""

    center: tuple[float, ...]
    amplitude: tuple[float, ...]
    phase: tuple[float, ...]
    period: float

    SIZE = 3 * HAND_JOINTS + 1

    def __post_init__(self):
        for field in ("center", "amplitude", "phase"):
            values = getattr(self, field)
            if len(values) != HAND_JOINTS or not all(math.isfinite(v) for v in values):
                raise ValueError(f"GaitParameters.{field} must be {HAND_JOINTS} finite numbers, got {values!r}")
        if not PERIOD_RANGE[0] <= self.period <= PERIOD_RANGE[1]:
            raise ValueError(f"GaitParameters.period must be in {PERIOD_RANGE} steps, got {self.period!r}")

    def to_vector(self) -> np.ndarray:
        """The ``SIZE`` numbers as one vector: centers, amplitudes, phases, period."""
        return np.r_[self.center, self.amplitude, self.phase, self.period]

    @classmethod
    def from_vector(cls, vector) -> GaitParameters:
        """The inverse of :meth:`to_vector`; the period is clipped into :data:`PERIOD_RANGE`, amplitudes made
        non-negative and phases wrapped into [-pi, pi) (a search samples unbounded vectors)."""
        v = np.asarray(vector, dtype=float)
        if v.shape != (cls.SIZE,):
            raise ValueError(f"a gait vector has {cls.SIZE} numbers, got shape {v.shape}")
        n = HAND_JOINTS
        phase = (v[2 * n:3 * n] + np.pi) % (2 * np.pi) - np.pi
        return cls(tuple(np.clip(v[:n], -1.0, 1.0)), tuple(np.abs(v[n:2 * n])), tuple(phase),
                   float(np.clip(v[-1], *PERIOD_RANGE)))

    def to_dict(self) -> dict:
        return {"center": list(self.center), "amplitude": list(self.amplitude), "phase": list(self.phase),
                "period": self.period}

    @classmethod
    def from_dict(cls, data: dict) -> GaitParameters:
        return cls(tuple(data["center"]), tuple(data["amplitude"]), tuple(data["phase"]), float(data["period"]))


def load_gait(path: str | Path = GAIT_FILE) -> GaitParameters:
    """The gait stored at ``path`` (a file of experiments/search_reorient_gait.py); a ValueError names a file that is
    missing, unreadable or not such a file, and says how to make one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        return GaitParameters.from_dict(data["gait"])
    except FileNotFoundError:
        raise ValueError(f"no reorient gait at {path}; make one with python experiments/search_reorient_gait.py"
                         ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path} is not a reorient gait file ({error}); rewrite it with "
                         "python experiments/search_reorient_gait.py") from None


class FingerGait:
    """The gait as a controller: ``act(observation, step)`` -> the 19-dim action (hand gait, wrist still; the
    hand holds once the tool is within :data:`HOLD_BELOW` of its goal). ``observation=None``: the gait alone."""

    def __init__(self, parameters: GaitParameters | None = None):
        self.parameters = parameters if parameters is not None else load_gait()
        p = self.parameters
        self._center, self._amplitude = np.asarray(p.center), np.asarray(p.amplitude)
        self._phase, self._omega = np.asarray(p.phase), 2.0 * np.pi / p.period

    def act(self, observation, step: int) -> np.ndarray:
        if observation is not None and _goal_angle(observation) < HOLD_BELOW:
            return np.r_[np.asarray(observation[PREVIOUS_ACTION][:HAND_JOINTS], dtype=float), 0.0, 0.0, 0.0]
        hand = np.clip(self._center + self._amplitude * np.sin(self._omega * step + self._phase), -1.0, 1.0)
        return np.r_[hand, 0.0, 0.0, 0.0]


def _goal_angle(observation) -> float:
    """The goal orientation error (rad) in a tool Reorient observation: 2 asin |vec(q_goal conj(q_tool))|."""
    w, x, y, z = (float(v) for v in observation[GOAL_ROTATION_ERROR])
    return 2.0 * math.asin(min(math.sqrt(x * x + y * y + z * z), 1.0))
