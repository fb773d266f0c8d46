"""Observation assembly: the paper's state vectors (appendix, "State Space in Simulation") from station ports.

The layout itself (which entries hold what, the index slices and sizes, ``pose_vector``, ``floats`` and the
quaternion helpers) lives in :mod:`seqdex_drake.observation_layout`, in the plain-data layer, so that the
sub-tasks read it without importing this Drake system; every name is re-exported here.

Orient, Grasp and tool Grasp use the 159-dim base; Insert and tool Reorient append the goal (173); Search
appends the pixel count (160): counted in a whole label image, or, with a
:class:`~seqdex_drake.sensors.target_pixels.TargetPixelCounter`, in a render of the target's region only (the
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

from seqdex_drake.observation_layout import (  # noqa: F401 (the layout's names, re-exported)
    ACTION_SIZE,
    BASE_SIZE,
    FINGERTIPS,
    GOAL_POSITION_ERROR,
    GOAL_ROTATION_ERROR,
    GOAL_SIZE,
    MOTOR_TACTILE,
    OBJECT_POSE,
    OBJECT_QUATERNION,
    PALM_POSE,
    floats,
    point_in_world,
    pose_vector,
    quat_conjugate,
    quat_multiply,
    quat_product,
)
from seqdex_drake.robots.allegro import FINGERTIP_FRAMES, PALM_BODY
from seqdex_drake.robots.tree_kinematics import TreeKinematics
from seqdex_drake.sensors.target_pixels import TargetPixelCounter


@dataclasses.dataclass
class ObservationTarget:
    """Per-episode observation parameters: which object, where its goal is, which label counts as target."""

    object_body: int = -1
    """Body index of the target object (-1 before the first reset)."""
    goal: np.ndarray = dataclasses.field(default_factory=lambda: np.array([0, 0, 0, 1.0, 0, 0, 0]))
    """Goal pose [x, y, z, qw, qx, qy, qz] (Insert, tool Reorient)."""
    label: int = -1
    """Render label of the target object in the label image (Search)."""
    approach_offset: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    """Where the chain's approach aims relative to the object's centre of mass (world frame, m) for stages without
    a goal pose: the point the sub-task's env hovers the hand over at reset (a tool: its top, ``height / 2`` up)."""
    rest_height: float = float("nan")
    """World height (m) of the target object's centre of mass where it rested at the start; NaN: unknown (the
    object never counts as lifted, ``ApproachTarget``'s ``object_lifted``)."""


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
            :class:`~seqdex_drake.sensors.target_pixels.TargetPixelCounter` renders the target's region of its
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
