"""The station: one Diagram holding the Franka + Allegro, fixtures and objects of a scenario.

``MakeStation(scenario, meshcat=None, name=None)`` returns a Diagram whose exported ports are named
``<model_instance>.<signal>``; outside code connects by name and never reaches inside:

Inputs
    ``franka.desired_state`` (14: q, v), ``allegro.desired_state`` (32): targets of the plant's built-in
    joint PD controllers. A disconnected desired state disarms that instance's PD controllers.
Outputs
    ``franka.state``, ``allegro.state``: positions and velocities in the canonical joint order.
    ``franka.net_actuation``, ``allegro.net_actuation``: joint torques the motors exert (PD + feedforward);
    the Allegro one is the paper's *motor tactile* signal. With the scenarios' sampled output ports these
    and ``contact_results`` are the plant's last step's; after editing a state without stepping, call
    :func:`RefreshSampledOutputs` (the environments and harnesses do).
    ``<object>.state`` for each loose object (quaternion pose and twist, 13).
    ``body_poses``, ``body_spatial_velocities``, ``contact_results``, ``query_object``, ``plant_state``.
    ``<camera>.color_image`` / ``.depth_image_32f`` / ``.label_image`` for each configured camera (those it enables).

The Franka receives gravity compensation (its joints' gravity torques with the hand attached).
:func:`MakeControllerPlant` builds, from the same directives, the plant an operational-space controller
needs: the Franka with the Allegro welded on and frozen. Keep a Python reference to it as long as any
System uses it (pydrake does not keep it alive for C++ systems such as ``InverseDynamics``).

Several stations in one diagram: give each its own ``name``. It names the Diagram (Drake requires unique
subsystem names) and prefixes the station's Meshcat paths (``/drake/<name>/illustration``, ``.../proximity``,
``.../contact_forces``), so stations sharing one Meshcat keep separate scene trees instead of overwriting each
other's (each can be hidden in Meshcat's controls). The model instances inside keep their names (``franka``,
``allegro``, ``block_2``): each station has its own plant, and the code that drives a station looks its
instances up in that plant by these names.
"""

from __future__ import annotations

