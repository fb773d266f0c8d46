"""Tests of the generated Franka Panda and Allegro right-hand models against the published facts, with Drake."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex, RevoluteJoint
from pydrake.systems.framework import Context, Diagram, DiagramBuilder

from seqdex_drake.modeling.franka_model import flange_position_at_zero
from seqdex_drake.modeling.robot_models import ROBOT_MODEL_FILES, write_robot_models
from seqdex_drake.robots import allegro, franka

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"

# The published numbers (FACTS.md), written out independently of the modules under test.
FACTS_FRANKA_Q_MIN = [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
FACTS_FRANKA_Q_MAX = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]
FACTS_FRANKA_V_MAX = [2.175] * 4 + [2.61] * 3
FACTS_FRANKA_EFFORT = [87.0] * 4 + [12.0] * 3
FACTS_ALLEGRO_Q_MIN = [-0.47, -0.196, -0.174, -0.227] * 3 + [0.263, -0.105, -0.189, -0.162]
FACTS_ALLEGRO_Q_MAX = [0.47, 1.61, 1.709, 1.618] * 3 + [1.396, 1.163, 1.644, 1.719]

PALM_FRONT_X = 0.0408 / 2
PALM_TOP_Z = 0.095

# Every finger flexed to 75% of its upper limits and the thumb curled beside the palm: as far as the fingers
# close before their tips reach the palm face (beyond about 78% of the range the fingertips meet the palm).
CURLED_Q = 0.75 * allegro.ALLEGRO_Q_MAX
CURLED_Q[[0, 4, 8]] = 0.0
CURLED_Q[12] = allegro.ALLEGRO_Q_MIN[12]


@dataclasses.dataclass
class LoadedModel:
    plant: MultibodyPlant
    scene_graph: SceneGraph
    diagram: Diagram
    context: Context
    model: ModelInstanceIndex

    @property
    def plant_context(self) -> Context:
        return self.plant.GetMyContextFromRoot(self.context)

    def set_positions(self, q) -> None:
        self.plant.SetPositions(self.plant_context, self.model, q)

    def frame_pose(self, name: str):
        return self.plant.GetFrameByName(name, self.model).CalcPoseInWorld(self.plant_context)

    def penetrations(self) -> list[tuple[str, str, float]]:
        query = self.scene_graph.get_query_output_port().Eval(self.scene_graph.GetMyContextFromRoot(self.context))
        inspector = query.inspector()
        return [
            (inspector.GetName(pair.id_A), inspector.GetName(pair.id_B), pair.depth)
            for pair in query.ComputePointPairPenetration()
        ]


def load_welded(url: str, weld_frame: str) -> LoadedModel:
    """Parses one model by package URL with `weld_frame` welded to the world."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    parser = Parser(plant)
    parser.package_map().Add("seqdex_models", str(MODELS_DIR))
    (model,) = parser.AddModels(url=url)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(weld_frame, model))
    plant.Finalize()
    diagram = builder.Build()
    return LoadedModel(plant, scene_graph, diagram, diagram.CreateDefaultContext(), model)


@pytest.fixture(scope="module")
def panda() -> LoadedModel:
    return load_welded(franka.FRANKA_MODEL_URL, franka.BASE_FRAME)


@pytest.fixture(scope="module")
def hand() -> LoadedModel:
    return load_welded(allegro.ALLEGRO_MODEL_URL, allegro.HAND_ROOT_FRAME)


def check_joints_and_actuators(loaded: LoadedModel, names, q_min, q_max, v_max, effort_max) -> None:
    plant = loaded.plant
    assert plant.num_positions(loaded.model) == len(names)
    assert plant.num_actuators(loaded.model) == len(names)
    joint_names = [plant.get_joint(i).name() for i in plant.GetJointIndices(loaded.model)]
    assert [n for n in joint_names if plant.GetJointByName(n, loaded.model).num_positions() == 1] == list(names)
    for i, name in enumerate(names):
        joint = plant.GetJointByName(name, loaded.model)
        assert isinstance(joint, RevoluteJoint)
        assert joint.position_lower_limits()[0] == pytest.approx(q_min[i])
        assert joint.position_upper_limits()[0] == pytest.approx(q_max[i])
        assert joint.velocity_upper_limits()[0] == pytest.approx(v_max[i])
        actuator = plant.GetJointActuatorByName(name, loaded.model)
        assert actuator.joint().name() == name
        assert actuator.effort_limit() == pytest.approx(effort_max[i])
    # Actuator order follows the canonical joint order, so actuation vectors need no permutation.
    actuators = [plant.get_joint_actuator(i).name() for i in plant.GetJointActuatorIndices(loaded.model)]
    assert actuators == list(names)


