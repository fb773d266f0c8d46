"""Observation assembly: the paper's state vectors (appendix, "State Space in Simulation") from station ports.

Layout (indices as in the paper's tables; poses are 7 = position + quaternion wxyz, velocities linear then
angular, all in the world frame as in the authors' release):

====================  =========  ==========================================================
indices               size       content
====================  =========  ==========================================================
0-23                  23         joint positions, canonical order (Franka 1-7, Allegro 0-15)
23-46                 23         joint velocities
46-98                 4 x 13     fingertip pose, linear velocity, angular velocity
98-111                13         hand base (palm) pose, linear, angular velocity
111-124               13         object pose, linear, angular velocity
124-143               19         previous action (16 hand joints + 3 wrist translation)
143-159               16         motor tactile: torques the 16 Allegro motors exert
159-160 (Search)      1          target-object pixels in the top-down label image
159-173 (Insert)      14         goal pose (7), goal - object position (3), goal * conj(object) quaternion (4)
====================  =========  ==========================================================

Orient, Grasp and tool Grasp use the 159-dim base; Insert and tool Reorient append the goal (173); Search
appends the pixel count (160): counted in a whole label image, or, with a
:class:`~seqdex_drake.systems.target_pixels.TargetPixelCounter`, in a render of the target's region only (the
same count, in about half the render time).
"""

import dataclasses
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.sensors import ImageLabel16I

from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY
from seqdex_drake.systems.target_pixels import TargetPixelCounter

BASE_SIZE = 159
ACTION_SIZE = 19
GOAL_SIZE = 14


@dataclasses.dataclass
class ObservationTarget:
    """Per-episode observation parameters: which object, where its goal is, which label counts as target."""

    object_body: int = -1
    """Body index of the target object (-1 before the first reset)."""
    goal: np.ndarray = dataclasses.field(default_factory=lambda: np.array([0, 0, 0, 1.0, 0, 0, 0]))
    """Goal pose [x, y, z, qw, qx, qy, qz] (Insert, tool Reorient)."""
    label: int = -1
    """Render label of the target object in the label image (Search)."""


#: Parts of an observation that the env and the tasks read back (indices as in the table above).
FINGERTIPS = slice(46, 98)
"""The 4 fingertip rows of 13 (pose, linear, angular velocity)."""
PALM_POSE = slice(98, 105)
"""The palm (hand base) pose [x, y, z, qw, qx, qy, qz]."""
OBJECT_POSE = slice(111, 118)
"""The object's pose [x, y, z, qw, qx, qy, qz]."""
OBJECT_QUATERNION = slice(114, 118)
"""The object's orientation [qw, qx, qy, qz], qw >= 0."""
MOTOR_TACTILE = slice(143, 159)
"""The torques the 16 Allegro motors exert."""
GOAL_POSITION_ERROR = slice(166, 169)
"""Goal position - object position (Insert, tool Reorient)."""
GOAL_ROTATION_ERROR = slice(169, 173)
"""Goal quaternion * conj(object quaternion) (Insert, tool Reorient)."""


def floats(v) -> list[float]:
    """The entries of a short vector (array, list or tuple) as Python floats, for plain float arithmetic:
    numpy's per-call overhead would be most of the cost of three- and four-element maths, run every env step."""
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]


def point_in_world(pose: list[float], p_BQ: list[float]) -> list[float]:
    """p_WQ of a point Q fixed in a body B, from B's pose [x, y, z, qw, qx, qy, qz] (e.g. an observation's
    ``PALM_POSE`` entries), as floats: p_WB + R(q) p_BQ, with R(q) v = v + 2 w (u x v) + 2 u x (u x v) for
    q = [w, u], in float arithmetic."""
    x, y, z, w, ux, uy, uz = pose
    vx, vy, vz = p_BQ
    tx, ty, tz = 2.0 * (uy * vz - uz * vy), 2.0 * (uz * vx - ux * vz), 2.0 * (ux * vy - uy * vx)  # 2 u x v
    return [x + vx + w * tx + uy * tz - uz * ty, y + vy + w * ty + uz * tx - ux * tz,
            z + vz + w * tz + ux * ty - uy * tx]


