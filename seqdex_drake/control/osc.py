"""Operational-space approach controller: brings the hand to a hover point above a target, then hands over.

The paper's rule (Sec. 4, "when the target is more than 5 cm from the hand an OSC moves the end-effector to
5 cm above it") as a Drake LeafSystem. Every control tick it solves one small quadratic program, built once
in the constructor and only re-parameterized afterwards, with Drake's ``OsqpSolver``.

Quadratic program (decision variables: joint accelerations ``qdd`` (7) and joint torques ``tau`` (7))::

    min  |W (J qdd + Jdot v - a_des)|^2 + w_post |qdd - qdd_post|^2 + w_reg |qdd|^2 + w_tau |tau|^2
    s.t. M(q) qdd + C(q, v) v - tau_g(q) = tau                   (rigid-body dynamics, hand welded)
         -effort <= tau <= effort                                (inverse-dynamics torque)
         qdd_lo <= qdd <= qdd_hi                                 (velocity, position, PD-torque limits)

``J`` is the spatial Jacobian (angular; translational) of the controlled point C (the palm centre), ``a_des``
a velocity-limited PD acceleration toward the hover point H = target + (0, 0, hover_height) (or, with a
``travel_height``, first up to that height and across at it: :meth:`OperationalSpaceController.waypoint`) and toward the
held orientation R_WD (R_off R_WD with the optional ``hold_rotation`` input), ``qdd_post`` a joint-space PD toward
the posture (the arm home). The bounds on ``qdd`` combine, per joint and per tick, the velocity limit on
``v + qdd dt``, a braking-distance bound that keeps ``q`` inside its limits minus a margin, and the limit on the
torque the station's joint PD actuators (gains kp, kd; gravity fed forward) exert at the start of the tick for
the command sent below.

The solution becomes the PD targets of ``franka.desired_state``: ``v_cmd = v + qdd dt`` and
``q_cmd = q + v_cmd dt / 2`` (the mid-tick position, so the PD's stiffness term averages to zero over the
hold and the joint PD behaves as a velocity servo around the planned motion). Both are clipped to the limits.

Handover (output ``approach_active``): 1 while the controller is in charge, 0 once the controlled point is
within ``hover_tolerance`` of the hover point or within ``handover_distance`` of the target itself (the
policy then moves the hand close to the target without the OSC pulling it back), and, where ``handover_angle`` and
``handover_speed`` are finite, the hand within that angle of its held orientation and the controlled point
slower than that speed (a carry hands over a settled block, its turn done). It turns 1 again only when
the target is farther than ``reengage_distance`` from the controlled point (a new or moved target), or when the
optional ``stage_epoch`` input changes (a chain's stage restarts: it starts from the hover point again); an
approach that has not ended after ``approach_timeout`` seconds hands over where the hand is. The
controller keeps tracking the hover point either way (unless ``solve_while_handed_over`` is False); a switcher
downstream chooses whose command to use.

Failures: a QP that OSQP does not solve holds the last command, adds one to the ``qp_failures`` output and
warns once. A non-finite target or robot state raises ``ValueError`` (it means a bug upstream).
"""

from __future__ import annotations

import logging
import time

import numpy as np
from pydrake.math import RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.solvers import MathematicalProgram, MathematicalProgramResult, OsqpSolver, SolverOptions
from pydrake.systems.framework import BasicVector, Context, DiagramBuilder, DiscreteValues, LeafSystem, System

from seqdex_drake.control.osc_params import OscParams, OscStatistics
from seqdex_drake.robots.allegro import PALM_BODY
from seqdex_drake.robots.franka import FRANKA_HOME_Q, FRANKA_JOINT_NAMES
from seqdex_drake.scenario import Scenario
from seqdex_drake.station import MakeControllerPlant

__all__ = ["AddOperationalSpaceController", "OperationalSpaceController", "OscParams", "OscStatistics"]

_LOGGER = logging.getLogger(__name__)
NUM_ARM = 7


