"""The chain's state in meshcat: which sub-policy runs and the feasibility scores, live and in recordings.

Drake's Meshcat has no text objects, so the display is geometry at ``/chain_status`` (shown in the live page
and in a ``StaticHtml`` replay, because every change goes through ``time_in_recording``):

* one cube per stage in a row on the far edge of the table (+x side, the robot's left to right is -y to +y):
  grey when idle, the stage's own colour and raised 3 cm while it runs;
* one bar per transition between the cubes: its height is the feasibility score c = F / h of switching to
  the next stage (1 cm per 0.1, clamped at c = 3), green above the threshold c = 1, orange below; a thin
  white slab marks c = 1;
* a stack of small discs counts the blocks (or tools) finished so far.

The live page also lists the state in its control panel as text: a button labelled ``stage k/K: <name>`` and
read-only sliders with the current scores (moving them changes nothing). Stdout gets a line per switch.

Args:
    meshcat: the ``pydrake.geometry.Meshcat`` to draw in.
    stages: the chain's sub-task names, first to last.
    period: display update period (s).
"""

import numpy as np
from pydrake.geometry import Box, Cylinder, Rgba
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

ROOT = "/chain_status"
#: Where the row of stage cubes starts (the table's far edge, right of the board).
ORIGIN = np.array([0.78, -0.40, 0.60])
CUBE = 0.05
SPACING = 0.16
BAR_WIDTH = 0.03
METRES_PER_SCORE = 0.10
MAX_SCORE = 3.0
IDLE_RGBA = Rgba(0.55, 0.55, 0.55, 1.0)
#: Stage colours (a chain with more stages cycles through them); also the colours the browser test counts.
STAGE_RGBA = [Rgba(0.95, 0.15, 0.15, 1.0), Rgba(0.15, 0.45, 0.95, 1.0), Rgba(0.95, 0.75, 0.05, 1.0),
              Rgba(0.60, 0.20, 0.85, 1.0)]
ABOVE_RGBA = Rgba(0.10, 0.85, 0.25, 1.0)
BELOW_RGBA = Rgba(1.00, 0.50, 0.00, 1.0)
THRESHOLD_RGBA = Rgba(1.0, 1.0, 1.0, 0.8)
DONE_RGBA = Rgba(0.05, 0.80, 0.80, 1.0)
MAX_DONE = 12


def stage_position(k: int) -> np.ndarray:
    return ORIGIN + [0.0, k * SPACING, CUBE / 2]


def bar_position(k: int) -> np.ndarray:
    """Bottom centre of the bar between stage k and k + 1."""
    return ORIGIN + [0.0, (k + 0.5) * SPACING, 0.0]


