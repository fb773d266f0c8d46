"""Damped least-squares IK of the Franka for the palm centre (position) with the palm orientation held.

The release drives the arm by Cartesian deltas through damped least-squares IK (damping 0.05) with a
palm-down target orientation (FACTS.md); :class:`PalmIK` does the same on the controller plant (the Franka
with the Allegro welded and frozen), whose palm pose, Jacobian and DLS step it evaluates in compiled code
(:class:`~seqdex_drake.robots.tree_kinematics.TreeKinematics`, read off that plant). One :meth:`PalmIK.step` is
the per-control-tick wrist controller of the sub-task environments; :meth:`PalmIK.solve` iterates it to place
the hand at reset.
"""

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant

from seqdex_drake.observation_layout import floats
from seqdex_drake.robots.allegro import PALM_BODY, p_PalmPc_Palm
from seqdex_drake.robots.franka import FRANKA_Q_MAX, FRANKA_Q_MIN
from seqdex_drake.robots.tree_kinematics import TreeKinematics


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
        self.damping = damping
        self.orientation_weight = orientation_weight
        self.p_PalmC_Palm = np.asarray(p_PalmC_Palm, dtype=float)
        self._kinematics = TreeKinematics(controller_plant, [self.palm], [RigidTransform(self.p_PalmC_Palm)])
        self._target = (None, None)  # (R_WP_target, its 9 entries) of the last step (the env holds one).
        self._q_min, self._q_max = FRANKA_Q_MIN.tolist(), FRANKA_Q_MAX.tolist()

    def palm_pose(self, q_arm: np.ndarray) -> RigidTransform:
        """X_WC: the controlled point with the palm's orientation, in the world, for arm positions ``q_arm``."""
        return self._kinematics.pose(floats(q_arm))

    def palm_position(self, q_arm: np.ndarray) -> np.ndarray:
        """p_WC: the controlled point's world position for arm positions ``q_arm`` (as :meth:`palm_pose`)."""
        return np.array(self.palm_point(floats(q_arm)))

    def palm_point(self, q_arm: list[float]) -> list[float]:
        """:meth:`palm_position` of arm positions given as a list of floats, as a list of floats."""
        return self._kinematics.poses(q_arm)[9:]

    def step(self, q_arm: np.ndarray, p_WC_target: np.ndarray, R_WP_target: RotationMatrix,
             max_step: float = 0.05) -> np.ndarray:
        """One DLS step: the joint positions moving the palm centre toward the target, within joint limits."""
        return np.array(self.step_values(floats(q_arm), floats(p_WC_target), R_WP_target, max_step))

    def step_values(self, q_arm: list[float], p_WC_target: list[float], R_WP_target: RotationMatrix,
                    max_step: float = 0.05) -> list[float]:
        """:meth:`step` on lists of floats (the env's per-tick call): with the error
        e = [w log(R_target R_WC^T); p_target - p_WC], w the orientation weight, and the palm's Jacobian J
        (angular rows times w), dq = J^T (J J^T + damping^2 I)^-1 e, at most ``max_step`` long, within the
        joint limits."""
        if self._target[0] is not R_WP_target:
            self._target = (R_WP_target, R_WP_target.matrix().ravel().tolist())
        return self._kinematics.dls_step(q_arm, p_WC_target, self._target[1], self.orientation_weight,
                                         self.damping, max_step, self._q_min, self._q_max)

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