import fnmatch

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.geometry import (
    MakeRenderEngineVtk,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    RenderEngineVtkParams,
    Role,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.meshcat import ContactVisualizer, ContactVisualizerParams
from pydrake.multibody.parsing import (
    LoadModelDirectives,
    ModelDirective,
    ModelDirectives,
    Parser,
    ProcessModelDirectives,
)
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex, PdControllerGains, RevoluteJoint, WeldJoint
from pydrake.systems.controllers import InverseDynamics
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import MatrixGain
from pydrake.systems.sensors import CameraConfig, RgbdSensor
from pydrake.visualization import VisualizationConfig

from seqdex_drake.robots.allegro import ALLEGRO_JOINT_NAMES, ALLEGRO_OPEN_Q
from seqdex_drake.robots.franka import FRANKA_JOINT_NAMES
from seqdex_drake.scenario import MODELS_DIR, MODELS_PACKAGE, Scenario, ScenarioError
from seqdex_drake.scene.freezing import AddObjectFreezer
from seqdex_drake.scene.perception_geometry import UseLowPolyPerceptionGeometry

FRANKA = "franka"
ALLEGRO = "allegro"
ROBOT_INSTANCES = (FRANKA, ALLEGRO)
#: The 23 actuated joints in canonical order: Franka 1-7, then Allegro 0-15 (index, middle, ring, thumb).
CANONICAL_JOINTS = tuple(f"{FRANKA}::{n}" for n in FRANKA_JOINT_NAMES) + tuple(
    f"{ALLEGRO}::{n}" for n in ALLEGRO_JOINT_NAMES)


def MakeParser(plant: MultibodyPlant) -> Parser:
    """A Parser that resolves ``package://seqdex_models/...`` to this repository's ``models/``."""
    parser = Parser(plant)
    parser.package_map().Add(MODELS_PACKAGE, str(MODELS_DIR))
    return parser


def _process_directives(directives: list[ModelDirective], plant: MultibodyPlant) -> None:
    try:
        ProcessModelDirectives(ModelDirectives(directives=directives), plant, MakeParser(plant))
    except RuntimeError as error:
        raise ScenarioError(f"cannot load the scenario's models: {error}") from error


def _robot_directives(directives: list[ModelDirective], parser: Parser) -> list[ModelDirective]:
    """The directives that add and attach the Franka and the Allegro (for the controller plant).

    Included directive files (``add_directives``) are expanded so the filter sees every directive.
    """
    kept = []
    for directive in directives:
        if directive.add_directives is not None:
            path = parser.package_map().ResolveUrl(directive.add_directives.file)
            kept += _robot_directives(LoadModelDirectives(path).directives, parser)
        elif directive.add_model is not None and directive.add_model.name in ROBOT_INSTANCES:
            kept.append(directive)
        elif directive.add_weld is not None and directive.add_weld.child.split("::")[0] in ROBOT_INSTANCES:
            kept.append(directive)
    return kept


def ResolveObjectNames(plant: MultibodyPlant, patterns: list[str]) -> list[str]:
    """Expands shell-style patterns (``block_*``) against the plant's model instance names, in order."""
    instances = [plant.GetModelInstanceName(plant.GetModelInstanceByName(n)) for n in _instance_names(plant)]
    names: list[str] = []
    for pattern in patterns:
        matched = [n for n in instances if fnmatch.fnmatchcase(n, pattern)]
        if not matched:
            raise ScenarioError(f"objects entry '{pattern}' matches no model instance; instances: "
                                f"{', '.join(instances)}")
        names += [n for n in matched if n not in names]
    return names


def _instance_names(plant: MultibodyPlant) -> list[str]:
    return [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]


def _check_robot(plant: MultibodyPlant) -> None:
    for name in ROBOT_INSTANCES:
        if not plant.HasModelInstanceNamed(name):
            raise ScenarioError(f"the scenario's directives must add a model instance named '{name}'")
    for full_name in CANONICAL_JOINTS:
        instance, joint = full_name.split("::")
        if not plant.HasJointNamed(joint, plant.GetModelInstanceByName(instance)):
            raise ScenarioError(f"model instance '{instance}' has no joint '{joint}'")


def _freeze_hand(plant: MultibodyPlant, hand_q: np.ndarray) -> None:
    """Replaces every Allegro joint (and actuator) by a weld at ``hand_q`` (pre-Finalize)."""
    hand = plant.GetModelInstanceByName(ALLEGRO)
    # GetJointActuatorIndices(instance) is empty before Finalize(): filter the full list instead.
    for index in plant.GetJointActuatorIndices():
        if plant.get_joint_actuator(index).model_instance() == hand:
            plant.RemoveJointActuator(plant.get_joint_actuator(index))
    for name, angle in zip(ALLEGRO_JOINT_NAMES, hand_q, strict=True):
        joint = plant.GetJointByName(name, hand)
        assert isinstance(joint, RevoluteJoint)
        frame_on_parent, frame_on_child = joint.frame_on_parent(), joint.frame_on_child()
        X_FM = RigidTransform(RotationMatrix(AngleAxis(angle, joint.revolute_axis())), np.zeros(3))
        plant.RemoveJoint(joint)
        plant.AddJoint(WeldJoint(f"{name}_frozen", frame_on_parent, frame_on_child, X_FM))


def MakeControllerPlant(scenario: Scenario) -> MultibodyPlant:
    """The Franka with the Allegro welded on and frozen at its open pose, from the scenario's directives.

    Used for gravity compensation and by the operational-space controller. Finalized, continuous-time.
    """
    plant = MultibodyPlant(time_step=0.0)
    _process_directives(_robot_directives(scenario.directives, MakeParser(plant)), plant)
    _check_robot(plant)
    _freeze_hand(plant, ALLEGRO_OPEN_Q)
    plant.Finalize()
    return plant


def _configure_actuators(plant: MultibodyPlant, scenario: Scenario) -> None:
    gains = {FRANKA: PdControllerGains(p=scenario.robot.arm_kp, d=scenario.robot.arm_kd),
             ALLEGRO: PdControllerGains(p=scenario.robot.hand_kp, d=scenario.robot.hand_kd)}
    for name, pd in gains.items():
        instance = plant.GetModelInstanceByName(name)
        for index in plant.GetJointActuatorIndices():  # The per-instance overload is empty pre-Finalize.
            actuator = plant.get_joint_actuator(index)
            if actuator.model_instance() != instance:
                continue
            actuator.set_controller_gains(pd)
            if name == ALLEGRO and scenario.robot.hand_rotor_inertia > 0:
                actuator.set_default_rotor_inertia(scenario.robot.hand_rotor_inertia)
                actuator.set_default_gear_ratio(1.0)


def _set_default_robot_positions(plant: MultibodyPlant, scenario: Scenario) -> None:
    arm_home = np.asarray(scenario.robot.arm_home, dtype=float)
    if arm_home.shape != (7,):
        raise ScenarioError(f"robot.arm_home must list 7 joint angles, got {arm_home.size}")
    for name, q in zip(FRANKA_JOINT_NAMES, arm_home, strict=True):
        plant.GetJointByName(name, plant.GetModelInstanceByName(FRANKA)).set_default_angle(q)
    for name, q in zip(ALLEGRO_JOINT_NAMES, ALLEGRO_OPEN_Q, strict=True):
        plant.GetJointByName(name, plant.GetModelInstanceByName(ALLEGRO)).set_default_angle(q)


def AddStationPlant(builder: DiagramBuilder, scenario: Scenario) -> tuple[MultibodyPlant, SceneGraph]:
    """Adds the scenario's MultibodyPlant and SceneGraph to ``builder``; the plant is finalized."""
    plant, scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    plant.set_name("plant")
    scene_graph.set_name("scene_graph")
    _process_directives(scenario.directives, plant)
    _check_robot(plant)
    scenario.objects = ResolveObjectNames(plant, scenario.objects)
    _configure_actuators(plant, scenario)
    plant.Finalize()
    _set_default_robot_positions(plant, scenario)
    return plant, scene_graph


def AddArmGravityCompensation(builder: DiagramBuilder, plant: MultibodyPlant) -> None:
    """Feeds the Franka joints' gravity torques forward into the Franka actuators.

    Computed on the station plant itself (C++ ``InverseDynamics`` in gravity-compensation mode), so the
    torques include the hand at its current configuration; the arm's 7 entries are selected by a gain.
    """
    gravity = builder.AddSystem(InverseDynamics(plant, InverseDynamics.InverseDynamicsMode.kGravityCompensation))
    gravity.set_name("franka.gravity_compensation")
    franka = plant.GetModelInstanceByName(FRANKA)
    selector = np.zeros((7, plant.num_velocities()))
    for row, name in enumerate(FRANKA_JOINT_NAMES):
        selector[row, plant.GetJointByName(name, franka).velocity_start()] = 1.0
    select = builder.AddSystem(MatrixGain(selector))
    select.set_name("franka.gravity_selector")
    builder.Connect(plant.get_state_output_port(), gravity.get_input_port_estimated_state())
    builder.Connect(gravity.get_output_port_generalized_force(), select.get_input_port())
    builder.Connect(select.get_output_port(), plant.get_actuation_input_port(franka))


def AddCamera(builder: DiagramBuilder, plant: MultibodyPlant, scene_graph: SceneGraph, name: str,
              camera: CameraConfig) -> RgbdSensor:
    """Adds an RgbdSensor (no LCM) rendering with VTK; exports ``<name>.color_image``, ``<name>.depth_image_32f``
    and ``<name>.label_image``, those the config enables (the camera's pose is not exported)."""
    renderer = camera.renderer_name
    if not scene_graph.HasRenderer(renderer):
        scene_graph.AddRenderer(renderer, MakeRenderEngineVtk(RenderEngineVtkParams()))
    color, depth = camera.MakeCameras()
    parent = plant.GetFrameByName(camera.X_PB.base_frame) if camera.X_PB.base_frame else plant.world_frame()
    X_PB = camera.X_PB.GetDeterministicValue()
    sensor = builder.AddSystem(RgbdSensor(parent_id=plant.GetBodyFrameIdOrThrow(parent.body().index()),
                                          X_PB=parent.GetFixedPoseInBodyFrame() @ X_PB,
                                          color_camera=color, depth_camera=depth))
    sensor.set_name(f"camera_{name}")
    builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
    for enabled, port in ((camera.rgb, "color_image"), (camera.depth, "depth_image_32f"),
                          (camera.label, "label_image")):
        if enabled:
            builder.ExportOutput(sensor.GetOutputPort(port), f"{name}.{port}")
    return sensor


def CheckSystemName(name: str) -> str:
    """Returns ``name`` if it can name a station or chain controller: a non-empty string with neither Drake's
    system path separator ``::`` nor Meshcat's ``/`` (it becomes one Meshcat path element); else ValueError."""
    if not isinstance(name, str) or not name or "::" in name or "/" in name:
        raise ValueError(f"name must be a non-empty string without '::' or '/', got {name!r}")
    return name


def MeshcatPath(prefix: str | None, path: str) -> str:
    """``<prefix>/<path>`` (``path`` itself when ``prefix`` is None): where a named system draws in Meshcat."""
    return path if prefix is None else f"{prefix}/{path}"


def AddMeshcatVisualization(builder: DiagramBuilder, plant: MultibodyPlant, scene_graph: SceneGraph, meshcat,
                            config: VisualizationConfig, prefix: str | None = None) -> None:
    """Meshcat visualizers per ``config`` (illustration, proximity, contacts), without any LCM traffic.

    ``pydrake.visualization.ApplyVisualizationConfig`` would also publish LCM (UDP multicast) messages for
    drake-visualizer; the station only talks to the Meshcat given. They draw at the Meshcat paths
    ``illustration``, ``proximity`` and ``contact_forces`` (under ``/drake``), each below ``<prefix>/`` when
    ``prefix`` is given.
    """
    if config.publish_illustration:
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
            role=Role.kIllustration, publish_period=config.publish_period, prefix=MeshcatPath(prefix, "illustration"),
            delete_on_initialization_event=config.delete_on_initialization_event))
    if config.publish_proximity:
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
            role=Role.kProximity, publish_period=config.publish_period, prefix=MeshcatPath(prefix, "proximity"),
            default_color=config.default_proximity_color, initial_alpha=config.initial_proximity_alpha,
            visible_by_default=False, delete_on_initialization_event=config.delete_on_initialization_event))
    if config.publish_contacts:
        ContactVisualizer.AddToBuilder(builder, plant, meshcat, ContactVisualizerParams(
            publish_period=config.publish_period, prefix=MeshcatPath(prefix, ContactVisualizerParams().prefix),
            delete_on_initialization_event=config.delete_on_initialization_event))


