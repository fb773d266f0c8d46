"""A scripted tripod grasp for the Allegro hand: hand shapes by inverse kinematics, squeeze targets, arm IK.

The grasp. The block's two parallel side faces, ``width`` apart, are held between the thumb tip on one face
and the index and middle tips side by side (``±spread`` along the palm's y) on the other. All three contact
normals are parallel to the palm's +z (wrist -> fingertips), so the thumb opposes the two fingers along one
line of action and the grasp is in force balance when the thumb pushes twice as hard as each finger.

Why this grasp. With point contact, a two-sphere pinch on a flat-sided block squeezed the block out in our
trials: the fingers' closing arcs are not along the face normal, so position targets past contact ask for
tangential force that friction cannot give, and nothing balances the two tip forces. Here the squeeze is
commanded in force: the PD targets are the contact shape plus ``(J^T F - tau_g) / kp`` (``SqueezeTargets``),
so at rest each fingertip presses about ``F`` along the face normal, with gravity on the fingers compensated.
The contact shape keeps the index and middle distal phalanges steep (``DISTAL_CHECK_HEIGHT``) so that only the
fingertip spheres, not the phalanges, land on the block; the pre-grasp shape puts every tip ``gap`` straight
out from its face at the contact height, so closing (a joint-space ramp) brings the tips onto the faces.
Neither IK checks collisions with the block: the test (tests/test_grasp_hold.py) checks the contacts.

Frames: ``palm`` (see ``seqdex_drake.robots.allegro``): +z wrist -> fingertips, +x palm normal out of the
palm, +y ring -> index. The grasp centre C is the point midway between the two faces at the contact height;
``p_PalmC`` is where the hand holds it. At the arm's home orientation (palm down, fingers along world +x) the
faces must be normal to world x, i.e. a block's short axis along world x.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable, ModelInstanceIndex
from pydrake.solvers import Solve
from pydrake.systems.framework import Context

from seqdex_drake.robots.allegro import (
    ALLEGRO_JOINT_NAMES,
    ALLEGRO_MODEL_URL,
    ALLEGRO_OPEN_Q,
    ALLEGRO_Q_MAX,
    ALLEGRO_Q_MIN,
    FINGERTIP_FRAMES,
    FINGERTIP_RADIUS,
    HAND_ROOT_FRAME,
    PALM_BODY,
)
from seqdex_drake.station import MakeParser

DEFAULT_P_PALM_C = np.array([0.08, 0.012, 0.165])
"""Default grasp centre in the palm frame [m]: 0.06 m in front of the palm face, between the index and middle
fingers' planes, 0.165 m from the wrist. There the thumb and the two fingers reach the faces of a 0.03 m block
with steep distal phalanges (farther from the wrist, e.g. 0.185 m, they cannot) and a 0.0575 m block's top,
with C 0.02 m above its bottom, stays 0.02 m below the palm."""

TRIPOD_DIGITS = (0, 1, 3)
"""Fingertips used (canonical finger order): index, middle, thumb. The ring finger stays straight."""

DISTAL_CHECK_HEIGHT = 0.025
"""The index and middle distal phalanges are kept steep: their axis point this far [m] above the fingertip
centre (toward the finger's middle joint) stays at least FINGERTIP_RADIUS outside the face plane, so only the
fingertip spheres touch the face; a slanted phalanx would otherwise land on the block's top edge first."""

_NOMINAL_Q = np.array([0.0, 0.6, 0.6, 0.6] * 2 + [0.0] * 4 + [1.2, 0.4, 0.4, 0.4])
"""Initial guess and cost centre of the contact-shape IK: fingers half curled, thumb in front of the palm."""


@dataclasses.dataclass
class TripodGrasp:
    """Hand shapes of a tripod grasp on faces ``width`` apart, centred at ``p_PalmC`` in the palm frame."""

    hand_q: np.ndarray
    """Contact shape [rad]: the fingertip spheres just touch the faces (canonical joint order)."""
    pregrasp_q: np.ndarray
    """Open shape [rad]: each tip ``gap`` farther from its face along the normal, at the same height."""
    p_PalmC: np.ndarray
    """Grasp centre in the palm frame [m]."""
    width: float
    """Distance between the two grasped faces [m]."""
    spread: float
    """Index and middle tips sit at ``p_PalmC ± spread`` along the palm's y [m]."""

    def tip_targets(self, gap: float = 0.0) -> np.ndarray:
        """(3, 3) index, middle and thumb fingertip-centre positions in the palm frame, ``gap`` off the faces."""
        d = 0.5 * self.width + FINGERTIP_RADIUS + gap
        return self.p_PalmC + np.array([[0.0, self.spread, d], [0.0, -self.spread, d], [0.0, 0.0, -d]])


def MakeHandPlant() -> MultibodyPlant:
    """The Allegro hand alone, ``hand_root`` welded to the world (so the palm frame is the world frame)."""
    plant = MultibodyPlant(0.0)
    MakeParser(plant).AddModels(url=ALLEGRO_MODEL_URL)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(HAND_ROOT_FRAME))
    plant.Finalize()
    return plant


