"""A scripted retrieve for the Building Blocks chain: take the target block out of the pile, in whatever pose it
lies, and set it down alone on the staging area (``tasks/blocks_common.STAGING_LOW`` .. ``STAGING_HIGH``), where
the shipped Orient and Grasp keep the success they have alone.

Why: inside the pile Orient stands up about 1 in 10 of the blocks it must roll and Grasp's open jaws land on the
neighbours; on the clear table both succeed in about 0.9 of episodes. The paper's Search "digs and retrieves"; this
is the retrieve, scripted as the other stages' bases are, and acting only through the env's 19-dim action space.

Strategy (every rule reads the observation and the step only, :meth:`ScriptedBlockRetrieve.act`, no hidden
state, so the env and a deployed policy system compute the same action):

* **Grip, in attempts.** The steps come in windows of ``attempt_steps``; in the first ``attempts`` windows, while
  the block is not held, Grasp's jaw pinch (:class:`~seqdex_drake.tasks.scripted.block_grasp_script.ScriptedBlockGrasp`
  on the window's own step count) puts its grasp centre C on the block's geometric centre, ``depth`` above the
  block's lowest point (not its origin: a lying block's origin is not its bottom), closes, and from the window's
  step ``lift_at`` lifts at full speed. A pinch that did not take (the block is not following C) opens back to the
  pre-grasp shape and rises until the next window re-grips the block where it now lies. Once lifted, the pinch
  along world x holds lying blocks as it holds upright ones, through the carry too.
* **Held** means C is within ``held_radius`` of the block's long axis (a block pinched near an end is held
  too). A held block above ``transfer_z`` (clear of the box's walls), or lifted beside the box, is *transferred*:
  first over the box's near wall to ``over_y`` at ``carry_z`` (until the block's centre is there, or C is, for a
  block hanging off-centre behind C: C alone could not take it further, and at ``carry_z`` it is above the wall
  anyway), then to the staging point at ``carry_z``, then lowered until its lowest point touches the table.
* **Release.** A held block resting on the table within 3 cm of the staging point: the hand
  returns to the pre-grasp shape (the jaws 7 cm apart, so the block is let go where it stands, not flung by
  straightening fingers) while the wrist rises slowly. Once the block is no longer held the hand rises to
  ``carry_z``, straightening its fingers once the jaws are 10 cm over the block's bottom (the pre-grasp jaws
  reach down past the grasp centre: left so, Orient's approach would bring them down onto the block), and waits:
  the retrieve is done, and Orient's approach takes over.
* A block dropped outside the box (on the table, or still settling on the staging area) is gripped again where
  it lies, in the following windows. After the attempts, a block still in the box and not held is given up: the
  hand opens and rises (the switcher can restart Search).

Measured in the whole chain's scene, the shipped chain from Orient after it (``experiments/retrieve_chain.py``):
``results/building_blocks.md``, "Out of the pile: the retrieve". Its limits there: blocks not taken out in three
attempts (mostly among neighbours on the box floor), and blocks set down upside down, pitched on a curved top or
on an end, which Orient then fails to stand up.
"""

from __future__ import annotations

import copy

import numpy as np

from seqdex_drake.modeling.blocks import BLOCK_SPECS, TOTAL_HEIGHT
from seqdex_drake.observation_layout import OBJECT_POSE, PALM_POSE, rotation_matrix
from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q, ALLEGRO_Q_MAX, ALLEGRO_Q_MIN, unscale_limits_to_action
from seqdex_drake.scene.piles import BOX_CENTER, BOX_INNER_HALF
from seqdex_drake.tasks.blocks_common import STAGING_HIGH, STAGING_LOW
from seqdex_drake.tasks.scripted.block_grasp_script import CLOSING, WRIST_STEP, ScriptedBlockGrasp, p_PalmC_Palm

BLOCK_WIDTH = 0.03
"""Every Mega Blok is one stud (3 cm) wide; its length is the type's (``modeling/blocks.BLOCK_SPECS``)."""
TABLE_Z = BOX_CENTER[2]
"""The table top and the box floor [m]."""
PALM_VELOCITY = slice(105, 108)
"""The palm's linear velocity in the observation [m/s]."""


def block_geometry(observation, length: float) -> tuple[np.ndarray, float]:
    """The observed block's geometric centre (world) and its lowest point's height [m], for a block ``length`` m
    long (its origin is the middle of its bottom face; the centre is ``TOTAL_HEIGHT / 2`` up its z axis)."""
    o = np.asarray(observation, dtype=float)
    return block_extent(o[OBJECT_POSE][:3], rotation_matrix(o[OBJECT_POSE][3:7]), length)


def block_extent(p_WB: np.ndarray, R_WB: np.ndarray, length: float) -> tuple[np.ndarray, float]:
    """:func:`block_geometry` of a block at pose (``p_WB``, ``R_WB``, a 3x3 rotation matrix)."""
    centre = np.asarray(p_WB, dtype=float) + R_WB[:, 2] * (TOTAL_HEIGHT / 2)
    half_extent_z = np.abs(R_WB[2]) @ [length / 2, BLOCK_WIDTH / 2, TOTAL_HEIGHT / 2]
    return centre, float(centre[2] - half_extent_z)


