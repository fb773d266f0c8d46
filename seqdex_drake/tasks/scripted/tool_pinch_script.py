"""A scripted tool pickup by a thumb-opposed pinch planned from the tool's observed yaw, acting only through the
env's 19-dim action space: the alternative to the fist of ``tasks/scripted/tool_grasp_script.py`` (residual base
``tool_pinch_script``; the shipped chain still runs the fist, whose hand-offs tool Reorient's gait was searched on).

Phase rules, as the fist's: steps 0-59 free (this script lifts from ``lift_at``, step 50); steps 60-89 the wrist
action is exactly [0, 0, 1] (the release's scripted lift); from step 90 the wrist is still and the hand holds.

Why a pinch. The fist closes its fingers toward the wrist whatever the hammer's yaw, so it pulls the handle across
the palm (yaw -> 0) and fails the 0.3 rad test for every positive yaw. The pinch instead presses across the handle
along its own normal: index and middle tips on the handle's far side, ``spread`` either way along it, the thumb
opposite on the near side. The wrist only translates, so the fingers do the turning: every tip position comes from
inverse kinematics on the hand alone for the observed yaw (:meth:`ScriptedToolPinch.pinch_shapes`, per 0.01 rad).

* Where. On the handle at the tool's centre of mass along it (``TOOL_GRIPS``: the hammer's at tool y 0.125, where
  the handle is 18 x 23 mm), so the lifted hammer hangs as it lay. The palm point ``p_PalmA`` (6.5 cm below the
  palm, 4.5 cm to its index side) is put there: the 14 cm head then stands beyond the index finger, never under
  the hand.
* Contact height. The tips sit ``phi`` (0.7 rad) below the handle's equator, on both sides: a cradle, whose
  contact normals carry the weight, where a pinch at the equator slid off the handle in the lift.
* Force. The squeeze is commanded in force, as ``tasks/scripted/grasping.SqueezeTargets``: the last shape's
  targets are ``q + J^T f / kp`` with each finger pressing ``force`` (2 N) along its contact normal and the thumb
  ``thumb_ratio`` (2.5) times that; a weaker thumb lets the hammer roll about its handle in the lift. A tool's
  grip may set its own force (the ladle's 1.2 N, ``TOOL_GRIPS``).
* Positive yaw above ``abduction_above`` (0.35 rad) puts the head near the index finger: there the index
  abduction is held within ``abduction_limit`` (0.2 rad) so that its proximal link does not land on the head.
* The plan holds once the jaws close. Until step ``close_at`` the shapes follow the tool's observed yaw; from
  there on they keep the yaw the hand was last sent (:meth:`ScriptedToolPinch.planned_yaw_key` reads it back from
  the observation's previous action). Re-planning from the observed yaw let a light tool that turned a little in
  the closing jaws drag the fingers, and the plan, round with it: the 145 g ladle turned 0.4-1.7 rad about the
  vertical (at 1.2 N, tuning seeds 0-11: 2 of 12 lifted within 0.3 rad, 8 of 12 with the plan held).

Schedule: open (steps 0-1), the pre-grasp shape (tips 3 cm off the handle) forms over steps 2-9 at ``z_up`` above
the goal, the wrist goes down a funnel as the fist's does, the jaws close over steps 34-45 through tips 1.5 cm and 0
off the handle to the squeeze, the wrist holds still from step 34 and lifts from step 50.

Measured (``seqdex rollout --task tool_grasp --zero-action --base tool_pinch_script --episodes 100 --seed S``,
``results/tool_positioning.md``): tuned on seeds 0-29 (hammer 28 / 30, the fist 12 / 30); on held-out seeds 3000 /
4000 / 5000 the hammer 297 / 300 (the fist 132, the shipped fist with its residual 134), the unseen spatula 300 / 300
and ladle 199 / 300 (the fist 0 each; the ladle's misses turn 0.3-0.5 rad as it rocks on its bowl in the closing
jaws). Tool Reorient's gait was searched on the fist's hand-offs and drops a pinched hammer: the chain still runs
the fist.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.solvers import Solve

from seqdex_drake.observation_layout import PREVIOUS_ACTION, rotation_matrix
from seqdex_drake.robots.allegro import (
    ALLEGRO_OPEN_Q,
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    FINGERTIP_FRAMES,
    FINGERTIP_RADIUS,
    p_PalmHc_Palm,
    unscale_limits_to_action,
)
from seqdex_drake.tasks.scripted.grasping import MakeHandPlant

FREE_STEPS, LIFT_END, EPISODE_STEPS = 60, 90, 150
WRIST_STEP = 0.005
"""Metres per step of the hand centre at wrist action 1 (the env's ``wrist_step``)."""
CONTROL_RATE = 60.0
"""Policy steps per second."""
HAND_KP = 3.0
"""The hand's joint PD stiffness [N m / rad] the force squeeze is computed for (``Scenario.robot.hand_kp``)."""

R_PalmW = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
"""World -> palm rotation at the held orientation (palm down, fingers along world +x): palm x = world -z, palm y =
world y, palm z = world x. The wrist only translates, so the shapes are planned in this frame."""



@dataclasses.dataclass(frozen=True)
class HandleGrip:
    """Where a tool's handle is pinched, in the tool frame (its handle along y at x = 0)."""

    y: float
    """Tool y [m] of the grasp point: the centre of mass's."""
    z: float
    """Tool z [m] of the handle's axis there."""
    half_width: float
    """The handle's half-width across (tool x) there [m]."""
    half_height: float
    """The handle's half-height (tool z) there [m]."""
    force: float | None = None
    """The squeeze per finger for this tool [N]; None: the pinch's ``force``."""


TOOL_GRIPS = {
    "hammer": HandleGrip(0.125, -0.0115, 0.00902, 0.01159),
    "spatula": HandleGrip(0.033, 0.029, 0.0117, 0.00915),
    "spoon": HandleGrip(0.0857, 0.0119, 0.008, 0.004, force=1.2),
}
"""Each tool's grip, from its parametric model (``modeling/tools.py``): the hammer's elliptic handle (25 x 31 mm
at the butt, 17 x 22 mm at the head) at its centre of mass; the spatula's handle where it meets the neck; the
ladle's flat 16 x 6 mm grip, inclined there (the script treats it as level), squeezed at 1.2 N a finger: at 2 N the
fingers pressing the inclined strip's edges at different heights turn the 145 g ladle about the vertical."""

PINCH_DIGITS = (0, 1, 3)
"""Fingertips used (index, middle, thumb); the ring finger stays open."""
_NOMINAL_Q = np.array([0.0, 0.6, 0.6, 0.6] * 2 + [0.0] * 4 + [1.2, 0.4, 0.4, 0.4])
"""Initial guess and cost centre of the first inverse kinematics of a yaw."""
_INDEX_ABDUCTION = 0
"""Joint index of the index finger's abduction (held within ``abduction_limit`` at large positive yaw)."""
YAW_KEY_LIMIT = 80
"""Plans exist for yaw keys -80 .. 80 (the yaw is clipped to +-0.8 rad)."""
PLAN_MATCH = 1e-4
"""Largest difference (action units) between the previous action's hand part and a plan's for a match."""
PLAN_SEARCH = 60
"""Yaw keys searched either side of the observed yaw's for the plan the hand was sent (0.6 rad: a tool the fist
or the jaws turned farther was not held by this plan)."""


def _hand_ik(plant, targets: np.ndarray, guess: np.ndarray, abduction_limit: float | None) -> np.ndarray:
    """Hand positions putting the pinch tips as near as they reach to ``targets`` (palm frame; least squares, so a
    target beyond reach gives the nearest shape), the ring finger open."""
    ik = InverseKinematics(plant, plant.CreateDefaultContext())
    q = ik.q()
    for digit, p_target in zip(PINCH_DIGITS, targets, strict=True):
        ik.AddPositionCost(plant.world_frame(), p_target, plant.GetFrameByName(FINGERTIP_FRAMES[digit]),
                           np.zeros(3), 1e4 * np.eye(3))
    prog = ik.get_mutable_prog()
    for joint in range(8, 12):
        prog.AddBoundingBoxConstraint(ALLEGRO_OPEN_Q[joint], ALLEGRO_OPEN_Q[joint], q[joint])
    if abduction_limit is not None:
        prog.AddBoundingBoxConstraint(-abduction_limit, abduction_limit, q[_INDEX_ABDUCTION])
    prog.AddQuadraticErrorCost(1e-3 * np.eye(len(guess)), guess, q)
    prog.SetInitialGuess(q, guess)
    result = Solve(prog)
    if not result.is_success():
        raise RuntimeError(f"the pinch's hand IK failed ({result.get_solver_id().name()}) for {targets.round(4)}")
    return result.GetSolution(q)


class ScriptedToolPinch:
    """The scripted pinch pickup (see the module docstring): :meth:`act` of the observation and the step only.

    Args:
        grip: where the handle is pinched (the hammer's by default; :meth:`for_object` binds a tool's).
        p_PalmA: where the palm holds the grasp point [m], palm frame.
        spread: the index and middle tips sit this far [m] either side of the grasp point along the handle.
        phi: the contacts' angle below the handle's equator [rad].
        gaps: the closing's tip offsets from the handle [m], pre-grasp first, the contact shape (0) last.
        force, thumb_ratio: the squeeze per finger [N], and the thumb's as a multiple of it.
        abduction_above, abduction_limit: above this yaw [rad] the index abduction stays within the limit [rad].
        z_up: the hand-centre goal's height over the grasp while the pre-grasp forms [m].
        pre_at, pre_steps, close_at, close_steps, lift_at: the schedule's steps.
        gain, damping, descend_xy, funnel: the wrist law, as ``ScriptedToolGrasp``'s.
    """

    def __init__(self, grip: HandleGrip = TOOL_GRIPS["hammer"], p_PalmA=(0.065, 0.045, 0.165), spread=0.025,
                 phi=0.7, gaps=(0.03, 0.015, 0.0),
                 force=2.0, thumb_ratio=2.5, abduction_above=0.35, abduction_limit=0.2, z_up=0.10, pre_at=2,
                 pre_steps=8, close_at=34, close_steps=12, lift_at=50, gain=0.4, damping=1.0, descend_xy=0.006,
                 funnel=10.0):
        self.grip, self.p_PalmA, self.spread, self.phi = grip, np.asarray(p_PalmA, float), spread, phi
        self._options = dict(p_PalmA=p_PalmA, spread=spread, phi=phi, gaps=gaps, force=force, thumb_ratio=thumb_ratio,
                             abduction_above=abduction_above, abduction_limit=abduction_limit, z_up=z_up,
                             pre_at=pre_at, pre_steps=pre_steps, close_at=close_at, close_steps=close_steps,
                             lift_at=lift_at, gain=gain, damping=damping, descend_xy=descend_xy, funnel=funnel)
        self.gaps, self.thumb_ratio = tuple(gaps), thumb_ratio
        self.force = force if grip.force is None else grip.force
        self.abduction_above, self.abduction_limit = abduction_above, abduction_limit
        self.z_up, self.pre_at, self.pre_steps = z_up, pre_at, pre_steps
        self.close_at, self.close_steps, self.lift_at = close_at, close_steps, lift_at
        self.gain, self.damping, self.descend_xy, self.funnel = gain, damping, descend_xy, funnel
        self._plant = MakeHandPlant()
        self._bound: dict[str, ScriptedToolPinch] = {}
        self._shapes: dict[int, tuple[np.ndarray, ...]] = {}

    def reset(self, env) -> None:
        pass

    def for_object(self, name: str) -> ScriptedToolPinch:
        """This pinch with tool ``name``'s grip (``TOOL_GRIPS``); the residual hook ``bind_base`` calls it when the
        env's target is set (the observation does not say which tool lies there)."""
        if name not in TOOL_GRIPS:
            raise ValueError(f"the tool pinch has no grip for {name!r}; it knows {', '.join(TOOL_GRIPS)}")
        if name not in self._bound:  # Kept: a bound pinch keeps its planned shapes across episodes.
            self._bound[name] = ScriptedToolPinch(TOOL_GRIPS[name], **self._options)
        return self._bound[name]

    def tip_targets(self, yaw: float, gap: float) -> np.ndarray:
        """(3, 3) index, middle and thumb tip-centre targets in the palm frame for handle yaw ``yaw``, ``gap`` off
        the handle along its horizontal normal."""
        a = np.array([-np.sin(yaw), np.cos(yaw), 0.0])  # Along the handle, toward the head.
        n = np.array([np.cos(yaw), np.sin(yaw), 0.0])  # Its horizontal normal, away from the wrist.
        half_x, half_z = self.grip.half_width, self.grip.half_height
        d = (half_x + FINGERTIP_RADIUS) * np.cos(self.phi) + gap
        down = np.array([0.0, 0.0, -(half_z + FINGERTIP_RADIUS) * np.sin(self.phi)])
        offsets = (d * n + self.spread * a + down, d * n - self.spread * a + down, -d * n + down)
        return np.array([self.p_PalmA + R_PalmW @ offset for offset in offsets])

    def pinch_shapes(self, yaw_key: int) -> tuple[np.ndarray, ...]:
        """The closing's hand targets for yaw ``yaw_key`` / 100 rad: one shape per gap, then the squeeze (planned
        once per key: a few keys an episode, each a deterministic solve from the same initial guess)."""
        if yaw_key not in self._shapes:
            self._shapes[yaw_key] = self._plan(yaw_key / 100.0)
        return self._shapes[yaw_key]

    def _plan(self, yaw: float) -> tuple[np.ndarray, ...]:
        limit = self.abduction_limit if yaw > self.abduction_above else None
        shapes, guess = [], _NOMINAL_Q
        for gap in self.gaps:
            guess = _hand_ik(self._plant, self.tip_targets(yaw, gap), guess, limit)
            shapes.append(guess)
        context = self._plant.CreateDefaultContext()
        self._plant.SetPositions(context, shapes[-1])
        n = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        up = np.array([0.0, 0.0, np.sin(self.phi)])
        press = {0: self.force * (up - np.cos(self.phi) * n), 1: self.force * (up - np.cos(self.phi) * n),
                 3: self.thumb_ratio * self.force * (up + np.cos(self.phi) * n)}  # Forces on the handle, world.
        tau = np.zeros(16)
        for digit, f_W in press.items():
            J = self._plant.CalcJacobianTranslationalVelocity(
                context, JacobianWrtVariable.kV, self._plant.GetFrameByName(FINGERTIP_FRAMES[digit]), np.zeros(3),
                self._plant.world_frame(), self._plant.world_frame())
            tau += J.T @ (R_PalmW @ f_W)
        shapes.append(np.clip(shapes[-1] + tau / HAND_KP, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX))
        return tuple(shapes)

    def grasp_point_and_yaw(self, observation) -> tuple[np.ndarray, float]:
        """The grasp point (world) and the handle's yaw (its heading about world z, within +-0.8 rad)."""
        R_WT = rotation_matrix(observation[114:118])
        p_WA = np.asarray(observation[111:114], float) + R_WT @ [0.0, self.grip.y, self.grip.z]
        yaw = float(np.arctan2(-R_WT[0, 1], R_WT[1, 1]))
        return p_WA, min(max(yaw, -0.8), 0.8)

    def planned_yaw_key(self, observation, step: int, yaw: float) -> int:
        """The yaw key the hand's targets follow at ``step``: the tool's observed ``yaw``'s until the jaws start
        closing; from ``close_at`` on, the key whose plan the hand was sent at the step before (read back from the
        observation's previous action, searched within ``PLAN_SEARCH`` keys of the observed yaw's), so that a tool
        turning in the hand does not drag the plan, and the fingers, with it. Where no plan of this pinch was sent
        (a state another controller left), the observed yaw's. The observation carries the choice: the action
        stays a function of the observation and the step."""
        key = int(round(yaw * 100))
        if step < self.close_at:
            return key
        previous = np.asarray(observation[PREVIOUS_ACTION][:16], dtype=float)
        for offset in range(PLAN_SEARCH + 1):
            for candidate in (key - offset, key + offset)[offset == 0:]:
                if abs(candidate) <= YAW_KEY_LIMIT and np.max(np.abs(
                        self.hand_action(self.pinch_shapes(candidate), step - 1) - previous)) < PLAN_MATCH:
                    return candidate
        return key

    def hand_action(self, shapes: tuple[np.ndarray, ...], step: int) -> np.ndarray:
        """The hand part of :meth:`act`'s action at ``step`` for the plan ``shapes``."""
        q = self.hand_q(shapes, min(step, LIFT_END - 1))
        return np.clip(unscale_limits_to_action(np.clip(q, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX)), -1.0, 1.0)

    def hand_q(self, shapes: tuple[np.ndarray, ...], step: int) -> np.ndarray:
        """The hand's joint targets at ``step``: open, to the pre-grasp, closing, squeezed."""
        if step < self.pre_at:
            return ALLEGRO_OPEN_Q.copy()
        if step < self.close_at:
            s = min(1.0, (step - self.pre_at + 1) / self.pre_steps)
            return ALLEGRO_OPEN_Q + (shapes[0] - ALLEGRO_OPEN_Q) * s
        s = min(1.0, (step - self.close_at + 1) / self.close_steps) * (len(shapes) - 1)
        k = min(int(s), len(shapes) - 2)
        return shapes[k] + (shapes[k + 1] - shapes[k]) * (s - k)

    def act(self, observation, step: int) -> np.ndarray:
        """The action for ``observation`` (the env's, 159 or 160 entries) at ``step``."""
        o = np.asarray(observation, dtype=float)
        p_WA, yaw = self.grasp_point_and_yaw(o)
        hand_action = self.hand_action(self.pinch_shapes(self.planned_yaw_key(o, step, yaw)), step)
        if step >= LIFT_END:
            wrist = np.zeros(3)
        elif step >= self.lift_at:
            wrist = np.array([0.0, 0.0, 1.0])
        elif step >= self.close_at:
            wrist = np.zeros(3)
        else:
            R_WP = rotation_matrix(o[101:105])
            hand = o[98:101] + R_WP @ p_PalmHc_Palm
            goal = p_WA - R_WP @ (self.p_PalmA - p_PalmHc_Palm)
            d_xy = float(np.linalg.norm(goal[:2] - hand[:2]))
            z_up = goal[2] + self.z_up
            z = z_up if step < self.pre_at + self.pre_steps else max(
                goal[2], min(z_up, goal[2] + self.funnel * (d_xy - self.descend_xy)))
            velocity = o[105:108] / CONTROL_RATE  # Palm displacement per step.
            wrist = np.clip((self.gain * (np.r_[goal[:2], z] - hand) - self.damping * velocity) / WRIST_STEP, -1, 1)
        return np.clip(np.r_[hand_action, wrist], -1.0, 1.0)

    def action(self, env, step: int) -> np.ndarray:
        return self.act(env.raw_observation(), step)
