"""Small systems the chain controller wires between the policies, the switcher, the OSC and the station.

- :class:`StageRouter`: enables the executing stage's policy and routes its commands to the hand.
- :class:`ApproachTarget`: the point the approach controller hovers over (the target object, or the goal for
  stages with a goal pose), from the chain's :class:`~seqdex_drake.sensors.observations.ObservationTarget`.
- :class:`WristTargetIntegrator`: the arm's PD targets: the OSC command while it is in charge, else the wrist
  translation integrated by damped least-squares IK from the previous arm *target* (as the environments do).
- :class:`ChainMarker`: an optional Meshcat sphere at the approach target, coloured by the executing stage.

Timing. Every system ticks at the control period with offset 0, so all read the values held before the tick.
The router latches the stage the switcher chose at the previous tick; its ``enable.<i>`` outputs give the
policies the same stage, so the routed commands always come from the policy that just ran. A stage chosen at
tick k therefore acts from tick k + 1 (one control period of switching latency).
"""

from __future__ import annotations

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.common.value import AbstractValue
from pydrake.geometry import Rgba, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, EventStatus, LeafSystem

from seqdex_drake.control.osc import turned_orientation
from seqdex_drake.controller.policy import ACTION_SIZE, HAND_SIZE
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.sensors.observations import ObservationTarget
from seqdex_drake.tasks.carry import CARRY_REACH, MAX_CARRY_TURN, nearest_equivalent
from seqdex_drake.tasks.tools_common import HELD_LIFT

NUM_ARM = 7
_STAGE_COLORS = [Rgba(0.9, 0.3, 0.2, 0.8), Rgba(0.95, 0.75, 0.1, 0.8), Rgba(0.2, 0.7, 0.3, 0.8),
                 Rgba(0.2, 0.45, 0.9, 0.8), Rgba(0.6, 0.3, 0.8, 0.8), Rgba(0.3, 0.8, 0.8, 0.8)]