def in_box(p_W: np.ndarray) -> bool:
    """Whether world point ``p_W``'s xy lies over the box's inner floor."""
    return bool(np.all(np.abs(np.asarray(p_W)[:2] - BOX_CENTER[:2]) <= BOX_INNER_HALF))


def on_staging_area(p_W: np.ndarray, margin: float = 0.03) -> bool:
    """Whether world point ``p_W``'s xy lies on the staging area, ``margin`` m of slack included."""
    p = np.asarray(p_W)[:2]
    return bool(np.all(p >= STAGING_LOW - margin) and np.all(p <= STAGING_HIGH + margin))


class ScriptedBlockRetrieve:
    """The scripted retrieve (see the module docstring): :meth:`act` of the observation and the step only.

    The target block's length is a parameter of the episode, not of the observation (which does not carry the
    block's type): construct with ``length``, or without and bind the target with :meth:`for_object` (as the env
    and a deployed policy system do once they know the target, ``tasks/residual.py``).

    Args:
        length: the target block's length [m] (its type's footprint length), for its lowest point; None: unbound
            (:meth:`act` refuses until :meth:`for_object` gives the target).
        stage_xy: where the block's centre is set down (world xy) [m]; default the staging area's centre.
        attempts, attempt_steps: the grip's attempts and the steps of each window.
        carry_z: the grasp centre's height while carrying [m]; the box's walls end 0.165 m above its floor.
        transfer_z: a held block whose centre is above this height [m] is carried out.
        over_y: the carry first crosses the box's near (-y) wall to this y [m].
        held_radius: the block is held while the grasp centre C is within this of its long axis [m].
        stage_tolerance: the carry lowers the block once its centre is within this of ``stage_xy``, plus 2 cm
            of slack as it settles [m].
        speed: the wrist's speed while lifting, carrying and lowering, as a fraction of its full step.
        gain: the wrist law's gain (per step, on the error over ``WRIST_STEP``).
        squeeze, depth, x_min: Grasp's pinch (:class:`ScriptedBlockGrasp`).
    """

    def __init__(self, length: float | None = None, stage_xy=None, attempts: int = 3, attempt_steps: int = 100,
                 carry_z: float = 0.88, transfer_z: float = 0.78, over_y: float = -0.10, held_radius: float = 0.04,
                 stage_tolerance: float = 0.01, speed: float = 0.6, gain: float = 0.4, squeeze: float = 0.1,
                 depth: float = 0.022, x_min: float = 0.085):
        if length is not None and not 0.0 < length <= 0.2:
            raise ValueError(f"length must be the block's length in metres (0.03 to 0.12 for Mega Bloks), got {length}")
        self.length = None if length is None else float(length)
        self.stage_xy = (STAGING_LOW + STAGING_HIGH) / 2 if stage_xy is None else np.asarray(stage_xy, dtype=float)
        self.attempts, self.attempt_steps = int(attempts), int(attempt_steps)
        self.clear_height = 0.10  # C over the block's bottom before the fingers straighten [m].
        self.carry_z, self.transfer_z, self.over_y = carry_z, transfer_z, over_y
        self.held_radius, self.stage_tolerance, self.speed, self.gain = held_radius, stage_tolerance, speed, gain
        self.grasp = ScriptedBlockGrasp(squeeze=squeeze, depth=depth, x_min=x_min)
        self.open_q = CLOSING[0]  # Grasp's pre-grasp shape: the jaws 7 cm either side of C.
        self.closed_q = self.grasp.closing[-1]
        if self.attempt_steps <= self.grasp.lift_at + 20:
            raise ValueError(f"attempt_steps ({attempt_steps}) must leave the pinch at least 20 steps to lift after "
                             f"it closes at step {self.grasp.lift_at}")

    def reset(self, env) -> None:
        pass

    def for_object(self, name: str) -> ScriptedBlockRetrieve:
        """This retrieve bound to target ``name`` (a pile block ``block_<type>_<k>``): its length is the type's."""
        parts = str(name).split("_")
        if len(parts) != 3 or parts[0] != "block" or not parts[1].isdigit() or int(parts[1]) not in BLOCK_SPECS:
            raise ValueError(f"the retrieve takes a pile block (block_<type>_<k>, types {sorted(BLOCK_SPECS)}) as "
                             f"its target, got {name!r}")
        bound = copy.copy(self)
        bound.length = float(BLOCK_SPECS[int(parts[1])].footprint[0])
        return bound

    def finished(self, observation, step: int) -> bool:
        """Whether the retrieve is over: the block set down and the open hand back up ("done"), or given up."""
        return self.phase(observation, step) in ("done", "give_up")

    def _length(self) -> float:
        if self.length is None:
            raise ValueError("the retrieve has no target block: bind it with for_object('block_<type>_<k>') or "
                             "construct it with length=")
        return self.length

    def phase(self, observation, step: int) -> str:
        """The rule that applies: "grip", "lift", "regrip" (a pinch that did not take), "transfer", "lower",
        "release", "rise" (the block is on the staging area, out of the hand), "done" (and the open hand is back
        at ``carry_z``) or "give_up"."""
        o = np.asarray(observation, dtype=float)
        centre, bottom = block_geometry(o, self._length())
        C = self._grasp_centre(o)
        held = self._reach(o, centre, C) < self.held_radius
        local = step % self.attempt_steps
        lifted_out = not in_box(centre) and bottom > TABLE_Z + 0.02  # Held off the table beside the box.
        if held and (centre[2] > self.transfer_z or lifted_out or (bottom < TABLE_Z + 0.02 and self._at_stage(centre))):
            if self._at_stage(centre):
                return "release" if bottom < TABLE_Z + 0.007 else "lower"
            return "transfer"
        if not held and on_staging_area(centre) and bottom < TABLE_Z + 0.01:
            return "done" if C[2] >= self.carry_z - 0.02 else "rise"
        if step >= self.attempts * self.attempt_steps and in_box(centre):
            return "give_up"
        if local < self.grasp.lift_at:
            return "grip"
        return "lift" if held else "regrip"

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 159 or 160 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        phase = self.phase(o, step)
        centre, bottom = block_geometry(o, self._length())
        C = self._grasp_centre(o)
        if phase == "grip":  # Grasp's pinch on the window's step count, aimed at the centre and the lowest point.
            aimed = o.copy()
            aimed[OBJECT_POSE.start:OBJECT_POSE.start + 2] = centre[:2]
            aimed[OBJECT_POSE.start + 2] = bottom
            return self.grasp.act(aimed, step % self.attempt_steps)
        hand = self.closed_q
        speed = self.speed
        if phase == "lift":  # At full speed: the block must clear the walls before the window ends.
            goal, speed = np.r_[C[:2], self.carry_z + 0.01], 1.0
        elif phase == "transfer":
            if centre[1] > self.over_y + 0.01 and C[1] > self.over_y + 0.002:  # Over the box's near wall first.
                goal = np.r_[C[0], self.over_y, self.carry_z]
            else:
                goal = np.r_[self.stage_xy + (C[:2] - centre[:2]), self.carry_z]
        elif phase == "lower":
            goal = np.r_[self.stage_xy + (C[:2] - centre[:2]), C[2] - (bottom - TABLE_Z - 0.005)]
        elif phase == "release":
            hand, goal = self.open_q, C + [0.0, 0.0, 0.002]
        elif phase == "rise":  # The jaws clear of the block first, then the fingers straight, as Search leaves them.
            hand = ALLEGRO_OPEN_Q if C[2] > bottom + self.clear_height else self.open_q
            goal = np.r_[C[:2], self.carry_z]
        elif phase == "done":
            hand, goal = ALLEGRO_OPEN_Q, C
        else:  # "regrip", "give_up": let go and rise over the block.
            hand, goal = self.open_q, np.r_[C[:2], max(C[2], bottom + self.grasp.z_up)]
        hand_action = unscale_limits_to_action(np.clip(hand, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        return np.r_[hand_action, self._wrist(o, C, goal, speed)]

    def _reach(self, o: np.ndarray, centre: np.ndarray, C: np.ndarray) -> float:
        """C's distance to the block's long axis (the segment through its centre, its length long): a block
        pinched near one end is held as well as one pinched at its centre."""
        axis = rotation_matrix(o[OBJECT_POSE][3:7])[:, 0]
        d = C - centre
        return float(np.linalg.norm(d - np.clip(d @ axis, -self.length / 2, self.length / 2) * axis))

    def _at_stage(self, centre: np.ndarray) -> bool:
        """Whether the block's centre is over the staging point (the transfer stops within ``stage_tolerance``;
        lowering and releasing go on within 2 cm more, as the block settles)."""
        return float(np.linalg.norm(centre[:2] - self.stage_xy)) < self.stage_tolerance + 0.02

    def _grasp_centre(self, o: np.ndarray) -> np.ndarray:
        R_WP = rotation_matrix(o[PALM_POSE][3:7])
        return o[PALM_POSE][:3] + R_WP @ p_PalmC_Palm

    def _wrist(self, o: np.ndarray, C: np.ndarray, goal: np.ndarray, speed: float) -> np.ndarray:
        """Moves C toward ``goal`` at most at ``speed`` of the full wrist step, damped by the palm's velocity."""
        velocity = o[PALM_VELOCITY] / 60.0  # Palm displacement per step.
        w = np.clip((self.gain * (goal - C) - velocity) / WRIST_STEP, -1.0, 1.0)
        return w * min(1.0, speed / max(float(np.linalg.norm(w)), 1e-9))
