"""Parameters and run statistics of the operational-space approach controller (:mod:`seqdex_drake.control.osc`)."""

import dataclasses

import numpy as np

from seqdex_drake.robots.allegro import p_PalmPc_Palm


@dataclasses.dataclass
class OscParams:
    """Parameters of :class:`OperationalSpaceController`."""

    hover_height: float = 0.05
    """Height (m) of the hover point above the target; the controlled point is driven there."""
    handover_distance: float = 0.05
    """The approach ends once the controlled point is within this distance (m) of the target itself."""
    hover_tolerance: float = 0.01
    """The approach ends once the controlled point is within this distance (m) of the hover point."""
    handover_angle: float = float("inf")
    """The approach ends only once the hand is within this angle (rad) of its held orientation (the ``hold_rotation``
    input's turn included); inf: the position alone decides."""
    handover_speed: float = float("inf")
    """The approach ends only once the controlled point moves slower than this (m/s); inf: no condition."""
    reengage_distance: float = 0.10
    """After a handover the approach restarts only when the target is farther than this (m) from the hand."""
    approach_timeout: float = float("inf")
    """Seconds after which an approach hands over wherever the hand is: a hover point the hand cannot reach (the
    fingers caught on the pile) would otherwise keep the approach active, and a chain's stage clock stopped, for
    good. inf: no limit."""
    travel_height: float = 0.0
    """If > 0: a world height (m) the controlled point travels at while it is farther than ``travel_xy`` from the
    hover point horizontally; it first rises in place to it, then crosses, then descends. A path over obstacles
    between workspaces (the Building Blocks box walls between the baseplate and the pile); 0: a straight line."""
    travel_xy: float = 0.05
    """Horizontal distance (m) from the hover point within which the approach leaves ``travel_height``."""
    position_kp: float = 200.0
    """Task-space stiffness (1/s^2) toward the hover point."""
    position_kd: float = 36.0
    """Task-space damping (1/s); the commanded speed is (kp / kd) * error, capped at ``max_speed``."""
    orientation_kp: float = 120.0
    """Stiffness (1/s^2) toward the held orientation."""
    orientation_kd: float = 26.0
    """Damping (1/s) of the orientation task; angular speed capped at ``max_angular_speed``."""
    max_speed: float = 0.9
    """Largest commanded speed (m/s) of the controlled point."""
    max_acceleration: float = 8.0
    """Largest commanded linear acceleration (m/s^2) of the controlled point (norm clip of a_des)."""
    max_angular_speed: float = 1.5
    """Largest commanded angular speed (rad/s) of the hand."""
    orientation_weight: float = 0.1
    """Weight of the angular rows of the task cost relative to the translational rows (m^2/rad^2)."""
    posture_weight: float = 1e-3
    """Weight of the joint-space posture term (mostly shapes the null-space motion of the elbow)."""
    posture_kp: float = 4.0
    """Joint-space stiffness (1/s^2) of the posture term toward ``posture_q``."""
    posture_kd: float = 4.0
    """Joint-space damping (1/s) of the posture term."""
    acceleration_regularization: float = 1e-6
    """Weight of |qdd|^2, keeps the program strictly convex near singularities."""
    torque_regularization: float = 1e-8
    """Weight of |tau|^2."""
    position_margin: float = 0.05
    """Joint positions are kept this far (rad) inside their limits."""
    velocity_scale: float = 0.9
    """Joint velocities are kept within this fraction of their limits."""
    effort_scale: float = 0.9
    """Joint torques (inverse dynamics and PD command) are kept within this fraction of the effort limits."""
    braking_acceleration: float = 4.0
    """Deceleration (rad/s^2) assumed when bounding the velocity toward a position limit."""
    p_PalmPc_Palm: tuple[float, float, float] = tuple(p_PalmPc_Palm)
    """The controlled point C in the ``palm`` frame (m); default: the palm centre."""
    R_WD: np.ndarray | None = None
    """Held hand (``palm`` frame) orientation in the world, 3x3; None: the orientation at ``posture_q``."""
    posture_q: tuple[float, ...] | None = None
    """Posture (rad) of the secondary task; None: the arm home given to the controller."""
    solve_while_handed_over: bool = True
    """False: while handed over (before and after the tick) only the handover check runs and the command is held
    (the chain controller's setting: its wrist IK drives the arm then). True: the QP runs every tick."""
    osqp_options: dict = dataclasses.field(default_factory=lambda: {
        "eps_abs": 1e-6, "eps_rel": 1e-6, "polishing": 1, "max_iter": 4000, "verbose": 0})
    """Options passed to OSQP by name (Drake's OsqpSolver spells solution polishing "polishing")."""


@dataclasses.dataclass
class OscStatistics:
    """Wall-clock statistics of the per-tick QP, for benchmarks (not part of the simulated state)."""

    ticks: int = 0
    """Periodic updates that solved the QP."""
    failures: int = 0
    """Updates whose QP OSQP did not solve."""
    solve_seconds_total: float = 0.0
    """Summed wall time of ``OsqpSolver.Solve``."""
    solve_seconds_max: float = 0.0
    """Largest wall time of one ``OsqpSolver.Solve``."""
    update_seconds_total: float = 0.0
    """Summed wall time of whole updates (kinematics, dynamics, coefficient updates, solve)."""
    update_seconds_max: float = 0.0
    """Largest wall time of one whole update."""