def _solve_hand_ik(plant: MultibodyPlant, targets: np.ndarray, fixed: dict[int, float], q_center: np.ndarray,
                   tolerance: float, steep: bool) -> np.ndarray:
    """Hand positions putting the tripod tips at ``targets`` (palm frame), joints in ``fixed`` pinned and,
    if ``steep``, the index and middle distal phalanges steep (see DISTAL_CHECK_HEIGHT)."""
    context = plant.CreateDefaultContext()
    ik = InverseKinematics(plant, context)
    q = ik.q()
    for digit, p_target in zip(TRIPOD_DIGITS, targets, strict=True):
        tip = plant.GetFrameByName(FINGERTIP_FRAMES[digit])
        ik.AddPositionConstraint(tip, np.zeros(3), plant.world_frame(), p_target - tolerance, p_target + tolerance)
        if steep and digit != 3:  # The tip centre is FINGERTIP_RADIUS outside the far face (+z).
            lower = np.array([-np.inf, -np.inf, p_target[2]])
            ik.AddPositionConstraint(tip, [0.0, 0.0, -DISTAL_CHECK_HEIGHT], plant.world_frame(), lower,
                                     np.full(3, np.inf))
    prog = ik.get_mutable_prog()
    for joint, value in fixed.items():
        prog.AddBoundingBoxConstraint(value, value, q[joint])
    prog.AddQuadraticErrorCost(np.eye(len(q_center)), q_center, q)
    prog.SetInitialGuess(q, q_center)
    result = Solve(prog)
    if not result.is_success():
        raise RuntimeError(f"tripod grasp IK failed ({result.get_solver_id().name()}): targets {targets.round(4)}")
    return result.GetSolution(q)


def SolveTripodGrasp(width: float, spread: float = 0.015, p_PalmC: np.ndarray = DEFAULT_P_PALM_C,
                     gap: float = 0.02, tolerance: float = 2e-4) -> TripodGrasp:
    """Computes the contact and pre-grasp hand shapes for faces ``width`` apart (e.g. a block's 0.03 m side).

    The hand joints are in canonical order and use the generated model's kinematics. Every position is
    within the joint limits; the ring finger stays straight (``ALLEGRO_OPEN_Q``). ``spread`` must keep the
    two finger spheres apart (> FINGERTIP_RADIUS) and on the face (<= half the face length minus a margin).
    """
    plant = MakeHandPlant()
    grasp = TripodGrasp(np.zeros(16), np.zeros(16), np.asarray(p_PalmC, dtype=float), width, spread)
    ring = {j: ALLEGRO_OPEN_Q[j] for j in range(8, 12)}
    grasp.hand_q = _solve_hand_ik(plant, grasp.tip_targets(), ring, _NOMINAL_Q, tolerance, steep=True)
    grasp.pregrasp_q = _solve_hand_ik(plant, grasp.tip_targets(gap), ring, grasp.hand_q, tolerance, steep=False)
    return grasp