def MakeStation(scenario: Scenario, meshcat=None, name: str | None = None) -> Diagram:
    """Builds the station Diagram for ``scenario`` (see the module docstring for its ports).

    Args:
        scenario: a loaded :class:`~seqdex_drake.scenario.Scenario`.
        meshcat: an optional ``pydrake.geometry.Meshcat``; when given, the scene is visualized.
        name: the Diagram's name and the prefix of its Meshcat paths (``<name>/illustration``, ...); give each
            station of one diagram its own. None: ``station_<task_family>_<subtask>``, unprefixed paths.

    Raises:
        ValueError: ``name`` is empty or contains ``::`` or ``/``.
        ScenarioError: the scenario's models cannot be loaded or lack the robot.
    """
    prefix = None if name is None else CheckSystemName(name)
    diagram_name = prefix or f"station_{scenario.task_family}_{scenario.subtask}".rstrip("_")
    builder = DiagramBuilder()
    plant, scene_graph = AddStationPlant(builder, scenario)

    for robot in ROBOT_INSTANCES:
        instance = plant.GetModelInstanceByName(robot)
        builder.ExportInput(plant.get_desired_state_input_port(instance), f"{robot}.desired_state")
        builder.ExportOutput(plant.get_state_output_port(instance), f"{robot}.state")
        builder.ExportOutput(plant.get_net_actuation_output_port(instance), f"{robot}.net_actuation")
    for loose in scenario.objects:
        builder.ExportOutput(plant.get_state_output_port(plant.GetModelInstanceByName(loose)), f"{loose}.state")

    if scenario.robot.arm_gravity_compensation:
        AddArmGravityCompensation(builder, plant)


    AddObjectFreezer(builder, plant, scene_graph, scenario)

    if scenario.cameras and scenario.low_poly_perception:
        UseLowPolyPerceptionGeometry(plant, scene_graph)
    for camera_name, camera in scenario.cameras.items():
        AddCamera(builder, plant, scene_graph, camera_name, camera)

    builder.ExportOutput(plant.get_body_poses_output_port(), "body_poses")
    builder.ExportOutput(plant.get_body_spatial_velocities_output_port(), "body_spatial_velocities")
    builder.ExportOutput(plant.get_contact_results_output_port(), "contact_results")
    builder.ExportOutput(plant.get_state_output_port(), "plant_state")
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")

    if meshcat is not None:
        AddMeshcatVisualization(builder, plant, scene_graph, meshcat, scenario.visualization, prefix=prefix)

    diagram = builder.Build()
    diagram.set_name(diagram_name)
    return diagram


