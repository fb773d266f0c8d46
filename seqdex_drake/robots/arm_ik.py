"""Damped least-squares IK of the Franka for the palm centre (position) with the palm orientation held.

The release drives the arm by Cartesian deltas through damped least-squares IK (damping 0.05) with a
palm-down target orientation (FACTS.md); :class:`PalmIK` does the same on the controller plant (the Franka
with the Allegro welded and frozen), whose palm pose and Jacobian it evaluates in float arithmetic
(:class:`~seqdex_drake.robots.chain_kinematics.SerialChainKinematics`, read off that plant). One
:meth:`PalmIK.step` is the per-control-tick wrist controller of the sub-task environments; :meth:`PalmIK.solve`
iterates it to place the hand at reset.
"""

import math

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from scipy.linalg.lapack import dposv

from seqdex_drake.robots.allegro import PALM_BODY, p_PalmPc_Palm
from seqdex_drake.robots.chain_kinematics import SerialChainKinematics
from seqdex_drake.robots.franka import FRANKA_Q_MAX, FRANKA_Q_MIN
from seqdex_drake.systems.observations import floats


def rotation_vector(R) -> tuple[float, float, float]:
    """angle * axis of a rotation matrix (its log map; an array or three rows of floats), in float arithmetic
    (Drake's ``ToAngleAxis`` costs a few Python calls, every env step): from the skew part, sin(angle) axis,
    and the trace, 1 + 2 cos(angle). Turns beyond 90 degrees, where the skew part loses the axis, go to Drake."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist() if isinstance(R, np.ndarray) else R
    x, y, z = 0.5 * (r21 - r12), 0.5 * (r02 - r20), 0.5 * (r10 - r01)
    cosine = 0.5 * (r00 + r11 + r22 - 1.0)
    if cosine < 0.0:
        angle_axis = RotationMatrix(np.array(R, dtype=float)).ToAngleAxis()
        return tuple((angle_axis.angle() * angle_axis.axis()).tolist())
    sine = math.sqrt(x * x + y * y + z * z)
    k = math.atan2(sine, cosine) / sine if sine > 0.0 else 1.0
    return k * x, k * y, k * z


class PalmIK:
    """Damped least-squares IK for a point fixed in the palm (default: the palm centre) and the palm orientation.

    Args:
        controller_plant: from :func:`seqdex_drake.station.MakeControllerPlant` (7 positions); kept alive here.
        damping: the DLS damping (the release's 0.05).
        orientation_weight: weight of the orientation error against the position error (1/m).
        p_PalmC_Palm: the controlled point C in the palm frame (e.g. ``allegro.p_PalmHc_Palm``, the hand centre).
    """

    def __init__(self, controller_plant: MultibodyPlant, damping: float = 0.05, orientation_weight: float = 0.3,
                 p_PalmC_Palm: np.ndarray = p_PalmPc_Palm):
        if controller_plant.num_positions() != 7:
            raise ValueError("PalmIK needs the 7-dof controller plant (MakeControllerPlant)")
        self.plant = controller_plant
        hand = controller_plant.GetModelInstanceByName("allegro")
        self.palm = controller_plant.GetBodyByName(PALM_BODY, hand).body_frame()
        self._kinematics = SerialChainKinematics(controller_plant, self.palm)
        self.damping = damping
        self.orientation_weight = orientation_weight
        self.p_PalmC_Palm = np.asarray(p_PalmC_Palm, dtype=float)
        self._damping_eye = (damping, damping**2 * np.eye(6))  # Recomputed if ``damping`` is changed.
        self._target = (None, None)  # (R_WP_target, its matrix) of the last step (the env holds one orientation).
        self._last = (None, None, None)  # (q_arm, X_WC rows, joint frames) of the last pose computed (_pose).
        self._p_PalmC_Palm = self.p_PalmC_Palm.tolist()
        self._q_min, self._q_max = FRANKA_Q_MIN.tolist(), FRANKA_Q_MAX.tolist()

    def palm_pose(self, q_arm: np.ndarray) -> RigidTransform:
        """X_WC: the controlled point with the palm's orientation, in the world, for arm positions ``q_arm``."""
        X_WC = np.array(self._pose(floats(q_arm)))
        return RigidTransform(RotationMatrix(X_WC[:, :3]), X_WC[:, 3])

    def palm_position(self, q_arm: np.ndarray) -> np.ndarray:
        """p_WC: the controlled point's world position for arm positions ``q_arm`` (as :meth:`palm_pose`)."""
        return np.array(self.palm_point(floats(q_arm)))

    def palm_point(self, q_arm: list[float]) -> list[float]:
        """:meth:`palm_position` of arm positions given as a list of floats, as a list of floats."""
        r0, r1, r2 = self._pose(q_arm)
        return [r0[3], r1[3], r2[3]]

    def _pose(self, q_arm: list[float]) -> list[list[float]]:
        """X_WC as three rows [r_i0, r_i1, r_i2, p_i] of floats (read only), computed once for consecutive calls
        with the same ``q_arm`` (a list of floats; the env asks twice a tick). Float arithmetic and lists, as
        the env's step runs this with the caches cold after the physics, where each distinct numpy function
        or Drake call costs microseconds."""
        if q_arm != self._last[0]:
            (R, (x, y, z)), joints = self._kinematics.pose(q_arm)  # X_WPalm; C shares its rotation.
            px, py, pz = self._p_PalmC_Palm
            rows = [[R[0], R[1], R[2], x + R[0] * px + R[1] * py + R[2] * pz],
                    [R[3], R[4], R[5], y + R[3] * px + R[4] * py + R[5] * pz],
                    [R[6], R[7], R[8], z + R[6] * px + R[7] * py + R[8] * pz]]
            self._last = (list(q_arm), rows, joints)
        return self._last[1]

    def step(self, q_arm: np.ndarray, p_WC_target: np.ndarray, R_WP_target: RotationMatrix,
             max_step: float = 0.05) -> np.ndarray:
        """One DLS step: the joint positions moving the palm centre toward the target, within joint limits."""
        return np.array(self.step_values(floats(q_arm), floats(p_WC_target), R_WP_target, max_step))

    def step_values(self, q_arm: list[float], p_WC_target: list[float], R_WP_target: RotationMatrix,
                    max_step: float = 0.05) -> list[float]:
        """:meth:`step` on lists of floats (the env's per-tick call)."""
        r0, r1, r2 = self._pose(q_arm)
        J = np.array(self._kinematics.jacobian(self._last[2], [r0[3], r1[3], r2[3]]))
        if self._target[0] is not R_WP_target:
            self._target = (R_WP_target, R_WP_target.matrix().tolist())
        # R_target R^T: the rotation still to go (row i of the target times row j of R).
        E = [[t[0] * r[0] + t[1] * r[1] + t[2] * r[2] for r in (r0, r1, r2)] for t in self._target[1]]
        rx, ry, rz = rotation_vector(E)
        w = self.orientation_weight
        error = np.array([w * rx, w * ry, w * rz, p_WC_target[0] - r0[3], p_WC_target[1] - r1[3],
                          p_WC_target[2] - r2[3]])
        J[:3] *= w  # J is our own fresh array.
        if self._damping_eye[0] != self.damping:
            self._damping_eye = (self.damping, self.damping**2 * np.eye(6))
        # J J^T + damping^2 I is symmetric positive definite: LAPACK's Cholesky solve, called directly (numpy's
        # solve wrapper cost several times the 6x6 solve itself, every env step).
        _, x, info = dposv(J @ J.T + self._damping_eye[1], error)
        if info != 0:
            raise RuntimeError(f"PalmIK: the damped normal matrix is not positive definite (LAPACK info {info})")
        dq = (J.T @ x).tolist()
        norm = math.sqrt(sum(d * d for d in dq))
        scale = max_step / norm if norm > max_step else 1.0
        return [min(max(q + d * scale, lo), hi)
                for q, d, lo, hi in zip(q_arm, dq, self._q_min, self._q_max, strict=True)]

    def solve(self, q_arm: np.ndarray, p_WC_target: np.ndarray, R_WP_target: RotationMatrix,
              iterations: int = 300, tolerance: float = 1e-4) -> tuple[np.ndarray, float]:
        """Iterates :meth:`step` from ``q_arm``; returns the solution and its remaining position error (m)."""
        q = np.asarray(q_arm, dtype=float).copy()
        for _ in range(iterations):
            q = self.step(q, p_WC_target, R_WP_target, max_step=0.2)
            error = np.linalg.norm(self.palm_position(q) - p_WC_target)
            if error < tolerance:
                break
        return q, float(error)