def SqueezeTargets(plant: MultibodyPlant, context: Context, grasp: TripodGrasp, force: float,
                   kp: float) -> np.ndarray:
    """PD position targets that make the index and middle tips press ``force`` [N] and the thumb ``2 force``.

    ``context`` is the station plant's context with the arm where the grasp happens (it sets the direction
    of gravity in the hand). Returns ``hand_q + (J^T F - tau_g) / kp`` clipped to the joint limits, where J
    are the fingertip Jacobians in the palm frame at ``grasp.hand_q``, F the forces on the block along the
    palm's z (fingers toward the wrist, thumb toward the fingertips) and tau_g the gravity torques on the
    hand joints, for joint PD stiffness ``kp`` [N m/rad] (the scenario's ``robot.hand_kp``).
    """
    hand = plant.GetModelInstanceByName("allegro")
    work = plant.CreateDefaultContext()
    plant.SetPositions(work, plant.GetPositions(context))
    plant.SetPositions(work, hand, grasp.hand_q)
    palm = plant.GetBodyByName(PALM_BODY, hand).body_frame()
    v_hand = [plant.GetJointByName(name, hand).velocity_start() for name in ALLEGRO_JOINT_NAMES]
    tau = -plant.CalcGravityGeneralizedForces(work)[v_hand]
    for digit, sign in zip(TRIPOD_DIGITS, (-1.0, -1.0, 2.0), strict=True):
        J = plant.CalcJacobianTranslationalVelocity(work, JacobianWrtVariable.kV,
                                                    plant.GetFrameByName(FINGERTIP_FRAMES[digit], hand),
                                                    np.zeros(3), palm, palm)
        tau += J[:, v_hand].T @ np.array([0.0, 0.0, sign * force])
    return np.clip(grasp.hand_q + tau / kp, ALLEGRO_Q_MIN, ALLEGRO_Q_MAX)


def SolveArmForPalm(plant: MultibodyPlant, context: Context, arm: ModelInstanceIndex, p_PalmC: np.ndarray,
                    X_WTarget: RigidTransform, q_guess: np.ndarray, tolerance: float = 1e-4,
                    angle_tolerance: float = 1e-3) -> np.ndarray:
    """Arm joint positions that put the palm point ``p_PalmC`` at ``X_WTarget``'s origin with the palm
    oriented as ``X_WTarget``, closest to ``q_guess``. All other positions stay as in ``context``."""
    hand = plant.GetModelInstanceByName("allegro")
    palm = plant.GetBodyByName(PALM_BODY, hand).body_frame()
    ik = InverseKinematics(plant, plant.CreateDefaultContext())
    p = X_WTarget.translation()
    ik.AddPositionConstraint(palm, p_PalmC, plant.world_frame(), p - tolerance, p + tolerance)
    ik.AddOrientationConstraint(palm, RotationMatrix(), plant.world_frame(), X_WTarget.rotation(), angle_tolerance)
    prog = ik.get_mutable_prog()
    q = ik.q()
    q_all = plant.GetPositions(context).copy()
    # The arm's entries of the full position vector, in the arm's own order.
    arm_index = plant.GetPositionsFromArray(arm, np.arange(plant.num_positions(), dtype=float)).astype(int)
    others = np.setdiff1d(np.arange(plant.num_positions()), arm_index)
    prog.AddBoundingBoxConstraint(q_all[others], q_all[others], q[others])
    prog.AddQuadraticErrorCost(np.eye(len(arm_index)), q_guess, q[arm_index])
    q_all[arm_index] = q_guess
    prog.SetInitialGuess(q, q_all)
    result = Solve(prog)
    if not result.is_success():
        raise RuntimeError(f"arm IK failed ({result.get_solver_id().name()}) for the palm target {p.round(4)}")
    return result.GetSolution(q)[arm_index]


@dataclasses.dataclass
class PickupPlan:
    """Arm and hand PD targets of a scripted pickup: descend open, squeeze, lift."""

    arm_above: np.ndarray
    """Arm positions with the grasp centre ``approach`` above its grasp position [rad]."""
    arm_grasp: np.ndarray
    """Arm positions with the palm's grasp centre at the block's grasp centre [rad]."""
    arm_lift: np.ndarray
    """Arm positions with the grasp centre ``lift`` above its grasp position [rad]."""
    hand_open: np.ndarray
    """The pre-grasp hand shape [rad]."""
    hand_squeeze: np.ndarray
    """Hand PD targets that squeeze the block (``SqueezeTargets``) [rad]."""