class StageRouter(LeafSystem):
    """Enables one policy at a time and routes its held commands out.

    Input ports: ``stage`` (1, the switcher's ``active_stage``), ``approach_active`` (1, the OSC's flag),
    and per stage i: ``action.<i>``, ``raw_action.<i>`` (19), ``hand_target.<i>`` (16), ``wrist_translation.<i>``
    (3) from that stage's :class:`~seqdex_drake.controller.policy.PolicySystem`.

    Output ports: ``enable.<i>`` (1: stage i is chosen and no approach runs), the routed ``action``,
    ``raw_action``, ``hand_target``, ``wrist_translation``, ``allegro.desired_state`` (32: hand target, zero
    velocities), ``policy_in_charge`` (1) and ``executing_stage`` (1: the stage whose policy ran last tick).

    While the approach runs for a stage flagged in ``hold_hand`` (a carry: the hand holds the object the previous
    stage grasped), the router keeps routing the previous stage's commands, so the hand stays closed; otherwise it
    routes the chosen stage's (its policy's held initial command: the hand as the episode started).

    Args:
        num_stages: K.
        control_period: seconds between updates.
        hold_hand: per stage, whether its approach keeps the previous stage's hand (default: none).
    """

    def __init__(self, num_stages: int, control_period: float, hold_hand=None):
        super().__init__()
        self.num_stages = int(num_stages)
        self._hold_hand = [False] * self.num_stages if hold_hand is None else [bool(h) for h in hold_hand]
        if len(self._hold_hand) != self.num_stages:
            raise ValueError(f"hold_hand needs one flag per stage ({self.num_stages}), got {hold_hand}")
        self._stage_port = self.DeclareVectorInputPort("stage", 1)
        self._approach_port = self.DeclareVectorInputPort("approach_active", 1)
        self._ports = {name: [self.DeclareVectorInputPort(f"{name}.{i}", size) for i in range(num_stages)]
                       for name, size in (("action", ACTION_SIZE), ("raw_action", ACTION_SIZE),
                                          ("hand_target", HAND_SIZE), ("wrist_translation", 3))}
        self._state_index = self.DeclareDiscreteState(np.zeros(2))  # executing stage, policy in charge
        state = self.discrete_state_ticket(self._state_index)
        choice = {self._stage_port.ticket(), self._approach_port.ticket()}
        for i in range(num_stages):
            self.DeclareVectorOutputPort(f"enable.{i}", 1, lambda context, output, i=i: self._calc_enable(
                context, output, i), prerequisites_of_calc=choice)
        for name, ports in self._ports.items():
            tickets = {state} | {port.ticket() for port in ports}
            self.DeclareVectorOutputPort(name, ports[0].size(), lambda context, output, name=name: output.SetFromVector(
                self._routed(context, name)), prerequisites_of_calc=tickets)
        hand_tickets = {state} | {port.ticket() for port in self._ports["hand_target"]}
        self.DeclareVectorOutputPort("allegro.desired_state", 2 * HAND_SIZE, self._calc_hand_state,
                                     prerequisites_of_calc=hand_tickets)
        self.DeclareVectorOutputPort("policy_in_charge", 1, lambda context, output: output.SetAtIndex(
            0, context.get_discrete_state(self._state_index).GetAtIndex(1)), prerequisites_of_calc={state})
        self.DeclareVectorOutputPort("executing_stage", 1, lambda context, output: output.SetAtIndex(
            0, context.get_discrete_state(self._state_index).GetAtIndex(0)), prerequisites_of_calc={state})
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, 0.0, self._update)

    def _choice(self, context: Context) -> tuple[int, bool]:
        stage = int(round(self._stage_port.Eval(context)[0]))
        if not 0 <= stage < self.num_stages:
            raise RuntimeError(f"StageRouter: stage {stage} is outside 0..{self.num_stages - 1}")
        return stage, self._approach_port.Eval(context)[0] < 0.5

    def _calc_enable(self, context: Context, output: BasicVector, i: int) -> None:
        stage, in_charge = self._choice(context)
        output.SetAtIndex(0, float(in_charge and stage == i))

    def _routed(self, context: Context, name: str) -> np.ndarray:
        stage = int(context.get_discrete_state(self._state_index).GetAtIndex(0))
        return self._ports[name][stage].Eval(context)

    def _calc_hand_state(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(np.concatenate((self._routed(context, "hand_target"), np.zeros(HAND_SIZE))))

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        discrete_state.set_value(self._state_index, np.zeros(2))

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        stage, in_charge = self._choice(context)
        if not in_charge and self._hold_hand[stage]:  # A carry: the previous stage's hand holds the object.
            stage = int(context.get_discrete_state(self._state_index).GetAtIndex(0))
        discrete_state.set_value(self._state_index, np.array([stage, float(in_charge)]))




class ApproachTarget(LeafSystem):
    """The approach controller's target: the goal position for stages with a goal pose, else the target
    object's centre of mass plus the target's ``approach_offset`` (world, m).

    A *carry* stage (``carry_heights[i]`` finite, a stage with a goal) instead aims so that the held object's origin
    comes to ``carry_height`` above its goal: the target is ``goal + carry_height z + (p_WC - p_WO) - hover_height
    z``, with p_WC the approach's controlled point (``hand``: the palm body and the point's offset in it) and p_WO
    the object's origin, so the approach's hover point (target + ``hover_height`` z) puts the object there. An
    object farther than ``CARRY_REACH`` from the controlled point is not in hand: the target is then the goal.

    With a ``goal_symmetry`` the carry also turns the hand until the held object takes its goal's orientation (the
    goal counting the same turned about its own z by multiples of that angle: pi for a block). Output
    ``hold_rotation`` (a 3x3 rotation, row-major) is then R_off = R_WG' R_WO^T R_WPalm R_WP_hold^T, R_WG' the goal's
    equivalent nearest the object's: the turn of the held orientation (``R_WP_hold``, the one the approach and the
    wrist IK otherwise hold) that brings the object to R_WG' if it moves with the palm. It stays constant while a
    rigidly held object turns with the hand, and is the identity in other stages, whenever the object is not in
    hand, and for a turn over ``MAX_CARRY_TURN``. The policies' wrist actions are translations, so without it a block
    that Grasp's jaws turned 10-15 deg in the pinch, or tilted along its length, comes down with its tubes on the
    plate's stud tops.

    Output ``object_lifted`` (1) is 1 while the target object's centre of mass is more than ``lifted_above`` over
    the height it rested at (the target's ``rest_height``; never with NaN): the object is in hand, not where a
    stage that picks it up can start (``SwitcherParams.free_object_stages``).

    Input ports: ``body_poses`` (the station's), ``stage`` (1). Output ports: ``target_position`` (3),
    ``hold_rotation`` (9), ``object_lifted`` (1). The chain target is an abstract parameter (:meth:`set_target`),
    shared with the observation assemblers.

    Args:
        plant: the station's plant (body centres of mass; not kept).
        stage_has_goal: per stage, whether its target is the goal pose (Insert, tool Reorient).
        carry_heights: per stage, the carry height (m) or NaN (no carry); default: no carry.
        hand: ``(palm body index, p_PalmC_Palm, hover_height)`` of the approach, needed with carry stages.
        goal_symmetry: turns [rad] about the goal's z that leave it the same, for the carry's orientation; 0: the
            carry does not turn the hand.
        R_WP_hold: the palm orientation held otherwise, needed with a ``goal_symmetry``.
        lifted_above: how far (m) over its rest height the object counts as lifted (default: the tasks'
            ``tools_common.HELD_LIFT``, as tool Reorient's success and the chain runner judge it).
    """

    def __init__(self, plant: MultibodyPlant, stage_has_goal: list[bool], carry_heights=None, hand=None,
                 goal_symmetry: float = 0.0, R_WP_hold: RotationMatrix | None = None,
                 lifted_above: float = HELD_LIFT):
        super().__init__()
        self._lifted_above = float(lifted_above)
        self._p_BoBcm = [plant.get_body(BodyIndex(i)).default_com() for i in range(plant.num_bodies())]
        self._has_goal = [bool(g) for g in stage_has_goal]
        self._carry = np.full(len(self._has_goal), np.nan) if carry_heights is None else \
            np.asarray(carry_heights, dtype=float)
        carried = np.isfinite(self._carry)
        if len(self._carry) != len(self._has_goal) or np.any(carried & ~np.asarray(self._has_goal, dtype=bool)):
            raise ValueError(f"carry_heights needs one entry per stage, finite only for stages with a goal; got "
                             f"{carry_heights} for stages with goals {self._has_goal}")
        if np.any(carried) and hand is None:
            raise ValueError("carry stages need hand = (palm body index, p_PalmC_Palm, hover_height)")
        self._hand = None if hand is None else (int(hand[0]), np.asarray(hand[1], dtype=float), float(hand[2]))
        if not (np.isfinite(goal_symmetry) and goal_symmetry >= 0.0):
            raise ValueError(f"goal_symmetry must be a finite angle >= 0 (rad), got {goal_symmetry}")
        if goal_symmetry > 0.0 and R_WP_hold is None:
            raise ValueError("a goal_symmetry needs R_WP_hold, the palm orientation the approach otherwise holds")
        turns = max(1, int(round(2 * np.pi / goal_symmetry))) if goal_symmetry > 0.0 else 0
        self._goal_turns = [RotationMatrix.MakeZRotation(k * 2 * np.pi / turns) for k in range(turns)]
        self._R_PW_hold = None if R_WP_hold is None else R_WP_hold.inverse()
        default_poses = [RigidTransform()] * plant.num_bodies()
        self._poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make(default_poses))
        self._stage_port = self.DeclareVectorInputPort("stage", 1)
        self._target_index = self.DeclareAbstractParameter(AbstractValue.Make(ObservationTarget()))
        self.DeclareVectorOutputPort("target_position", 3, self._calc)
        self.DeclareVectorOutputPort("hold_rotation", 9, self._calc_rotation)
        self.DeclareVectorOutputPort("object_lifted", 1, self._calc_lifted)

    def set_target(self, context: Context, target: ObservationTarget) -> None:
        if not 0 <= target.object_body < len(self._p_BoBcm):
            raise ValueError(f"target body index {target.object_body} is not a body of the station's plant "
                             f"(0..{len(self._p_BoBcm) - 1})")
        context.get_mutable_abstract_parameter(self._target_index).set_value(target)

    def target(self, context: Context) -> ObservationTarget:
        return context.get_abstract_parameter(self._target_index).get_value()

    def _calc(self, context: Context, output: BasicVector) -> None:
        target = self.target(context)
        if target.object_body < 0:
            raise RuntimeError("the chain has no target: call SetChainTarget(controller, root_context, body) "
                               "before simulating")
        stage = int(round(self._stage_port.Eval(context)[0]))
        goal = np.asarray(target.goal, dtype=float)[:3]
        held = self._held(context, stage)
        if held is not None:  # Held: carry it. Not held: the goal, as without carry.
            X_WPalm, X_WO = held
            palm, p_PalmC, hover = self._hand
            p_OC = X_WPalm @ p_PalmC - X_WO.translation()
            output.SetFromVector(goal + [0.0, 0.0, self._carry[stage] - hover] + p_OC)
            return
        if self._has_goal[stage]:
            output.SetFromVector(goal)
            return
        X_WB = self._poses_port.Eval(context)[target.object_body]
        output.SetFromVector(X_WB @ self._p_BoBcm[target.object_body] + target.approach_offset)

    def _calc_lifted(self, context: Context, output: BasicVector) -> None:
        target = self.target(context)
        lifted = False
        if target.object_body >= 0 and np.isfinite(target.rest_height):
            X_WB = self._poses_port.Eval(context)[target.object_body]
            lifted = (X_WB @ self._p_BoBcm[target.object_body])[2] > target.rest_height + self._lifted_above
        output.SetAtIndex(0, float(lifted))

    def _held(self, context: Context, stage: int) -> tuple[RigidTransform, RigidTransform] | None:
        """(X_WPalm, X_WO) while carry stage ``stage`` has the target object in hand (its origin within
        ``CARRY_REACH`` of the controlled point), else None."""
        if not (self._has_goal[stage] and np.isfinite(self._carry[stage])):
            return None
        poses = self._poses_port.Eval(context)
        palm, p_PalmC, _ = self._hand
        X_WPalm, X_WO = poses[palm], poses[self.target(context).object_body]
        return (X_WPalm, X_WO) if np.linalg.norm(X_WPalm @ p_PalmC - X_WO.translation()) <= CARRY_REACH else None

    def _calc_rotation(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self.hold_rotation(context).matrix().ravel())

    def hold_rotation(self, context: Context) -> RotationMatrix:
        """R_off, the turn of the held palm orientation (see the class docstring)."""
        target = self.target(context)
        held = None
        if self._goal_turns and target.object_body >= 0:
            held = self._held(context, int(round(self._stage_port.Eval(context)[0])))
        if held is None:
            return RotationMatrix()
        X_WPalm, X_WO = held
        goal = np.asarray(target.goal, dtype=float)[3:]
        R_WG = RotationMatrix(Quaternion(goal / np.linalg.norm(goal)))
        R_err = nearest_equivalent(R_WG, X_WO.rotation(), self._goal_turns) @ X_WO.rotation().inverse()
        R_off = R_err @ X_WPalm.rotation() @ self._R_PW_hold
        return R_off if R_off.ToAngleAxis().angle() <= MAX_CARRY_TURN else RotationMatrix()


