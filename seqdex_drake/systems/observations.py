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

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.sensors import ImageLabel16I

from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY
from seqdex_drake.robots.tree_kinematics import TreeKinematics
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

    The fingertip, palm and object poses and velocities are computed from ``plant_state`` by the compiled
    :class:`~seqdex_drake.robots.tree_kinematics.TreeKinematics` (one call, no plant context), with the plant's
    default frame offsets, which domain randomization does not change (it scales masses, inertias, friction,
    joint limits, stiffness and damping, and object geometry).

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
        self._nq = plant.num_positions()
        # Where the canonical joint order (Franka 1-7, Allegro 0-15) sits in the plant state [q, v].
        q_index, v_index = np.arange(self._nq, dtype=float), np.arange(plant.num_velocities(), dtype=float)
        self._joint_index = np.concatenate(
            [plant.GetPositionsFromArray(arm, q_index), plant.GetPositionsFromArray(hand, q_index),
             self._nq + plant.GetVelocitiesFromArray(arm, v_index),
             self._nq + plant.GetVelocitiesFromArray(hand, v_index)]).astype(int).tolist()
        # The four fingertip frames and the palm; each target object's body frame is appended (set_target).
        self._frames = [plant.GetFrameByName(name, hand) for name in FINGERTIP_FRAMES]
        self._frames.append(plant.GetBodyByName(PALM_BODY, hand).body_frame())
        self._kinematics = {}  # Target body index -> TreeKinematics of the six frames.
        self._frame_ids = {}  # Target body index -> its geometry frame (with a pixel counter).
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
        if target.object_body >= 0 and target.object_body not in self._kinematics:
            if not 0 <= target.object_body < self._plant.num_bodies():
                raise ValueError(f"ObservationAssembler: no body with index {target.object_body} in the plant "
                                 f"({self._plant.num_bodies()} bodies)")
            body = self._plant.get_body(BodyIndex(target.object_body))
            self._kinematics[target.object_body] = TreeKinematics(self._plant, self._frames + [body.body_frame()])
            if self._counter is not None:
                self._frame_ids[target.object_body] = self._plant.GetBodyFrameIdOrThrow(body.index())
        context.get_mutable_abstract_parameter(self._target_index).set_value(target)

    def target(self, context) -> ObservationTarget:
        return context.get_abstract_parameter(self._target_index).get_value()

    def _calc(self, context, output: BasicVector) -> None:
        pixel_input = self.get_input_port(3).Eval(context) if self._pixels else None
        output.SetFromVector(self.assemble_values(self.get_input_port(0).Eval(context).tolist(), self.target(context),
                                                  self.get_input_port(2).Eval(context),
                                                  self.get_input_port(1).Eval(context), pixel_input))

    def assemble(self, plant_context, target: ObservationTarget, previous_action: np.ndarray,
                 net_actuation: np.ndarray, pixel_input=None) -> np.ndarray:
        """The observation of the state in ``plant_context`` (a context of the plant this system was built with)
        and the given inputs: what the output port computes from its input ports. ``pixel_input``: with pixels,
        the label image (``pixels=True``) or the query object (a counter)."""
        return np.array(self.assemble_values(self._plant.GetPositionsAndVelocities(plant_context).tolist(), target,
                                             previous_action, net_actuation, pixel_input))

    def assemble_values(self, plant_state: list[float], target: ObservationTarget, previous_action, net_actuation,
                        pixel_input=None) -> list[float]:
        """:meth:`assemble` of the plant's state [q, v] given as a list of floats, as a list of floats (what
        ``SubtaskEnv.step`` reads back in float arithmetic).

        Built in plain Python around one compiled kinematics call: right after a physics step this code runs
        with the caches cold, where every distinct numpy function or Drake call costs several microseconds
        (see docs/performance.md, "How the env time is spent"), and a list of ~160 floats is cheap."""
        kinematics = self._kinematics.get(target.object_body)
        if kinematics is None:
            raise RuntimeError(
                "ObservationAssembler: no target object set. In a chain controller, call SetChainTarget(controller, "
                "root_context, object_body[, goal]) after creating the context and before simulating; in a sub-task "
                "environment, call env.reset() first (the task's reset calls env.set_target(name[, goal])); a "
                "standalone assembler needs assembler.set_target(context, ObservationTarget(...))")
        x = plant_state
        values = [x[i] for i in self._joint_index]
        # The 4 fingertip frames, the palm and the object, one 13-row each: position, quaternion (the hemisphere
        # qw >= 0), linear and angular velocity.
        values += kinematics.states(x)
        values += floats(previous_action)
        values += floats(net_actuation)
        if self._goal:
            goal = floats(target.goal)
            values += goal
            values += (goal[0] - values[111], goal[1] - values[112], goal[2] - values[113])
            values += quat_product(goal[3:], quat_conjugate(values[114:118]))
        if self._counter is not None:
            R, p = (entries := kinematics.poses(x)[60:72])[:9], entries[9:]  # The object's X_WB.
            X_WB = [[R[0], R[1], R[2], p[0]], [R[3], R[4], R[5], p[1]], [R[6], R[7], R[8], p[2]]]
            values.append(float(self._counter.count(pixel_input, target.label, self._frame_ids[target.object_body],
                                                    X_WB)))
        elif self._pixels:
            values.append(float(np.count_nonzero(pixel_input.data == target.label)))
        return values