def PlanTripodPickup(plant: MultibodyPlant, context: Context, grasp: TripodGrasp, p_WC: np.ndarray,
                     R_WPalm: RotationMatrix, force: float, kp: float, approach: float = 0.06,
                     lift: float = 0.15, q_guess: np.ndarray | None = None) -> PickupPlan:
    """Plans a vertical pickup of a block whose grasp centre is at ``p_WC`` with the palm at ``R_WPalm``.

    ``context`` is the station plant's context (objects where they are; the arm's current positions are the
    IK's default guess). The squeeze targets are computed with the arm at its grasp positions.
    """
    arm = plant.GetModelInstanceByName("franka")
    hand = plant.GetModelInstanceByName("allegro")
    q_guess = plant.GetPositions(context, arm) if q_guess is None else np.asarray(q_guess, dtype=float)
    p_WC = np.asarray(p_WC, dtype=float)

    def solve(height: float, guess: np.ndarray) -> np.ndarray:
        return SolveArmForPalm(plant, context, arm, grasp.p_PalmC,
                               RigidTransform(R_WPalm, p_WC + [0.0, 0.0, height]), guess)

    arm_grasp = solve(0.0, q_guess)
    work = plant.CreateDefaultContext()
    plant.SetPositions(work, plant.GetPositions(context))
    plant.SetPositions(work, arm, arm_grasp)
    plant.SetPositions(work, hand, grasp.hand_q)
    return PickupPlan(arm_above=solve(approach, arm_grasp), arm_grasp=arm_grasp, arm_lift=solve(lift, arm_grasp),
                      hand_open=grasp.pregrasp_q.copy(),
                      hand_squeeze=SqueezeTargets(plant, work, grasp, force, kp))


def _smoothstep(s: float) -> float:
    return s * s * (3.0 - 2.0 * s)


def RampTargets(harness, ticks: int, arm: tuple[np.ndarray, np.ndarray] | None = None,
                hand: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Steps a :class:`~seqdex_drake.harness.StationHarness` ``ticks`` control periods while moving the arm
    and/or hand PD targets from ``start`` to ``end`` (pairs) along a smoothstep in joint space."""
    for k in range(ticks):
        s = _smoothstep((k + 1) / ticks)
        harness.set_targets(arm_q=None if arm is None else (1.0 - s) * arm[0] + s * arm[1],
                            hand_q=None if hand is None else (1.0 - s) * hand[0] + s * hand[1])
        harness.step(1)


def ExecuteGrasp(harness, plan: PickupPlan, descend_ticks: int = 30, close_ticks: int = 30,
                 settle_ticks: int = 20) -> None:
    """Runs the grasp part of ``plan`` on a :class:`~seqdex_drake.harness.StationHarness` whose block
    already rests, dynamic, at the grasp position: puts the arm at ``arm_above`` with the hand open, at rest
    (state and targets), descends, closes and lets the squeeze settle (durations in control ticks, 60 per
    second). Lift with ``RampTargets(harness, ticks, arm=(plan.arm_grasp, plan.arm_lift))``."""
    plant = harness.objects.plant
    plant_context = plant.GetMyMutableContextFromRoot(harness.context)
    for name, q in (("franka", plan.arm_above), ("allegro", plan.hand_open)):
        instance = plant.GetModelInstanceByName(name)
        plant.SetPositions(plant_context, instance, q)
        plant.SetVelocities(plant_context, instance, np.zeros(len(q)))
    harness.set_targets(arm_q=plan.arm_above, hand_q=plan.hand_open)
    RampTargets(harness, descend_ticks, arm=(plan.arm_above, plan.arm_grasp))
    RampTargets(harness, close_ticks, hand=(plan.hand_open, plan.hand_squeeze))
    harness.step(settle_ticks)