def RefreshSampledOutputs(plant: MultibodyPlant, plant_context, scratch=None):
    """Brings a plant's sampled outputs up to date with its current state (a no-op without sampled outputs).

    With ``MultibodyPlantConfig.use_sampled_output_ports`` (the scenarios' setting) the outputs that need a
    contact solve (net actuation -- the motor-tactile signal --, contact results, reaction forces) hold what the
    plant computed during its last step, so reading them costs nothing. After the state is edited without a step
    (a reset, a restored state) they would describe the old state. This recomputes them as the next step would,
    from the current state and inputs (one discrete contact solve), and leaves positions and velocities alone.

    Args:
        plant, plant_context: the plant and its context (inside a diagram context, so the inputs are connected).
        scratch: a context from ``plant.CreateDefaultContext()`` to compute into (allocated when None; pass the
            returned one back to save the allocation on later calls).

    Returns:
        The scratch context (None when there is nothing to refresh).
    """
    count = plant_context.num_abstract_states()
    if count == 0:
        return None
    scratch = plant.CreateDefaultContext() if scratch is None else scratch
    state = scratch.get_mutable_state()
    plant.CalcForcedUnrestrictedUpdate(plant_context, state)
    for index in range(count):
        plant_context.get_mutable_abstract_state(index).SetFrom(state.get_abstract_state().get_value(index))
    return scratch
