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


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions [w, x, y, z]."""
    w0, v0, w1, v1 = a[0], a[1:], b[0], b[1:]
    return np.r_[w0 * w1 - v0 @ v1, w0 * v1 + w1 * v0 + np.cross(v0, v1)]


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    return np.r_[q[0], -q[1:]]


def pose_vector(X) -> np.ndarray:
    """[x, y, z, qw, qx, qy, qz] of a RigidTransform, with qw >= 0."""
    q = X.rotation().ToQuaternion().wxyz()
    return np.r_[X.translation(), q if q[0] >= 0 else -q]


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

    def _body_state(self, poses, velocities, body: int, X_BF=None) -> np.ndarray:
        X_WB = poses[body]
        V = velocities[body]
        if X_BF is None:
            return np.r_[pose_vector(X_WB), V.translational(), V.rotational()]
        X_WF = X_WB @ X_BF
        v_WF = V.translational() + np.cross(V.rotational(), X_WB.rotation() @ X_BF.translation())
        return np.r_[pose_vector(X_WF), v_WF, V.rotational()]

    def _calc(self, context, output: BasicVector) -> None:
        target = self.target(context)
        if target.object_body < 0:
            raise RuntimeError("ObservationAssembler: no target object set; call set_target() at reset")
        arm = self.get_input_port(0).Eval(context)
        hand = self.get_input_port(1).Eval(context)
        tactile = self.get_input_port(2).Eval(context)
        poses = self.get_input_port(3).Eval(context)
        velocities = self.get_input_port(4).Eval(context)
        previous_action = self.get_input_port(5).Eval(context)
        tips = [self._body_state(poses, velocities, b, X) for b, X in zip(self._tip_bodies, self._X_BF, strict=True)]
        obj = self._body_state(poses, velocities, target.object_body)
        parts = [arm[:7], hand[:16], arm[7:], hand[16:], *tips, self._body_state(poses, velocities, self._palm),
                 obj, previous_action, tactile]
        if self._goal:
            goal = np.asarray(target.goal, dtype=float)
            parts += [goal, goal[:3] - obj[:3], quat_multiply(goal[3:], quat_conjugate(obj[3:7]))]
        if self._pixels:
            image = self.GetInputPort("label_image").Eval(context)
            parts.append([np.count_nonzero(image.data == target.label)])
        output.SetFromVector(np.concatenate([np.ravel(p) for p in parts]))