class WristTargetIntegrator(LeafSystem):
    """The arm's PD targets: the OSC's command, or the policy's wrist translation tracked by IK.

    While the policy is in charge the output is ``[q, (q - q_prev) / period]`` with
    ``q = ik.step(q_prev, p_WC(q_prev) + w, R_WP)``:
    one damped least-squares step from the previous arm *target* ``q_prev`` toward the hand centre moved by the
    routed wrist translation ``w``, palm orientation held. Otherwise it passes the OSC's ``franka.desired_state``
    through. The state is the target held during the last control period, so the integration continues from
    the OSC's last command when a policy takes over.

    The held orientation while the policy is in charge is ``R_off R_WP_hold`` with R_off the ``hold_rotation``
    input's value at the last tick before the policy took over, latched (state) until the approach is in charge
    again, as the sub-task env holds the palm orientation its carry left (``tasks/carry.py``): the carry's R_off
    follows the held block, and a block that turns in a compliant pinch while the wrist follows it made a feedback
    loop (traced in the whole chain: the palm swung at 1.5-2.9 rad/s through Insert's descent, the block turned
    +-20 deg in the jaws, and Insert never started to lower it).

    Input ports: ``franka.state`` (14, read at initialization), ``osc.desired_state`` (14),
    ``wrist_translation`` (3), ``policy_in_charge`` (1), ``hold_rotation`` (9, optional: the held orientation is
    R_off ``R_WP_hold``, R_off the input row-major, :class:`ApproachTarget`). Output port:
    ``franka.desired_state`` (14).

    Args:
        ik: the palm IK on the controller plant (controlled point: the hand centre).
        R_WP_hold: the palm orientation held while the policy moves the wrist.
        control_period: seconds between updates.
    """

    def __init__(self, ik: PalmIK, R_WP_hold: RotationMatrix, control_period: float):
        super().__init__()
        self._ik, self._R_WP, self._period = ik, R_WP_hold, float(control_period)
        self._state_port = self.DeclareVectorInputPort("franka.state", 2 * NUM_ARM)
        self._osc_port = self.DeclareVectorInputPort("osc.desired_state", 2 * NUM_ARM)
        self._wrist_port = self.DeclareVectorInputPort("wrist_translation", 3)
        self._in_charge_port = self.DeclareVectorInputPort("policy_in_charge", 1)
        self._turn_port = self.DeclareVectorInputPort("hold_rotation", 9)
        self._held = [None, R_WP_hold]
        self._q_index = self.DeclareDiscreteState(NUM_ARM)
        self._turn_index = self.DeclareDiscreteState(np.eye(3).ravel())  # R_off latched at the handover.
        tickets = {self.discrete_state_ticket(self._q_index), self.discrete_state_ticket(self._turn_index),
                   self._osc_port.ticket(), self._wrist_port.ticket(), self._in_charge_port.ticket()}
        self._output_port = self.DeclareVectorOutputPort("franka.desired_state", 2 * NUM_ARM, self._calc,
                                                         prerequisites_of_calc=tickets)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, 0.0, self._update)

    def _command(self, context: Context) -> np.ndarray:
        if self._in_charge_port.Eval(context)[0] < 0.5:
            return np.asarray(self._osc_port.Eval(context), dtype=float)
        q = context.get_discrete_state(self._q_index).get_value()
        p_WC = self._ik.palm_position(q) + self._wrist_port.Eval(context)
        turn = np.asarray(context.get_discrete_state(self._turn_index).get_value(), dtype=float)
        q_next = self._ik.step(q, p_WC, turned_orientation(turn, self._R_WP, self._held))
        # The target moves at (q_next - q) / period: fed forward as the desired velocity, as the sub-task env does
        # (without it the arm's heavily damped PD trails a moving wrist command by centimetres).
        return np.concatenate((q_next, (q_next - q) / self._period))

    def _calc(self, context: Context, output: BasicVector) -> None:
        output.SetFromVector(self._command(context))

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        discrete_state.set_value(self._q_index, self._state_port.Eval(context)[:NUM_ARM])
        discrete_state.set_value(self._turn_index, np.eye(3).ravel())

    def held_turn(self, context: Context) -> RotationMatrix:
        """R_off as latched now: the one the policy's wrist holds (the identity before any handover)."""
        return RotationMatrix(np.asarray(context.get_discrete_state(self._turn_index).get_value()).reshape(3, 3))

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        # The held output is exactly this tick's command and is usually cached (the station read it), so the
        # IK step is not solved twice per tick.
        discrete_state.set_value(self._q_index, self._output_port.Eval(context)[:NUM_ARM])
        if self._in_charge_port.Eval(context)[0] < 0.5:  # The approach's turn, followed until the policy takes over.
            discrete_state.set_value(self._turn_index, self._turn_port.Eval(context) if self._turn_port.HasValue(
                context) else np.eye(3).ravel())


class ChainMarker(LeafSystem):
    """Draws a sphere in Meshcat at the approach target, coloured by the executing stage.

    Input ports: ``target_position`` (3), ``stage`` (1).

    Args:
        meshcat: the Meshcat to draw in.
        publish_period: seconds between redraws.
        path: the Meshcat path of the sphere.
    """

    def __init__(self, meshcat, publish_period: float = 0.1, path: str = "chain/target"):
        super().__init__()
        self._meshcat, self._path, self._stage = meshcat, path, -1
        self._target_port = self.DeclareVectorInputPort("target_position", 3)
        self._stage_port = self.DeclareVectorInputPort("stage", 1)
        self.DeclarePeriodicPublishEvent(publish_period, 0.0, self._publish)

    def _publish(self, context: Context) -> EventStatus:
        stage = int(round(self._stage_port.Eval(context)[0]))
        if stage != self._stage:
            self._meshcat.SetObject(self._path, Sphere(0.012), _STAGE_COLORS[stage % len(_STAGE_COLORS)])
            self._stage = stage
        self._meshcat.SetTransform(self._path, RigidTransform(self._target_port.Eval(context)))
        return EventStatus.Succeeded()
