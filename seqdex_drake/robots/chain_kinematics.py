"""Forward kinematics and Jacobian of a serial chain of revolute joints in Python float arithmetic.

The env's wrist IK (:class:`~seqdex_drake.robots.arm_ik.PalmIK`) needs, every control step, the palm pose and
its 6 x 7 Jacobian on the controller plant. Drake computes both in microseconds, but the env's step runs right
after ~5-10 ms of physics has evicted the interpreter's and Drake's code from the CPU caches, and there each
Drake call from Python (argument conversion, context and cache bookkeeping, the result's conversion) costs
tens of microseconds: the pose and Jacobian took ~240 us of a ~5 ms tool-grasp step (``/tmp`` diagnostic).
:class:`SerialChainKinematics` reads the chain's fixed transforms and joint axes off the plant once and
evaluates the same products in ~400 float operations. The tests compare it with Drake's
``CalcPoseInWorld`` and ``CalcJacobianSpatialVelocity`` on random configurations.
"""

import math

from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, RevoluteJoint, WeldJoint

# A pose as (R, p): R the 9 entries of a rotation matrix, row by row, p the 3 of a translation.
Pose = tuple[list[float], list[float]]


def _pose(X: RigidTransform) -> Pose:
    return X.rotation().matrix().ravel().tolist(), X.translation().tolist()


def _compose(a: Pose, b: Pose) -> Pose:
    """a b."""
    (a0, a1, a2, a3, a4, a5, a6, a7, a8), (ax, ay, az) = a
    (b0, b1, b2, b3, b4, b5, b6, b7, b8), (bx, by, bz) = b
    return ([a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
             a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
             a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8],
            [a0 * bx + a1 * by + a2 * bz + ax, a3 * bx + a4 * by + a5 * bz + ay, a6 * bx + a7 * by + a8 * bz + az])


def _rotation(axis: list[float], angle: float) -> Pose:
    """The rotation by ``angle`` about unit ``axis`` (Rodrigues), as a pose with no translation."""
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return ([t * x * x + c, t * x * y - s * z, t * x * z + s * y,
             t * x * y + s * z, t * y * y + c, t * y * z - s * x,
             t * x * z - s * y, t * y * z + s * x, t * z * z + c], [0.0, 0.0, 0.0])


class SerialChainKinematics:
    """The pose of ``frame`` and the spatial Jacobian of a point on it, for a plant whose positions are all
    revolute joints on the chain from the world to ``frame``'s body (welds allowed anywhere on it).

    Args:
        plant: a finalized plant, e.g. the controller plant (:func:`seqdex_drake.station.MakeControllerPlant`).
        frame: the end frame (e.g. the palm's body frame).

    The transforms are the plant's default (fixed) frame poses; a plant whose frame offsets are parameters
    changed in a context is not followed.
    """

    def __init__(self, plant: MultibodyPlant, frame: Frame):
        inboard = {}  # Child body index -> the joint connecting it to its parent.
        for index in plant.GetJointIndices():
            joint = plant.get_joint(index)
            inboard[joint.child_body().index()] = joint
        chain, body = [], frame.body()
        while body.index() != plant.world_body().index():
            if body.index() not in inboard:
                raise ValueError(f"SerialChainKinematics: body '{body.name()}' has no inboard joint")
            joint = inboard[body.index()]
            chain.append(joint)
            body = joint.parent_body()
        chain.reverse()
        # X_W,frame = F_0 Rot(a_1, q_1) F_1 ... Rot(a_n, q_n) F_n, the F_i fixed (frame offsets and welds).
        fixed, axes, columns = _pose(RigidTransform()), [], []
        self._fixed = []
        for joint in chain:
            X_PF = joint.frame_on_parent().GetFixedPoseInBodyFrame()
            X_MC = joint.frame_on_child().GetFixedPoseInBodyFrame().inverse()
            if isinstance(joint, WeldJoint):
                fixed = _compose(fixed, _pose(X_PF @ joint.X_FM() @ X_MC))
            elif isinstance(joint, RevoluteJoint):
                self._fixed.append(_compose(fixed, _pose(X_PF)))
                axes.append(joint.revolute_axis().tolist())
                columns.append(joint.position_start())
                fixed = _pose(X_MC)
            else:
                raise ValueError(f"SerialChainKinematics: joint '{joint.name()}' is a {joint.type_name()} joint; "
                                 "only revolute and weld joints are supported")
        self._fixed.append(_compose(fixed, _pose(frame.GetFixedPoseInBodyFrame())))
        if sorted(columns) != list(range(plant.num_positions())) or plant.num_positions() != plant.num_velocities():
            raise ValueError("SerialChainKinematics: the plant's positions must be exactly the chain's revolute "
                             f"joints (it has {plant.num_positions()} positions, the chain {len(columns)} joints)")
        self._axes, self._columns = axes, columns

    def pose(self, q: list[float]) -> tuple[Pose, list[Pose]]:
        """(X_W,frame, the joint frames' poses M_i in the world) at positions ``q`` (plant order), as floats."""
        X, joints = self._fixed[0], []
        for axis, column, fixed in zip(self._axes, self._columns, self._fixed[1:], strict=True):
            X = _compose(X, _rotation(axis, q[column]))
            joints.append(X)
            X = _compose(X, fixed)
        return X, joints

    def jacobian(self, joints: list[Pose], p_WC: list[float]) -> list[list[float]]:
        """The 6 x n spatial Jacobian (rows: angular, then translational velocity, in the world) of the point
        at world position ``p_WC`` fixed on the end frame, with respect to q, from :meth:`pose`'s joint
        frames: column i is [w_i; w_i x (p_WC - p_WMi)], w_i the joint axis in the world."""
        J = [[0.0] * len(joints) for _ in range(6)]
        cx, cy, cz = p_WC
        for (axis_x, axis_y, axis_z), column, (R, (ox, oy, oz)) in zip(self._axes, self._columns, joints,
                                                                        strict=True):
            wx = R[0] * axis_x + R[1] * axis_y + R[2] * axis_z
            wy = R[3] * axis_x + R[4] * axis_y + R[5] * axis_z
            wz = R[6] * axis_x + R[7] * axis_y + R[8] * axis_z
            dx, dy, dz = cx - ox, cy - oy, cz - oz
            J[0][column], J[1][column], J[2][column] = wx, wy, wz
            J[3][column], J[4][column], J[5][column] = wy * dz - wz * dy, wz * dx - wx * dz, wx * dy - wy * dx
        return J
