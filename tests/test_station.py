"""The station Diagram: builds for every scenario, named ports, canonical joints, gravity compensation."""


import numpy as np
import pytest
from pydrake.multibody.tree import BodyIndex

from seqdex_drake import CANONICAL_JOINTS, LoadScenario, MakeControllerPlant, MakeStation, ScenarioNames
from seqdex_drake.harness import MakeStationHarness
from seqdex_drake.robots.allegro import ALLEGRO_JOINT_NAMES
from seqdex_drake.robots.franka import FRANKA_JOINT_NAMES
from seqdex_drake.scenario import ScenarioError

ROBOT_PORTS = ["franka.desired_state", "allegro.desired_state"]
ROBOT_OUTPUTS = ["franka.state", "allegro.state", "franka.net_actuation", "allegro.net_actuation", "body_poses",
                 "body_spatial_velocities", "contact_results", "plant_state", "query_object"]


@pytest.mark.parametrize("name", ScenarioNames())
def test_every_scenario_builds_with_named_ports(name):
    scenario = LoadScenario(name)
    station = MakeStation(scenario)
    inputs = {station.get_input_port(i).get_name() for i in range(station.num_input_ports())}
    outputs = {station.get_output_port(i).get_name() for i in range(station.num_output_ports())}
    assert set(ROBOT_PORTS) <= inputs
    assert set(ROBOT_OUTPUTS) <= outputs
    assert scenario.objects and all(f"{o}.state" in outputs for o in scenario.objects)
    for camera in scenario.cameras:
        assert f"{camera}.label_image" in outputs
    context = station.CreateDefaultContext()
    assert station.GetOutputPort("franka.state").Eval(context).shape == (14,)
    assert station.GetOutputPort("allegro.state").Eval(context).shape == (32,)
    assert station.GetOutputPort(f"{scenario.objects[0]}.state").Eval(context).shape == (13,)


def test_object_counts():
    assert len(MakeStationHarness(LoadScenario("search")).objects.names) == 72
    assert MakeStationHarness(LoadScenario("grasp")).objects.names == [f"block_{t}" for t in range(1, 9)]


def test_23_actuated_joints_in_canonical_order():
    scenario = LoadScenario("building_blocks/grasp")
    station = MakeStation(scenario)
    plant = station.GetSubsystemByName("plant")
    assert plant.num_actuators() == 23
    names = []
    for index in plant.GetJointActuatorIndices():
        actuator = plant.get_joint_actuator(index)
        names.append(f"{plant.GetModelInstanceName(actuator.model_instance())}::{actuator.joint().name()}")
    assert tuple(names) == CANONICAL_JOINTS
    assert CANONICAL_JOINTS[:7] == tuple(f"franka::{n}" for n in FRANKA_JOINT_NAMES)
    assert CANONICAL_JOINTS[7:] == tuple(f"allegro::{n}" for n in ALLEGRO_JOINT_NAMES)
    assert ALLEGRO_JOINT_NAMES[0] == "joint_0" and ALLEGRO_JOINT_NAMES[15] == "joint_15"


def test_controller_plant_is_the_arm_with_a_frozen_hand():
    plant = MakeControllerPlant(LoadScenario("grasp"))
    assert plant.num_positions() == 7 and plant.num_velocities() == 7 and plant.num_actuators() == 7
    full = MakeStation(LoadScenario("grasp")).GetSubsystemByName("plant")
    hand = full.GetModelInstanceByName("allegro")
    hand_mass = sum(full.get_body(i).default_mass() for i in full.GetBodyIndices(hand))
    # Body 0 is the world (NaN mass).
    arm_hand_mass = sum(plant.get_body(BodyIndex(i)).default_mass() for i in range(1, plant.num_bodies()))
    arm_mass = sum(full.get_body(i).default_mass() for i in full.GetBodyIndices(full.GetModelInstanceByName("franka")))
    assert arm_hand_mass == pytest.approx(arm_mass + hand_mass)


def test_gravity_compensated_arm_holds_home():
    harness = MakeStationHarness(LoadScenario("tool_positioning/tool_grasp"))
    home = np.array(harness.scenario.robot.arm_home)
    harness.step(60)
    q = harness.port("franka.state")[:7]
    assert np.max(np.abs(q - home)) < 2e-3


def test_missing_model_file_is_a_clear_error():
    scenario = LoadScenario("grasp", scenario_text=(
        "{directives: [{add_model: {name: franka, file: package://seqdex_models/franka/no_such.urdf}}]}"))
    with pytest.raises(ScenarioError, match="no_such.urdf"):
        MakeStation(scenario)


def test_unknown_object_pattern_is_a_clear_error():
    with pytest.raises(ScenarioError, match="block_9"):
        MakeStation(LoadScenario("grasp", scenario_text="{objects: [block_9]}"))