class ChainStatusDisplay(LeafSystem):
    """Draws the active stage and feasibility scores (see the module docstring).

    Input ports: ``active_stage`` (1: stage index, 0-based), ``feasibility_scores`` (K: c^i of switching into
    stage i, as the chain controller outputs them; entry 0 and NaN entries mean no score), ``completed`` (1:
    blocks or tools finished).
    """

    def __init__(self, meshcat, stages: list[str], period: float = 1.0 / 30.0):
        super().__init__()
        self.meshcat = meshcat
        self.stages = list(stages)
        self.DeclareVectorInputPort("active_stage", BasicVector(1))
        self.DeclareVectorInputPort("feasibility_scores", BasicVector(len(self.stages)))
        self.DeclareVectorInputPort("completed", BasicVector(1))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareForcedPublishEvent(self._publish)
        self._last = None
        self._label = None
        self._sliders: list[str] = []
        self._build()

    def _build(self) -> None:
        m = self.meshcat
        m.Delete(ROOT)
        for k, stage in enumerate(self.stages):
            for state, rgba in (("idle", IDLE_RGBA), ("active", STAGE_RGBA[k % len(STAGE_RGBA)])):
                path = f"{ROOT}/stage_{k}_{stage}/{state}"
                m.SetObject(path, Box(CUBE, CUBE, CUBE), rgba)
                m.SetProperty(path, "visible", state == "idle")
            m.SetTransform(f"{ROOT}/stage_{k}_{stage}", RigidTransform(stage_position(k)))
        for k in range(len(self.stages) - 1):
            path = f"{ROOT}/transition_{k}"
            m.SetTransform(path, RigidTransform(bar_position(k)))
            m.SetObject(f"{path}/threshold", Box(BAR_WIDTH * 2.2, BAR_WIDTH * 2.2, 0.003), THRESHOLD_RGBA)
            m.SetTransform(f"{path}/threshold", RigidTransform([0.0, 0.0, METRES_PER_SCORE]))
            for kind, rgba in (("above", ABOVE_RGBA), ("below", BELOW_RGBA)):
                # A unit-height bar standing on z = 0, scaled in z by the score.
                m.SetObject(f"{path}/{kind}/bar", Box(BAR_WIDTH, BAR_WIDTH, 1.0), rgba)
                m.SetTransform(f"{path}/{kind}/bar", RigidTransform([0.0, 0.0, 0.5]))
                m.SetProperty(f"{path}/{kind}", "visible", False)
                m.SetProperty(f"{path}/{kind}", "scale", [1.0, 1.0, 1e-3])
            name = f"c {self.stages[k]} -> {self.stages[k + 1]}"
            m.AddSlider(name, 0.0, MAX_SCORE, 0.01, 0.0)
            self._sliders.append(name)
        for n in range(MAX_DONE):
            path = f"{ROOT}/done/{n}"
            m.SetObject(path, Cylinder(0.02, 0.008), DONE_RGBA)
            m.SetTransform(path, RigidTransform(ORIGIN + [0.0, -SPACING, 0.004 + 0.01 * n]))
            m.SetProperty(path, "visible", False)

    def _publish(self, context) -> EventStatus:
        stage = int(round(self.get_input_port(0).Eval(context)[0]))
        scores = np.asarray(self.get_input_port(1).Eval(context), dtype=float)[1:]
        done = int(round(self.get_input_port(2).Eval(context)[0]))
        key = (stage, tuple(np.round(np.nan_to_num(scores, nan=-1.0), 2)), done)
        if key == self._last:
            return EventStatus.DidNothing()
        t = context.get_time()
        previous = self._last
        self._last = key
        m = self.meshcat
        if previous is None or previous[0] != stage:
            for k, name in enumerate(self.stages):
                path = f"{ROOT}/stage_{k}_{name}"
                m.SetProperty(f"{path}/idle", "visible", k != stage, t)
                m.SetProperty(f"{path}/active", "visible", k == stage, t)
                lift = 0.03 if k == stage else 0.0
                m.SetTransform(path, RigidTransform(stage_position(k) + [0, 0, lift]), t)
            self._set_label(stage)
        for k, c in enumerate(scores):
            path = f"{ROOT}/transition_{k}"
            valid = bool(np.isfinite(c) and c >= 0)
            height = float(np.clip(c, 0.0, MAX_SCORE)) * METRES_PER_SCORE if valid else 1e-3
            m.SetProperty(f"{path}/above", "visible", valid and c > 1.0, t)
            m.SetProperty(f"{path}/below", "visible", valid and c <= 1.0, t)
            for kind in ("above", "below"):
                m.SetProperty(f"{path}/{kind}", "scale", [1.0, 1.0, max(height, 1e-3)], t)
            m.SetSliderValue(self._sliders[k], float(np.clip(c, 0.0, MAX_SCORE)) if valid else 0.0)
        if previous is None or previous[2] != done:
            for n in range(MAX_DONE):
                m.SetProperty(f"{ROOT}/done/{n}", "visible", n < done, t)
        return EventStatus.Succeeded()

    def _set_label(self, stage: int) -> None:
        if self._label is not None:
            self.meshcat.DeleteButton(self._label)
        name = self.stages[stage] if 0 <= stage < len(self.stages) else "idle"
        self._label = f"stage {stage + 1}/{len(self.stages)}: {name}"
        self.meshcat.AddButton(self._label)

    def clear_controls(self) -> None:
        """Removes the control-panel entries this display added."""
        if self._label is not None:
            self.meshcat.DeleteButton(self._label)
            self._label = None
        for name in self._sliders:
            self.meshcat.DeleteSlider(name)
        self._sliders = []
