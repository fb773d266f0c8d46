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
appends the pixel count (160).
"""

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.sensors import ImageLabel16I

from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY

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
"""The 4 fingertip rows of 13 (pose, linear, angular velocity): ``fingertip_positions`` takes their positions."""
OBJECT_QUATERNION = slice(114, 118)
"""The object's orientation [qw, qx, qy, qz], qw >= 0."""
GOAL_POSITION_ERROR = slice(166, 169)
"""Goal position - object position (Insert, tool Reorient)."""
GOAL_ROTATION_ERROR = slice(169, 173)
"""Goal quaternion * conj(object quaternion) (Insert, tool Reorient)."""


def fingertip_positions(observation: np.ndarray) -> np.ndarray:
    """(4, 3) world positions of the fingertips (index, middle, ring, thumb) in an observation."""
    return observation[FINGERTIPS].reshape(4, 13)[:, :3]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions [w, x, y, z] (float arithmetic: numpy's per-call overhead would be most
    of the cost of four-element maths, run every env step)."""
    a0, a1, a2, a3 = (float(x) for x in a)
    b0, b1, b2, b3 = (float(x) for x in b)
    return np.array([a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3, a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
                     a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1, a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0])


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=float)


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

    Input ports (connect to the station ports of the same names): ``franka.state``, ``allegro.state``,
    ``allegro.net_actuation``, ``body_poses``, ``body_spatial_velocities``; with ``pixels=True`` also
    ``label_image``. Input ``previous_action`` (19). Output ``observation``.

    Args:
        plant: the station's plant (for body and frame lookups; not kept in the loop).
        goal: append the 14 goal dimensions (Insert, tool Reorient).
        pixels: append the target-pixel count from a label image (Search).
    """

    def __init__(self, plant: MultibodyPlant, goal: bool = False, pixels: bool = False):
        super().__init__()
        hand = plant.GetModelInstanceByName("allegro")
        self._tips = [plant.GetFrameByName(name, hand) for name in FINGERTIP_FRAMES]
        self._tip_bodies = [int(f.body().index()) for f in self._tips]
        self._X_BF = [f.GetFixedPoseInBodyFrame() for f in self._tips]
        self._tips_are_bodies = all(X.IsExactlyIdentity() for X in self._X_BF)  # Our Allegro: tip links.
        self._palm = int(plant.GetBodyByName(PALM_BODY, hand).index())
        self._goal, self._pixels = goal, pixels
        self.size = BASE_SIZE + (GOAL_SIZE if goal else 0) + (1 if pixels else 0)
        self.DeclareVectorInputPort("franka.state", 14)
        self.DeclareVectorInputPort("allegro.state", 32)
        self.DeclareVectorInputPort("allegro.net_actuation", 16)
        self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([plant.world_body().body_frame()
                                                                       .CalcPoseInWorld(plant.CreateDefaultContext())]))
        self.DeclareAbstractInputPort("body_spatial_velocities", AbstractValue.Make([SpatialVelocity.Zero()]))
        self.DeclareVectorInputPort("previous_action", ACTION_SIZE)
        if pixels:
            self.DeclareAbstractInputPort("label_image", AbstractValue.Make(ImageLabel16I()))
        self._target_index = self.DeclareAbstractParameter(AbstractValue.Make(ObservationTarget()))
        self.DeclareVectorOutputPort("observation", self.size, self._calc)

    def set_target(self, context, target: ObservationTarget) -> None:
        """Sets the episode's target object, goal and label in this system's context."""
        context.get_mutable_abstract_parameter(self._target_index).set_value(target)

    def target(self, context) -> ObservationTarget:
        return context.get_abstract_parameter(self._target_index).get_value()

    def _calc(self, context, output: BasicVector) -> None:
        target = self.target(context)
        if target.object_body < 0:
            raise RuntimeError("ObservationAssembler: no target object set; call set_target() at reset")
        arm = self.get_input_port(0).Eval(context)
        hand = self.get_input_port(1).Eval(context)
        poses = self.get_input_port(3).Eval(context)
        velocities = self.get_input_port(4).Eval(context)
        out = np.empty(self.size)
        out[0:7], out[7:23], out[23:30], out[30:46] = arm[:7], hand[:16], arm[7:], hand[16:]
        # The 4 fingertip frames, the palm and the object, one 13-row each: pose (7), linear, angular velocity.
        X_WB = [poses[b] for b in self._tip_bodies]
        frames = X_WB if self._tips_are_bodies else [X.multiply(X_BF) for X, X_BF in zip(X_WB, self._X_BF,
                                                                                          strict=True)]
        frames = [*frames, poses[self._palm], poses[target.object_body]]
        rows = np.empty((6, 13))
        rows[:, :3] = [X.translation() for X in frames]
        quaternions = [X.rotation().ToQuaternion().wxyz() for X in frames]
        rows[:, 3:7] = [q if q[0] >= 0.0 else -q for q in quaternions]  # The hemisphere qw >= 0.
        V = np.array([velocities[b].get_coeffs() for b in (*self._tip_bodies, self._palm, target.object_body)])
        rows[:, 7:10], rows[:, 10:13] = V[:, 3:], V[:, :3]  # Drake's coefficients are [angular, linear].
        if not self._tips_are_bodies:  # A frame F fixed on body B moves at v_WB + w_WB x p_BF (in the world).
            rows[:4, 7:10] += np.cross(V[:4, :3], rows[:4, :3] - [X.translation() for X in X_WB])
        out[46:124] = rows.ravel()
        out[124:143] = self.get_input_port(5).Eval(context)
        out[143:159] = self.get_input_port(2).Eval(context)
        if self._goal:
            goal = np.asarray(target.goal, dtype=float)
            out[159:166], out[GOAL_POSITION_ERROR] = goal, goal[:3] - out[111:114]
            out[GOAL_ROTATION_ERROR] = quat_multiply(goal[3:], quat_conjugate(out[OBJECT_QUATERNION]))
        if self._pixels:
            image = self.GetInputPort("label_image").Eval(context)
            out[BASE_SIZE] = np.count_nonzero(image.data == target.label)
        output.SetFromVector(out)
