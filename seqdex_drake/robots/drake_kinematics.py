"""TreeKinematics' quantities from Drake's MultibodyPlant: the fallback when the C extension is not built.

:class:`DrakeKinematics` answers the calls of :class:`~seqdex_drake.robots.tree_kinematics.TreeKinematics`
(frame states, frame poses, one damped least-squares IK step) with the plant's own kinematics on a context of
its own: ``CalcPoseInWorld``, ``CalcSpatialVelocityInWorld`` and ``CalcJacobianSpatialVelocity``. The results
are those of the compiled path to ~1e-13 (``tests/test_tree_kinematics.py`` runs every test on both); each
call costs several Drake calls from Python instead of one compiled call, so an env step is slower.

As the compiled path, it evaluates the plant's *default* parameters (its own default context), not a context
whose frame offsets were changed.
"""

from collections.abc import Sequence

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, JacobianWrtVariable


def _vector(values, what: str) -> np.ndarray:
    """``values`` (a list or an array of numbers) as a float array; TypeError for anything else, as the C side."""
    array = np.asarray(values)
    if array.ndim != 1 or array.dtype.kind not in "biuf":
        raise TypeError(f"_kinematics: {what} must be a sequence of floats")
    return array.astype(float)


def _entries(values, n: int, what: str) -> np.ndarray:
    array = _vector(values, what)
    if array.size != n:
        raise ValueError(f"_kinematics: {what} must have {n} entries, got {array.size}")
    return array


def rotation_vector(R) -> list[float]:
    """angle * axis of a rotation matrix (its log map, for any angle up to a half turn), an array or rows."""
    angle_axis = RotationMatrix(np.reshape(_entries(np.ravel(R), 9, "the rotation matrix"), (3, 3))).ToAngleAxis()
    return (angle_axis.angle() * angle_axis.axis()).tolist()


class DrakeKinematics:
    """Poses and spatial velocities of ``frames`` of ``plant`` (or of the frames Q fixed in them at ``X_FQ``)
    evaluated by Drake; the same calls and layouts as
    :class:`~seqdex_drake.robots.tree_kinematics.TreeKinematics`, which builds it and checks the arguments.

    Args:
        plant: a finalized MultibodyPlant (double).
        frames: the frames to evaluate.
        X_FQ: optional per-frame offsets.
    """

    def __init__(self, plant: MultibodyPlant, frames: Sequence[Frame], X_FQ: Sequence[RigidTransform] | None = None):
        self._plant = plant
        self._context = plant.CreateDefaultContext()
        self._frames = list(frames)
        self._X_FQ = list(X_FQ) if X_FQ is not None else [RigidTransform()] * len(self._frames)
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        self._world = plant.world_frame()

    def _set_state(self, x) -> None:
        self._plant.SetPositionsAndVelocities(self._context, _entries(x, self._nq + self._nv, "plant state [q, v]"))

    def _set_positions(self, q) -> None:
        q = _vector(q, "positions q")
        if q.size not in (self._nq, self._nq + self._nv):  # Positions q, or a whole state [q, v].
            raise ValueError(f"_kinematics: the positions q must have {self._nq} entries, got {q.size}")
        self._plant.SetPositions(self._context, q[:self._nq])

    def states(self, x) -> list[float]:
        """Per frame: position (3), quaternion [w, x, y, z] with w >= 0 (4), translational velocity (3) and
        angular velocity (3), in the world, from the plant's state ``x`` = [q, v]."""
        self._set_state(x)
        out = []
        for frame, X_FQ in zip(self._frames, self._X_FQ, strict=True):
            X_WF = frame.CalcPoseInWorld(self._context)
            V_WQ = frame.CalcSpatialVelocityInWorld(self._context).Shift(X_WF.rotation() @ X_FQ.translation())
            X_WQ = X_WF @ X_FQ
            quaternion = X_WQ.rotation().ToQuaternion().wxyz()
            out += [*X_WQ.translation(), *(quaternion if quaternion[0] >= 0 else -quaternion),
                    *V_WQ.translational(), *V_WQ.rotational()]
        return [float(value) for value in out]

    def poses(self, q) -> list[float]:
        """Per frame: X_WQ's rotation row by row (9), then its translation (3), from positions ``q`` (or [q, v])."""
        self._set_positions(q)
        out = []
        for frame, X_FQ in zip(self._frames, self._X_FQ, strict=True):
            X_WQ = frame.CalcPoseInWorld(self._context) @ X_FQ
            out += [*X_WQ.rotation().matrix().ravel(), *X_WQ.translation()]
        return [float(value) for value in out]

    def dls_step(self, q, p_WQ_target, R_WQ_target, orientation_weight: float, damping: float, max_step: float,
                 q_min, q_max) -> list[float]:
        """One damped least-squares IK step for the single frame Q (see ``TreeKinematics.dls_step``)."""
        n = self._nq
        if len(self._frames) != 1 or self._nq != self._nv:
            raise ValueError("_kinematics.dls_step: needs one frame and a plant whose positions are all revolute "
                             "or prismatic joints (nq == nv <= 64)")
        q = _entries(q, n, "q")
        p_target, R_target = _entries(p_WQ_target, 3, "p_target"), _entries(R_WQ_target, 9, "R_target")
        q_min, q_max = _entries(q_min, n, "q_min"), _entries(q_max, n, "q_max")
        self._plant.SetPositions(self._context, q)
        frame, X_FQ = self._frames[0], self._X_FQ[0]
        X_WQ = frame.CalcPoseInWorld(self._context) @ X_FQ
        J = self._plant.CalcJacobianSpatialVelocity(self._context, JacobianWrtVariable.kV, frame,
                                                    X_FQ.translation(), self._world, self._world)
        J[:3] *= orientation_weight
        R_WQ = X_WQ.rotation().matrix()
        e = np.r_[orientation_weight * np.array(rotation_vector(np.reshape(R_target, (3, 3)) @ R_WQ.T)),
                  p_target - X_WQ.translation()]
        A = J @ J.T + damping**2 * np.eye(6)
        if not np.all(np.isfinite(A)):
            raise RuntimeError("PalmIK: the damped normal matrix is not positive definite (damping must be non-zero "
                               "and the state finite)")
        try:
            L = np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            raise RuntimeError("PalmIK: the damped normal matrix is not positive definite (damping must be non-zero "
                               "and the state finite)") from None
        dq = J.T @ np.linalg.solve(L.T, np.linalg.solve(L, e))
        norm = np.linalg.norm(dq)
        scale = max_step / norm if norm > max_step else 1.0
        return np.clip(q + dq * scale, q_min, q_max).tolist()