def check_inertias_valid(loaded: LoadedModel) -> float:
    """Returns the model's mass after checking every massive body's inertia (positive principal moments that
    satisfy the triangle inequality, about the centre of mass)."""
    plant = loaded.plant
    total = 0.0
    for index in plant.GetBodyIndices(loaded.model):
        body = plant.get_body(index)
        if body.default_mass() == 0.0:
            continue
        M_BBo_B = body.CalcSpatialInertiaInBodyFrame(loaded.plant_context)
        assert M_BBo_B.IsPhysicallyValid(), body.name()
        I_BBcm_B = M_BBo_B.Shift(M_BBo_B.get_com()).CalcRotationalInertia()
        moments = np.sort(np.linalg.eigvalsh(I_BBcm_B.CopyToFullMatrix3()))
        assert moments[0] > 0.0, body.name()
        assert moments[0] + moments[1] >= moments[2], body.name()
        total += body.default_mass()
    return total


# --- Franka ---------------------------------------------------------------------------------------------


def test_franka_constants_match_published_facts():
    assert franka.FRANKA_JOINT_NAMES == tuple(f"panda_joint{i}" for i in range(1, 8))
    np.testing.assert_array_equal(franka.FRANKA_Q_MIN, FACTS_FRANKA_Q_MIN)
    np.testing.assert_array_equal(franka.FRANKA_Q_MAX, FACTS_FRANKA_Q_MAX)
    np.testing.assert_array_equal(franka.FRANKA_V_MAX, FACTS_FRANKA_V_MAX)
    np.testing.assert_array_equal(franka.FRANKA_EFFORT_MAX, FACTS_FRANKA_EFFORT)
    np.testing.assert_array_equal(franka.FRANKA_HOME_Q, [0, -0.785, 0, -2.356, 0, 1.571, 0.785])
    assert np.all(franka.FRANKA_HOME_Q >= franka.FRANKA_Q_MIN)
    assert np.all(franka.FRANKA_HOME_Q <= franka.FRANKA_Q_MAX)
    view = franka.FrankaPositions(franka.FRANKA_HOME_Q)
    assert view.panda_joint4 == pytest.approx(-2.356)


def test_franka_joints_and_actuators(panda):
    check_joints_and_actuators(
        panda,
        franka.FRANKA_JOINT_NAMES,
        franka.FRANKA_Q_MIN,
        franka.FRANKA_Q_MAX,
        franka.FRANKA_V_MAX,
        franka.FRANKA_EFFORT_MAX,
    )