def held_orientation(port, context: Context, R_WP_hold: RotationMatrix, cache: list) -> RotationMatrix:
    """``R_off R_WP_hold`` for the optional ``hold_rotation`` input ``port`` (R_off row-major; unconnected: the
    identity). ``cache`` is ``[R_off values, result]``, reused while the input is unchanged (the wrist IK caches its
    target's matrix by the rotation's identity)."""
    if not port.HasValue(context):
        return R_WP_hold
    return turned_orientation(np.asarray(port.Eval(context), dtype=float), R_WP_hold, cache)


def turned_orientation(values: np.ndarray, R_WP_hold: RotationMatrix, cache: list) -> RotationMatrix:
    """``R_off R_WP_hold`` for R_off given row-major in ``values``; ``cache`` as :func:`held_orientation`'s."""
    if cache[0] is None or not np.array_equal(values, cache[0]):
        cache[:] = [values.copy(), RotationMatrix(values.reshape(3, 3)) @ R_WP_hold]
    return cache[1]


class OperationalSpaceController(LeafSystem):
    """Drives the palm centre to a hover point above a target by solving a QP every control tick.

    Input ports: ``franka.state`` (14: q, v), ``target_position`` (3, world, m), optional ``stage_epoch`` (1) and
    ``hold_rotation`` (9: R_off row-major, the held orientation is then R_off R_WD; unconnected: R_WD).
    Output ports: ``franka.desired_state`` (14: q_cmd, v_cmd for the joint PD actuators),
    ``approach_active`` (1: 1.0 while the controller is in charge), ``qp_failures`` (1: count since init).

    The command, the handover flag and the failure count are discrete state. The program, the controller
    plant's scratch context, the warm start and :attr:`statistics` belong to the instance: one instance
    serves one simulation at a time (each update rewrites the scratch from its inputs).

    Args:
        plant: the controller plant (:func:`~seqdex_drake.station.MakeControllerPlant`): 7 positions in
            Franka joint order, finalized, continuous. The system keeps a reference to it.
        control_period: seconds between updates (the scenario's ``control_period``).
        arm_kp: stiffness (N m/rad) of the station's Franka joint PD actuators.
        arm_kd: damping (N m s/rad) of the station's Franka joint PD actuators.
        params: controller parameters; defaults to ``OscParams()``.
        home_q: arm home (rad), the default posture; defaults to ``FRANKA_HOME_Q``.
    """

    def __init__(self, plant: MultibodyPlant, control_period: float, arm_kp: float, arm_kd: float,
                 params: OscParams | None = None, home_q: np.ndarray | None = None):
        super().__init__()
        self._plant = plant  # Keep a Python reference: pydrake does not keep it alive for us.
        self._params = params = params or OscParams()
        if plant.num_positions() != NUM_ARM or plant.num_velocities() != NUM_ARM:
            raise ValueError(f"the controller plant must have 7 positions and velocities (the Franka with the "
                             f"hand welded), got {plant.num_positions()} and {plant.num_velocities()}")
        franka = plant.GetModelInstanceByName("franka")
        starts = [plant.GetJointByName(n, franka).position_start() for n in FRANKA_JOINT_NAMES]
        if starts != list(range(NUM_ARM)):
            raise ValueError(f"controller plant positions are not in Franka joint order: {starts}")
        if control_period <= 0:
            raise ValueError(f"control_period must be positive, got {control_period}")
        self._dt = float(control_period)
        self._kp, self._kd = float(arm_kp), float(arm_kd)
        self._plant_context = plant.CreateDefaultContext()
        self._palm_frame = plant.GetBodyByName(PALM_BODY).body_frame()
        self._p_PC = np.asarray(params.p_PalmPc_Palm, dtype=float)
        self._q_min, self._q_max = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
        self._v_max = plant.GetVelocityUpperLimits() * params.velocity_scale
        self._effort = plant.GetEffortUpperLimits() * params.effort_scale
        home = np.asarray(FRANKA_HOME_Q if home_q is None else home_q, dtype=float)
        self._posture_q = np.asarray(home if params.posture_q is None else params.posture_q, dtype=float)
        if params.R_WD is None:
            plant.SetPositions(self._plant_context, home)
            self._R_WD = plant.EvalBodyPoseInWorld(self._plant_context, self._palm_frame.body()).rotation()
        else:
            self._R_WD = RotationMatrix(np.asarray(params.R_WD, dtype=float))
        self._W = np.sqrt(np.r_[np.full(3, params.orientation_weight), np.ones(3)])
        self.statistics = OscStatistics()
        self._warned = False
        self._build_program()

        self._state_port = self.DeclareVectorInputPort("franka.state", 2 * NUM_ARM)
        self._target_port = self.DeclareVectorInputPort("target_position", 3)
        self._command_index = self.DeclareDiscreteState(np.r_[home, np.zeros(NUM_ARM)])
        self._epoch_port = self.DeclareVectorInputPort("stage_epoch", 1)  # Optional.
        self._turn_port = self.DeclareVectorInputPort("hold_rotation", 9)  # Optional.
        self._turn_cache = [None, self._R_WD]
        self._status_index = self.DeclareDiscreteState(np.array([1.0, 0.0]))  # approach_active, qp_failures
        self._epoch_index = self.DeclareDiscreteState(np.zeros(1))  # The stage_epoch seen last tick.
        self._since_index = self.DeclareDiscreteState(np.zeros(1))  # When the current approach started.
        self.DeclareStateOutputPort("franka.desired_state", self._command_index)
        self.DeclareVectorOutputPort("approach_active", 1, self._calc_active)
        self.DeclareVectorOutputPort("qp_failures", 1, self._calc_failures)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

    # ------------------------------------------------------------------------------------------- program
    def _build_program(self) -> None:
        """Builds the QP once; :meth:`_update` only changes its coefficients and bounds."""
        prog = MathematicalProgram()
        self._qdd = prog.NewContinuousVariables(NUM_ARM, "qdd")
        self._tau = prog.NewContinuousVariables(NUM_ARM, "tau")
        self._task_cost = prog.AddQuadraticCost(np.eye(NUM_ARM), np.zeros(NUM_ARM), self._qdd,
                                                is_convex=True).evaluator()
        prog.AddQuadraticCost(2 * self._params.torque_regularization * np.eye(NUM_ARM), np.zeros(NUM_ARM),
                              self._tau, is_convex=True)
        self._dynamics = prog.AddLinearEqualityConstraint(
            np.hstack([np.eye(NUM_ARM), -np.eye(NUM_ARM)]), np.zeros(NUM_ARM),
            np.r_[self._qdd, self._tau]).evaluator()
        self._qdd_bounds = prog.AddBoundingBoxConstraint(np.zeros(NUM_ARM), np.zeros(NUM_ARM),
                                                         self._qdd).evaluator()
        prog.AddBoundingBoxConstraint(-self._effort, self._effort, self._tau)
        self._prog = prog
        self._solver = OsqpSolver()
        self._solver_options = SolverOptions()
        for name, value in self._params.osqp_options.items():
            self._solver_options.SetOption(OsqpSolver.id(), name, value)
        self._result = MathematicalProgramResult()
        self._guess = np.zeros(2 * NUM_ARM)

    @property
    def program(self) -> MathematicalProgram:
        """The one MathematicalProgram this controller re-solves every tick."""
        return self._prog

    @property
    def controller_plant(self) -> MultibodyPlant:
        return self._plant

    @property
    def params(self) -> OscParams:
        return self._params

    @property
    def R_WD(self) -> RotationMatrix:
        """The held orientation of the ``palm`` frame in the world."""
        return self._R_WD

    # ------------------------------------------------------------------------------------------ task math
    def hover_point(self, p_WT: np.ndarray) -> np.ndarray:
        """The hover point H above target T (world, m)."""
        return np.asarray(p_WT, dtype=float) + np.array([0.0, 0.0, self._params.hover_height])

    def waypoint(self, p_WC: np.ndarray, p_WH: np.ndarray) -> np.ndarray:
        """Where the controlled point at ``p_WC`` heads for hover point ``p_WH``: the hover point itself, or with a
        ``travel_height`` and farther than ``travel_xy`` from it horizontally, first straight up to that height,
        then across at it."""
        p = self._params
        if p.travel_height <= 0.0 or np.linalg.norm(p_WH[:2] - p_WC[:2]) <= p.travel_xy:
            return p_WH
        height = max(p.travel_height, p_WH[2])
        if p_WC[2] < height - p.hover_tolerance:
            return np.array([p_WC[0], p_WC[1], height])
        return np.array([p_WH[0], p_WH[1], height])

    def controlled_point(self, q: np.ndarray) -> np.ndarray:
        """p_WC: the controlled point in the world (m) at arm positions ``q`` (controller plant kinematics)."""
        self._plant.SetPositions(self._plant_context, q)
        X_WPalm = self._plant.EvalBodyPoseInWorld(self._plant_context, self._palm_frame.body())
        return X_WPalm @ self._p_PC

    def _desired_acceleration(self, p_WC: np.ndarray, R_WPalm: RotationMatrix, V_WC: np.ndarray,
                              p_WH: np.ndarray, R_WD: RotationMatrix) -> np.ndarray:
        """Velocity-limited PD acceleration [alpha; a] (world) of the controlled point toward H and R_WD."""
        p = self._params
        R_err = (R_WD @ R_WPalm.inverse()).ToAngleAxis()
        w_des = _clip_norm(p.orientation_kp / p.orientation_kd * R_err.angle() * R_err.axis(),
                           p.max_angular_speed)
        v_des = _clip_norm(p.position_kp / p.position_kd * (p_WH - p_WC), p.max_speed)
        alpha = p.orientation_kd * (w_des - V_WC[:3])
        accel = _clip_norm(p.position_kd * (v_des - V_WC[3:]), p.max_acceleration)
        return np.concatenate((alpha, accel))

    def _qdd_bounds_now(self, q: np.ndarray, v: np.ndarray, tau_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint bounds on qdd from velocity, position (braking) and PD-command torque limits."""
        dt, p = self._dt, self._params
        lo_v, hi_v = -self._v_max, self._v_max.copy()
        # Velocity v_next over the next tick, after which the joint must still stop inside the margins.
        a_b = p.braking_acceleration
        d_hi = np.maximum(self._q_max - p.position_margin - q, 0.0)
        d_lo = np.maximum(q - self._q_min - p.position_margin, 0.0)
        hi_v = np.minimum(hi_v, -a_b * dt + np.sqrt((a_b * dt) ** 2 + 2 * a_b * d_hi))
        lo_v = np.maximum(lo_v, a_b * dt - np.sqrt((a_b * dt) ** 2 + 2 * a_b * d_lo))
        lo, hi = (lo_v - v) / dt, (hi_v - v) / dt
        # PD torque at the start of the tick: kp (q_cmd - q) + kd (v_cmd - v) - tau_g = c qdd + kp dt/2 v - tau_g.
        c = self._kp * dt * dt / 2 + self._kd * dt
        offset = self._kp * dt / 2 * v - tau_g
        lo_t, hi_t = (-self._effort - offset) / c, (self._effort - offset) / c
        return np.clip(lo, lo_t, hi_t), np.clip(hi, lo_t, hi_t)

    # --------------------------------------------------------------------------------------------- events
    def _read_inputs(self, context: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = self._state_port.Eval(context)
        p_WT = self._target_port.Eval(context)
        if not np.all(np.isfinite(p_WT)):
            raise ValueError(f"OperationalSpaceController: non-finite target_position {p_WT}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"OperationalSpaceController: non-finite franka.state {x}")
        return x[:NUM_ARM], x[NUM_ARM:], p_WT

    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        """Holds the measured arm positions and marks the approach active (the first tick may hand over)."""
        q, _, _ = self._read_inputs(context)
        discrete_state.set_value(self._command_index, np.r_[q, np.zeros(NUM_ARM)])
        discrete_state.set_value(self._status_index, np.array([1.0, 0.0]))
        discrete_state.set_value(self._epoch_index, self._epoch(context))
        discrete_state.set_value(self._since_index, np.array([context.get_time()]))
        self._guess[:] = 0.0

    def _epoch(self, context: Context) -> np.ndarray:
        return self._epoch_port.Eval(context) if self._epoch_port.HasValue(context) else np.zeros(1)

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        start = time.perf_counter()
        q, v, p_WT = self._read_inputs(context)
        plant, pc, p = self._plant, self._plant_context, self._params
        plant.SetPositions(pc, q)
        plant.SetVelocities(pc, v)
        X_WPalm = plant.EvalBodyPoseInWorld(pc, self._palm_frame.body())
        p_WC = X_WPalm @ self._p_PC
        p_WH = self.hover_point(p_WT)
        status = discrete_state.get_value(self._status_index).copy()
        epoch = self._epoch(context)
        if epoch[0] != discrete_state.get_value(self._epoch_index)[0]:  # A stage (re)started: approach again.
            status[0] = 1.0
            discrete_state.set_value(self._epoch_index, epoch)
            discrete_state.set_value(self._since_index, np.array([context.get_time()]))
        was_active = bool(status[0])
        R_WD = held_orientation(self._turn_port, context, self._R_WD, self._turn_cache)
        settled = self._settled(X_WPalm.rotation(), R_WD, v) if was_active else True
        status[0] = self._next_active(was_active, p_WC, p_WH, p_WT, settled)
        now = context.get_time()
        if status[0] and not was_active:
            discrete_state.set_value(self._since_index, np.array([now]))
        elif status[0] and now - discrete_state.get_value(self._since_index)[0] > p.approach_timeout:
            status[0] = 0.0  # Timed out: the stage starts wherever the hand got to.
        if not (p.solve_while_handed_over or was_active or status[0]):
            discrete_state.set_value(self._status_index, status)  # Handed over: the command is held.
            return
        world = plant.world_frame()
        J = plant.CalcJacobianSpatialVelocity(pc, JacobianWrtVariable.kV, self._palm_frame, self._p_PC,
                                              world, world)
        bias = plant.CalcBiasSpatialAcceleration(pc, JacobianWrtVariable.kV, self._palm_frame, self._p_PC,
                                                 world, world)
        a_des = self._desired_acceleration(p_WC, X_WPalm.rotation(), J @ v, self.waypoint(p_WC, p_WH), R_WD)
        a_des -= np.concatenate((bias.rotational(), bias.translational()))

        # Task + posture cost on qdd: |W (J qdd - a_des)|^2 + w_post |qdd - qdd_post|^2 + w_reg |qdd|^2.
        WJ, Wa = self._W[:, None] * J, self._W * a_des
        qdd_post = p.posture_kp * (self._posture_q - q) - p.posture_kd * v
        Q = 2 * (WJ.T @ WJ + (p.posture_weight + p.acceleration_regularization) * np.eye(NUM_ARM))
        b = -2 * (WJ.T @ Wa + p.posture_weight * qdd_post)
        self._task_cost.UpdateCoefficients(Q, b, 0.0, True)

        M = plant.CalcMassMatrix(pc)
        tau_g = plant.CalcGravityGeneralizedForces(pc)
        Cv = plant.CalcBiasTerm(pc)
        self._dynamics.UpdateCoefficients(np.hstack([M, -np.eye(NUM_ARM)]), tau_g - Cv)
        self._qdd_bounds.set_bounds(*self._qdd_bounds_now(q, v, tau_g))

        solve_start = time.perf_counter()
        self._solver.Solve(self._prog, self._guess, self._solver_options, self._result)
        solve_seconds = time.perf_counter() - solve_start

        if self._result.is_success():
            solution = self._result.GetSolution()
            self._guess[:] = solution
            qdd = self._result.GetSolution(self._qdd)
            v_cmd = np.clip(v + qdd * self._dt, -self._v_max, self._v_max)
            q_cmd = np.clip(q + v_cmd * self._dt / 2, self._q_min, self._q_max)
            discrete_state.set_value(self._command_index, np.concatenate((q_cmd, v_cmd)))
        else:
            status[1] += 1
            self.statistics.failures += 1
            if not self._warned:
                _LOGGER.warning("OSC QP not solved (%s) at t = %.3f s; holding the last command",
                                self._result.get_solution_result(), context.get_time())
                self._warned = True
        discrete_state.set_value(self._status_index, status)
        self._record(solve_seconds, time.perf_counter() - start)

    def _settled(self, R_WPalm: RotationMatrix, R_WD: RotationMatrix, v: np.ndarray) -> bool:
        """Whether the hand is within ``handover_angle`` of its held orientation and the controlled point slower
        than ``handover_speed`` (always, with both infinite)."""
        p = self._params
        if np.isinf(p.handover_angle) and np.isinf(p.handover_speed):
            return True
        if (R_WD @ R_WPalm.inverse()).ToAngleAxis().angle() > p.handover_angle:
            return False
        J = self._plant.CalcJacobianTranslationalVelocity(self._plant_context, JacobianWrtVariable.kV,
                                                           self._palm_frame, self._p_PC, self._plant.world_frame(),
                                                           self._plant.world_frame())
        return bool(np.linalg.norm(J @ v) <= p.handover_speed)

    def _next_active(self, active: bool, p_WC: np.ndarray, p_WH: np.ndarray, p_WT: np.ndarray,
                     settled: bool = True) -> float:
        """Handover logic with hysteresis (see the module docstring)."""
        p = self._params
        to_target = np.linalg.norm(p_WT - p_WC)
        if active:
            done = np.linalg.norm(p_WH - p_WC) <= p.hover_tolerance or to_target <= p.handover_distance
            return 0.0 if done and settled else 1.0
        return 1.0 if to_target > p.reengage_distance else 0.0

    def _record(self, solve_seconds: float, update_seconds: float) -> None:
        s = self.statistics
        s.ticks += 1
        s.solve_seconds_total += solve_seconds
        s.solve_seconds_max = max(s.solve_seconds_max, solve_seconds)
        s.update_seconds_total += update_seconds
        s.update_seconds_max = max(s.update_seconds_max, update_seconds)

    def _calc_active(self, context: Context, output: BasicVector) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._status_index).GetAtIndex(0))

    def _calc_failures(self, context: Context, output: BasicVector) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._status_index).GetAtIndex(1))


def AddOperationalSpaceController(builder: DiagramBuilder, station: System, scenario: Scenario,
                                  params: OscParams | None = None) -> OperationalSpaceController:
    """Adds the controller for ``scenario`` to ``builder`` and wires it to the station's Franka ports.

    Connects ``franka.state`` to the controller and the controller to ``franka.desired_state``; the caller
    connects ``target_position`` (and uses ``approach_active``).

    Args:
        builder: the DiagramBuilder that already holds ``station``.
        station: the Diagram from :func:`~seqdex_drake.station.MakeStation`.
        scenario: the scenario the station was built from (controller plant, gains, period, home).
        params: controller parameters; defaults to ``OscParams()``.
    """
    osc = OperationalSpaceController(MakeControllerPlant(scenario), scenario.control_period,
                                     scenario.robot.arm_kp, scenario.robot.arm_kd, params,
                                     home_q=np.asarray(scenario.robot.arm_home, dtype=float))
    builder.AddNamedSystem("osc", osc)
    builder.Connect(station.GetOutputPort("franka.state"), osc.GetInputPort("franka.state"))
    builder.Connect(osc.GetOutputPort("franka.desired_state"), station.GetInputPort("franka.desired_state"))
    return osc


def _clip_norm(x: np.ndarray, limit: float) -> np.ndarray:
    norm = np.linalg.norm(x)
    return x * (limit / norm) if norm > limit else x