def quat_product(a, b) -> list[float]:
    """Hamilton product of quaternions [w, x, y, z] (short sequences of floats), as a list of floats."""
    a0, a1, a2, a3 = a
    b0, b1, b2, b3 = b
    return [a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3, a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1, a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions [w, x, y, z] (see :func:`quat_product`)."""
    return np.array(quat_product(floats(a), floats(b)))


def quat_conjugate(q) -> list[float]:
    """[w, -x, -y, -z] of a quaternion [w, x, y, z], as a list of floats."""
    w, x, y, z = floats(q)
    return [w, -x, -y, -z]


def quaternion_wxyz(r0: list[float], r1: list[float], r2: list[float]) -> list[float]:
    """The unit quaternion [w, x, y, z], w >= 0, of a rotation matrix given by its rows (floats; extra columns
    are ignored, so the rows of a 3 x 4 [R | p] do), by Shepperd's method: the largest of 4 w^2 = 1 + tr R,
    4 x^2 = 1 + 2 r00 - tr R, ... fixes the divisor. Plain float arithmetic: per-matrix conversions through
    Drake cost a few Python calls each, and numpy's per-call overhead would be most of the cost, every env step."""
    r00, r01, r02 = r0[0], r0[1], r0[2]
    r10, r11, r12 = r1[0], r1[1], r1[2]
    r20, r21, r22 = r2[0], r2[1], r2[2]
    trace = r00 + r11 + r22
    if trace >= r00 and trace >= r11 and trace >= r22:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s]
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = [(r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s]
    elif r11 >= r22:
        s = 2.0 * math.sqrt(1.0 - r00 + r11 - r22)
        q = [(r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s]
    else:
        s = 2.0 * math.sqrt(1.0 - r00 - r11 + r22)
        q = [(r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s]
    return q if q[0] >= 0.0 else [-q[0], -q[1], -q[2], -q[3]]


def quaternions_wxyz(R: np.ndarray) -> list[list[float]]:
    """:func:`quaternion_wxyz` of each of (n, 3, 3) rotation matrices."""
    return [quaternion_wxyz(*rows) for rows in np.asarray(R, dtype=float).tolist()]


def pose_vector(X) -> np.ndarray:
    """[x, y, z, qw, qx, qy, qz] of a RigidTransform, with qw >= 0."""
    out = np.empty(7)
    _write_pose(out, 0, X)
    return out


def _write_pose(out: np.ndarray, start: int, X) -> None:
    """Writes :func:`pose_vector` of ``X`` into ``out[start:start + 7]``."""
    q = X.rotation().ToQuaternion().wxyz()
    out[start:start + 3] = X.translation()
    out[start + 3:start + 7] = q if q[0] >= 0 else -q


class ObservationAssembler(LeafSystem):
    """Assembles the paper's observation vector from the station's output ports.

    Input ports (connect to the station ports of the same names): ``plant_state`` (the whole plant's
    [q, v]) and ``allegro.net_actuation``; with ``pixels=True`` also ``label_image``, with a pixel counter
    ``query_object``. Input ``previous_action`` (19). Output ``observation``.

    The fingertip, palm and object kinematics are computed from ``plant_state`` on a plant context of the
    system's own (a scratch workspace, overwritten at every evaluation, as in the manipulation course's
    controllers): six bodies' poses and velocities, where the plant's ``body_poses`` and
    ``body_spatial_velocities`` ports would convert all of them to Python objects at every control step. The
    kinematics use the plant's default parameters, which domain randomization does not change for them (it
    scales masses, inertias, friction, joint limits, stiffness and damping, not frame offsets).

    Args:
        plant: the station's plant, or one built from the same scenario (kept for the kinematics).
        goal: append the 14 goal dimensions (Insert, tool Reorient).
        pixels: append the target-pixel count (Search): True counts it in the ``label_image`` input; a
            :class:`~seqdex_drake.systems.target_pixels.TargetPixelCounter` renders the target's region of its
            camera's image from the ``query_object`` input (the plant must be registered with that scene graph).
    """

    def __init__(self, plant: MultibodyPlant, goal: bool = False, pixels: bool | TargetPixelCounter = False):
        super().__init__()
        hand, arm = plant.GetModelInstanceByName("allegro"), plant.GetModelInstanceByName("franka")
        self._plant = plant
        self._scratch = plant.CreateDefaultContext()
        self._nq = plant.num_positions()
        # Where the canonical joint order (Franka 1-7, Allegro 0-15) sits in the plant state [q, v].
        q_index, v_index = np.arange(self._nq, dtype=float), np.arange(plant.num_velocities(), dtype=float)
        self._joint_index = np.concatenate(
            [plant.GetPositionsFromArray(arm, q_index), plant.GetPositionsFromArray(hand, q_index),
             self._nq + plant.GetVelocitiesFromArray(arm, v_index),
             self._nq + plant.GetVelocitiesFromArray(hand, v_index)]).astype(int).tolist()
        self._tips = [plant.GetFrameByName(name, hand) for name in FINGERTIP_FRAMES]
        self._tip_bodies = [f.body() for f in self._tips]
        self._X_BF = np.array([f.GetFixedPoseInBodyFrame().GetAsMatrix34() for f in self._tips])  # (4, 3, 4)
        self._tips_are_bodies = all(f.GetFixedPoseInBodyFrame().IsExactlyIdentity() for f in self._tips)
        self._palm = plant.GetBodyByName(PALM_BODY, hand)
        self._bodies = {}  # Body index -> body, of the target objects seen (set_target).
        self._frames = {}  # Body index -> its geometry frame (with a pixel counter).
        self._counter = pixels if isinstance(pixels, TargetPixelCounter) else None
        self._goal, self._pixels = goal, bool(pixels)
        self.size = BASE_SIZE + (GOAL_SIZE if goal else 0) + (1 if pixels else 0)
        self.DeclareVectorInputPort("plant_state", self._nq + plant.num_velocities())
        self.DeclareVectorInputPort("allegro.net_actuation", 16)
        self.DeclareVectorInputPort("previous_action", ACTION_SIZE)
        if self._counter is not None:
            self.DeclareAbstractInputPort("query_object", AbstractValue.Make(QueryObject()))
        elif pixels:
            self.DeclareAbstractInputPort("label_image", AbstractValue.Make(ImageLabel16I()))
        self._target_index = self.DeclareAbstractParameter(AbstractValue.Make(ObservationTarget()))
        self.DeclareVectorOutputPort("observation", self.size, self._calc)

    def set_target(self, context, target: ObservationTarget) -> None:
        """Sets the episode's target object, goal and label in this system's context."""
        if target.object_body >= 0 and target.object_body not in self._bodies:
            if not 0 <= target.object_body < self._plant.num_bodies():
                raise ValueError(f"ObservationAssembler: no body with index {target.object_body} in the plant "
                                 f"({self._plant.num_bodies()} bodies)")
            self._bodies[target.object_body] = self._plant.get_body(BodyIndex(target.object_body))
            if self._counter is not None:
                self._frames[target.object_body] = self._plant.GetBodyFrameIdOrThrow(BodyIndex(target.object_body))
        context.get_mutable_abstract_parameter(self._target_index).set_value(target)

    def target(self, context) -> ObservationTarget:
        return context.get_abstract_parameter(self._target_index).get_value()

    def _calc(self, context, output: BasicVector) -> None:
        target = self.target(context)
        self._plant.SetPositionsAndVelocities(self._scratch, self.get_input_port(0).Eval(context))
        pixel_input = self.get_input_port(3).Eval(context) if self._pixels else None
        output.SetFromVector(self.assemble(self._scratch, target, self.get_input_port(2).Eval(context),
                                           self.get_input_port(1).Eval(context), pixel_input))

    def assemble(self, plant_context, target: ObservationTarget, previous_action: np.ndarray,
                 net_actuation: np.ndarray, pixel_input=None) -> np.ndarray:
        """The observation of the state in ``plant_context``, a context of the plant this system was built with.

        The output port computes it on the system's own plant context, from its input ports. A caller that
        owns the plant's context and the other inputs (``SubtaskEnv``) gets the same vector directly, without
        copying the state or computing the kinematics twice (the plant's own context keeps them for its next
        step). ``pixel_input``: with pixels, the label image (``pixels=True``) or the query object (a counter)."""
        return np.array(self.assemble_values(plant_context, target, previous_action, net_actuation, pixel_input))

    def assemble_values(self, plant_context, target: ObservationTarget, previous_action, net_actuation,
                        pixel_input=None, plant_state: list[float] | None = None) -> list[float]:
        """:meth:`assemble` as a list of floats (what ``SubtaskEnv.step`` reads back in float arithmetic).
        ``plant_state``: the plant's [q, v] in ``plant_context`` as a list of floats, where the caller has it.

        Built in plain Python from a handful of Drake calls and ``tolist()`` conversions: right after a
        physics step this code runs with the caches cold, where every distinct numpy function costs several
        microseconds (see the README's "Where the env time goes"), and a list of ~160 floats is cheap."""
        if target.object_body not in self._bodies:
            raise RuntimeError("ObservationAssembler: no target object set; call set_target() at reset")
        plant = self._plant
        x = plant.GetPositionsAndVelocities(plant_context).tolist() if plant_state is None else plant_state
        values = [x[i] for i in self._joint_index]
        # The 4 fingertip frames, the palm and the object, one 13-row each: pose (7), linear, angular velocity.
        bodies = (*self._tip_bodies, self._palm, self._bodies[target.object_body])
        poses = [plant.EvalBodyPoseInWorld(plant_context, body).GetAsMatrix34().tolist() for body in bodies]
        velocities = [plant.EvalBodySpatialVelocityInWorld(plant_context, body).get_coeffs().tolist()
                      for body in bodies]  # Drake's coefficients are [angular, linear].
        if not self._tips_are_bodies:
            self._tip_frames_from_bodies(poses, velocities)
        for (r0, r1, r2), (wx, wy, wz, vx, vy, vz) in zip(poses, velocities, strict=True):
            values += (r0[3], r1[3], r2[3])
            values += quaternion_wxyz(r0, r1, r2)  # The hemisphere qw >= 0.
            values += (vx, vy, vz, wx, wy, wz)
        values += floats(previous_action)
        values += floats(net_actuation)
        if self._goal:
            goal = floats(target.goal)
            values += goal
            values += (goal[0] - values[111], goal[1] - values[112], goal[2] - values[113])
            values += quat_product(goal[3:], quat_conjugate(values[114:118]))
        if self._counter is not None:
            values.append(float(self._counter.count(pixel_input, target.label, self._frames[target.object_body],
                                                    poses[5])))
        elif self._pixels:
            values.append(float(np.count_nonzero(pixel_input.data == target.label)))
        return values

    def _tip_frames_from_bodies(self, poses: list, velocities: list) -> None:
        """Replaces the first four bodies' poses and velocities by their fingertip frames' (in place), for a
        hand model whose fingertip frames are offset in their bodies: X_WF = X_WB X_BF; F moves at
        v_WB + w_WB x p_BF (in the world)."""
        X, V = np.array(poses[:4]), np.array(velocities[:4])
        R_WB, X_BF = X[:, :, :3], self._X_BF
        p_BF_W = np.einsum("nij,nj->ni", R_WB, X_BF[:, :, 3])
        V[:, 3:] += np.cross(V[:, :3], p_BF_W)
        X[:, :, 3] += p_BF_W
        X[:, :, :3] = R_WB @ X_BF[:, :, :3]
        poses[:4], velocities[:4] = X.tolist(), V.tolist()