def test_franka_flange_at_zero(panda):
    panda.set_positions(np.zeros(7))
    X_WF = panda.frame_pose(franka.FLANGE_FRAME)
    np.testing.assert_allclose(X_WF.translation(), [0.088, 0.0, 0.926], atol=1e-6)
    np.testing.assert_allclose(X_WF.rotation().matrix()[:, 2], [0.0, 0.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(flange_position_at_zero(), [0.088, 0.0, 0.926], atol=1e-12)


def test_franka_flange_points_down_at_home(panda):
    panda.set_positions(franka.FRANKA_HOME_Q)
    z_axis = panda.frame_pose(franka.FLANGE_FRAME).rotation().matrix()[:, 2]
    angle = np.arccos(np.clip(z_axis @ np.array([0.0, 0.0, -1.0]), -1.0, 1.0))
    assert angle < 0.05
    assert panda.penetrations() == []


def test_franka_mass_properties(panda):
    mass = check_inertias_valid(panda)
    assert 16.0 < mass < 20.0  # datasheet: about 18 kg
    link1 = panda.plant.GetBodyByName("panda_link1", panda.model)
    assert link1.default_mass() == pytest.approx(4.970684)
    assert panda.plant.GetBodyByName(franka.FLANGE_FRAME, panda.model).default_mass() == 0.0


# --- Allegro --------------------------------------------------------------------------------------------


def test_allegro_constants_match_published_facts():
    assert allegro.ALLEGRO_JOINT_NAMES == tuple(f"joint_{i}" for i in range(16))
    np.testing.assert_array_equal(allegro.ALLEGRO_Q_MIN, FACTS_ALLEGRO_Q_MIN)
    np.testing.assert_array_equal(allegro.ALLEGRO_Q_MAX, FACTS_ALLEGRO_Q_MAX)
    np.testing.assert_array_equal(allegro.ALLEGRO_EFFORT_MAX, [0.7] * 16)
    np.testing.assert_array_equal(allegro.ALLEGRO_V_MAX, [10.0] * 16)
    for q in (allegro.ALLEGRO_OPEN_Q, allegro.ALLEGRO_PINCH_Q, CURLED_Q):
        assert np.all(q >= allegro.ALLEGRO_Q_MIN) and np.all(q <= allegro.ALLEGRO_Q_MAX)
    view = allegro.AllegroPositions(np.arange(16.0))
    assert view.index_joint_0 == 0 and view.middle_joint_1 == 5 and view.thumb_joint_0 == 12
    assert view.thumb_joint_3 == 15


def test_allegro_joints_and_actuators(hand):
    check_joints_and_actuators(
        hand,
        allegro.ALLEGRO_JOINT_NAMES,
        allegro.ALLEGRO_Q_MIN,
        allegro.ALLEGRO_Q_MAX,
        allegro.ALLEGRO_V_MAX,
        allegro.ALLEGRO_EFFORT_MAX,
    )


def test_allegro_frame_convention(hand):
    hand.set_positions(allegro.ALLEGRO_OPEN_Q)
    assert hand.frame_pose(allegro.PALM_BODY).IsExactlyIdentity()
    tips = np.array([hand.frame_pose(name).translation() for name in allegro.FINGERTIP_FRAMES])
    index, middle, ring, thumb = tips
    assert index[1] > middle[1] > ring[1]  # +y from ring toward index
    assert thumb[1] > middle[1]  # thumb on the +y side
    assert np.all(tips[:, 2] > PALM_TOP_Z)  # fingers extend along +z
    # Flexion curls the fingers toward +x (out of the palm face).
    hand.set_positions(CURLED_Q)
    curled = np.array([hand.frame_pose(name).translation() for name in allegro.FINGERTIP_FRAMES])
    assert np.all(curled[:3, 0] > PALM_FRONT_X + allegro.FINGERTIP_RADIUS)


def test_allegro_open_pinch_and_curled(hand):
    hand.set_positions(allegro.ALLEGRO_OPEN_Q)
    for name in allegro.FINGERTIP_FRAMES:
        assert hand.frame_pose(name).translation()[2] > PALM_TOP_Z, name
    assert hand.penetrations() == []

    hand.set_positions(allegro.ALLEGRO_PINCH_Q)
    p_index = hand.frame_pose("index_tip").translation()
    p_thumb = hand.frame_pose("thumb_tip").translation()
    assert np.linalg.norm(p_index - p_thumb) < 0.025
    assert p_index[0] > PALM_FRONT_X + 0.03 and p_thumb[0] > PALM_FRONT_X + 0.03
    assert hand.penetrations() == []

    hand.set_positions(CURLED_Q)
    assert hand.penetrations() == []


def test_allegro_mass_and_inertias(hand):
    mass = check_inertias_valid(hand)
    assert 0.9 < mass < 1.3
    for name in allegro.FINGERTIP_FRAMES + (allegro.HAND_ROOT_FRAME,):
        assert hand.plant.GetBodyByName(name, hand.model).default_mass() == 0.0


def test_action_scaling():
    q_min, q_max = allegro.ALLEGRO_Q_MIN, allegro.ALLEGRO_Q_MAX
    np.testing.assert_allclose(allegro.scale_action_to_limits(-np.ones(16)), q_min)
    np.testing.assert_allclose(allegro.scale_action_to_limits(np.ones(16)), q_max)
    np.testing.assert_allclose(allegro.scale_action_to_limits(np.zeros(16)), (q_min + q_max) / 2)
    np.testing.assert_allclose(allegro.scale_action_to_limits(3 * np.ones(16)), q_max)  # clipped
    actions = np.random.default_rng(0).uniform(-1, 1, size=(5, 16))
    targets = allegro.scale_action_to_limits(actions)
    assert targets.shape == (5, 16)
    np.testing.assert_allclose(allegro.unscale_limits_to_action(targets), actions, atol=1e-12)


# --- Generation -----------------------------------------------------------------------------------------


def test_generator_reproduces_committed_files(tmp_path):
    write_robot_models(tmp_path)
    for relative in ROBOT_MODEL_FILES:
        assert (tmp_path / relative).read_bytes() == (MODELS_DIR / relative).read_bytes(), relative
