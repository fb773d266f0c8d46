"""Generated scene assets: they parse in Drake, have the published sizes and masses, regenerate identically,
and behave: blocks seat on plates and blocks by free fall, and rest on the table.

Runs in about half a minute on two cores.
"""

import filecmp
from pathlib import Path

import numpy as np
import pytest
import trimesh
from pydrake.geometry import Box
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import LoadModelDirectives, Parser, ProcessModelDirectives
from pydrake.multibody.plant import AddMultibodyPlant, AddMultibodyPlantSceneGraph, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake.modeling import blocks, fixtures, tools

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
BLOCK_TYPES = sorted(blocks.BLOCK_SPECS)
BLOCK_URLS = [(blocks.block_sdf_url(t, r), "block") for t in BLOCK_TYPES for r in blocks.RESOLUTIONS]
FIXTURE_LINKS = {"table": "table", "box": "box", "baseplate": "baseplate", "plate_1": "plate", "plate_2": "plate",
                 "plate_3": "plate"}
FIXTURE_URLS = [(fixtures.fixture_sdf_url(name), link) for name, link in FIXTURE_LINKS.items()]
TOOL_URLS = [(tools.tool_sdf_url(name), "tool") for name in sorted(tools.TOOL_SPECS)]
SEATED_Z = blocks.BODY_HEIGHT  # Height of a block's frame when it sits on a one-layer plate or on a block.



def load_mesh(path) -> trimesh.Trimesh:
    """Loads a generated OBJ with its own vertex indexing (trimesh's loader splits vertices per face normal)."""
    vertices, faces = [], []
    for line in open(path):
        if line.startswith("v "):
            vertices.append([float(c) for c in line.split()[1:4]])
        elif line.startswith("f "):
            faces.append([int(corner.split("/")[0]) - 1 for corner in line.split()[1:4]])
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)

def _parser(plant) -> Parser:
    """A Parser resolving package://seqdex_models to this repository's models/."""
    parser = Parser(plant)
    parser.package_map().Add("seqdex_models", str(MODELS_DIR))
    return parser


def _load(url: str):
    """A finalized plant (kept alive with its diagram) holding the model at `url`."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    (instance,) = _parser(plant).AddModels(url=url)
    plant.Finalize()
    return builder.Build(), plant, scene_graph, instance


def _block_dir(block_type: int) -> Path:
    """models/blocks/block_N."""
    return MODELS_DIR / "blocks" / f"block_{block_type}"


@pytest.mark.parametrize("url, link", BLOCK_URLS + FIXTURE_URLS + TOOL_URLS)
def test_every_sdf_parses_with_collisions_and_mass(url, link):
    diagram, plant, _, instance = _load(url)
    body = plant.GetBodyByName(link, instance)
    assert body.default_mass() > 0.0
    assert len(plant.GetCollisionGeometriesForBody(body)) > 0
    assert len(plant.GetVisualGeometriesForBody(body)) > 0


@pytest.mark.parametrize("resolution", blocks.RESOLUTIONS)
def test_pile_directives_add_72_blocks(resolution):
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, 0.002)
    path = MODELS_DIR / f"building_blocks_pile_{resolution}.dmd.yaml"
    infos = ProcessModelDirectives(LoadModelDirectives(str(path)), plant, _parser(plant))
    plant.Finalize()
    expected = {f"block_{t}_{k}" for t in BLOCK_TYPES for k in range(9)}
    assert {info.model_name for info in infos} == expected
    assert len(infos) == 72


@pytest.mark.parametrize("block_type", BLOCK_TYPES)
def test_block_mass_properties_come_from_the_visual_mesh(block_type):
    mesh = load_mesh(_block_dir(block_type) / "visual.obj")
    assert mesh.is_watertight
    diagram, plant, _, instance = _load(blocks.block_sdf_url(block_type, "fine"))
    body = plant.GetBodyByName("block", instance)
    mass = body.default_mass()
    assert mass == pytest.approx(blocks.DENSITY * mesh.volume, rel=1e-6)
    assert 0.010 <= mass <= 0.060
    np.testing.assert_allclose(body.default_com(), mesh.center_mass, atol=1e-8)
    inertia = body.default_spatial_inertia().Shift(body.default_com()).CalcRotationalInertia()
    np.testing.assert_allclose(inertia.CopyToFullMatrix3(), blocks.DENSITY * mesh.moment_inertia, atol=1e-10)


@pytest.mark.parametrize("block_type", BLOCK_TYPES)
def test_block_bounds_match_footprint_and_height(block_type):
    spec = blocks.BLOCK_SPECS[block_type]
    length, width = spec.footprint
    expected = np.array([[-length / 2, -width / 2, 0.0], [length / 2, width / 2, 0.0575]])
    mesh = load_mesh(_block_dir(block_type) / "visual.obj")
    np.testing.assert_allclose(mesh.bounds, expected, atol=1e-3)
    for resolution in blocks.RESOLUTIONS:
        pieces = [load_mesh(p) for p in sorted((_block_dir(block_type) / resolution).glob("*.obj"))]
        bounds = np.vstack([p.bounds for p in pieces])
        np.testing.assert_allclose([bounds.min(axis=0), bounds.max(axis=0)], expected, atol=1e-3)
        # Convex up to the 1 um rounding of the written vertices (Drake uses the hull of each piece).
        assert all(piece.convex_hull.volume - piece.volume < 1e-5 * piece.volume for piece in pieces)
        # The cavity stays open: slimmed studs under every cell fit with 0.5 mm of head room.
        assert blocks.socket_clearance_volume(block_type, pieces) < 1e-12
    assert len(spec.stud_centers) == spec.num_studs


def test_every_visual_mesh_is_watertight():
    paths = sorted(MODELS_DIR.glob("blocks/*/visual.obj")) + sorted(MODELS_DIR.glob("tools/*/visual_*.obj"))
    paths += sorted(MODELS_DIR.glob("fixtures/meshes/*_visual.obj"))
    assert len(paths) == 8 + 5 + 4
    for path in paths:
        assert load_mesh(path).is_watertight, path


def test_regenerating_block_7_is_byte_identical(tmp_path):
    blocks.generate_block(7, str(tmp_path))
    new, old = tmp_path / "blocks" / "block_7", _block_dir(7)
    new_files = sorted(str(p.relative_to(new)) for p in new.rglob("*") if p.is_file())
    old_files = sorted(str(p.relative_to(old)) for p in old.rglob("*") if p.is_file())
    assert new_files == old_files
    for relative in new_files:
        assert filecmp.cmp(new / relative, old / relative, shallow=False), relative


def test_urls_and_errors():
    assert blocks.block_sdf_url(3, "fine") == "package://seqdex_models/blocks/block_3/block_3_fine.sdf"
    assert tools.tool_sdf_url("spoon") == "package://seqdex_models/tools/spoon/spoon.sdf"
    with pytest.raises(ValueError, match=r"valid types are \[1, 2, 3, 4, 5, 6, 7, 8\]"):
        blocks.block_sdf_url(9, "fine")
    with pytest.raises(ValueError, match="valid resolutions are \\['coarse', 'fine'\\]"):
        blocks.block_sdf_url(1, "medium")
    with pytest.raises(ValueError, match="valid tools are"):
        tools.tool_sdf_url("wrench")
    with pytest.raises(ValueError, match="valid fixtures are"):
        fixtures.fixture_sdf_url("shelf")


@pytest.mark.parametrize("name", sorted(tools.TOOL_SPECS))
def test_tool_size_origin_and_mass(name):
    meshes = [load_mesh(p) for p in sorted((MODELS_DIR / "tools" / name).glob("visual_*.obj"))]
    bounds = np.vstack([m.bounds for m in meshes])
    low, high = bounds.min(axis=0), bounds.max(axis=0)
    np.testing.assert_allclose(high - low, tools.TOOL_SPECS[name].bounding_box, atol=1e-3)
    np.testing.assert_allclose((high + low) / 2, 0.0, atol=1e-6)  # Origin at the bounding-box centre.
    diagram, plant, _, instance = _load(tools.tool_sdf_url(name))
    body = plant.GetBodyByName("tool", instance)
    if name == "hammer":
        assert 0.4 <= body.default_mass() <= 0.6
        assert body.default_com()[1] > 0.1  # The steel head at +y dominates.
    else:
        assert 0.05 <= body.default_mass() < 0.4


def _collision_boxes(url: str):
    """{name: (size, translation)} of the box collision geometries of a fixture."""
    diagram, plant, scene_graph, instance = _load(url)
    inspector = scene_graph.model_inspector()
    boxes = {}
    for geometry in inspector.GetAllGeometryIds():
        shape = inspector.GetShape(geometry)
        if isinstance(shape, Box) and inspector.GetProximityProperties(geometry) is not None:
            boxes[inspector.GetName(geometry).split("::")[-1]] = (
                np.array([shape.width(), shape.depth(), shape.height()]),
                inspector.GetPoseInFrame(geometry).translation())
    return boxes


def test_fixture_frames():
    top_size, top_center = _collision_boxes(fixtures.fixture_sdf_url("table"))["top"]
    np.testing.assert_allclose(top_size, [1.5, 1.0, 0.05])
    assert top_center[2] + top_size[2] / 2 == pytest.approx(0.0)  # Table top at z = 0.
    box = _collision_boxes(fixtures.fixture_sdf_url("box"))
    assert "floor" not in box  # The table top is the box's floor (a coplanar floor would double contacts).
    assert box["wall_pos_x"][1][2] - box["wall_pos_x"][0][2] / 2 == pytest.approx(-0.01)  # Walls reach the table.
    wall_size, wall_center = box["wall_pos_x"]
    assert wall_center[0] - wall_size[0] / 2 == pytest.approx(0.30)  # Inner footprint 0.60 x 0.416.
    assert wall_center[2] + wall_size[2] / 2 == pytest.approx(0.165)
    assert box["wall_pos_y"][1][1] - box["wall_pos_y"][0][1] / 2 == pytest.approx(0.208)
    for name, side, thickness in [("baseplate", 0.36, 0.018)] + [
            (f"plate_{n}", 0.12, n * blocks.BODY_HEIGHT) for n in fixtures.PLATE_LAYERS]:
        slab_size, slab_center = _collision_boxes(fixtures.fixture_sdf_url(name))["slab"]
        np.testing.assert_allclose(slab_size, [side, side, thickness])
        np.testing.assert_allclose(slab_center, [0.0, 0.0, thickness / 2])


def _drop(fixed_url, fixed_link, moving_url, X_WB_start, duration=1.0, approximation="lagged", contact="point"):
    """Welds `fixed_url` at the world origin, releases a block at `X_WB_start`, simulates; returns pose, plant."""
    builder = DiagramBuilder()
    config = MultibodyPlantConfig(time_step=0.002, discrete_contact_approximation=approximation,
                                  contact_model=contact)
    plant, scene_graph = AddMultibodyPlant(config, builder)
    parser = _parser(plant)
    (fixed,) = parser.AddModels(url=fixed_url)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(fixed_link, fixed))
    (moving,) = parser.AddModels(url=moving_url)
    plant.Finalize()
    diagram = builder.Build()
    simulator = Simulator(diagram)
    plant_context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    body = plant.GetBodyByName("block", moving)
    plant.SetFreeBodyPose(plant_context, body, X_WB_start)
    simulator.AdvanceTo(duration)
    return plant.EvalBodyPoseInWorld(plant_context, body), (diagram, simulator, plant, scene_graph, body)


def _assert_seated(X_WB, X_WB_seated, tolerance=0.002, angle=0.05):
    """The block rests within `tolerance` (m) and `angle` (rad) of the seated pose."""
    error = np.linalg.norm(X_WB.translation() - X_WB_seated.translation())
    rotation = RotationMatrix(X_WB_seated.rotation().matrix().T @ X_WB.rotation().matrix())
    assert error < tolerance, f"rests {error * 1000:.2f} mm from the seated pose"
    assert rotation.ToAngleAxis().angle() < angle


def _seated_on_plate(block_type: int, yaw: float = 0.0) -> RigidTransform:
    """A stud-aligned seated pose on plate_1 (4x4 studs at +-0.015, +-0.045)."""
    offsets = {1: (0.0, 0.015), 2: (0.0, 0.015), 3: (0.0, 0.015), 4: (0.015, 0.015), 5: (0.0, 0.015),
               6: (0.015, 0.015), 7: (0.015, 0.015), 8: (0.0, 0.0)}
    x, y = offsets[block_type]
    if yaw:
        x, y = y, x
    return RigidTransform(RotationMatrix.MakeZRotation(yaw), [x, y, SEATED_Z])


def _above(X: RigidTransform, dx=0.0, dy=0.0, dz=0.02) -> RigidTransform:
    """`X` moved by (dx, dy, dz): the release pose."""
    return RigidTransform(X.rotation(), X.translation() + [dx, dy, dz])


@pytest.mark.parametrize("block_type", BLOCK_TYPES)
def test_block_seats_on_plate_by_free_fall(block_type):
    seated = _seated_on_plate(block_type)
    X_WB, _ = _drop(fixtures.fixture_sdf_url("plate_1"), "plate", blocks.block_sdf_url(block_type, "fine"),
                    _above(seated))
    _assert_seated(X_WB, seated)


def test_block_rotated_90_degrees_seats_on_plate():
    seated = _seated_on_plate(1, yaw=np.pi / 2)
    X_WB, _ = _drop(fixtures.fixture_sdf_url("plate_1"), "plate", blocks.block_sdf_url(1, "fine"), _above(seated))
    _assert_seated(X_WB, seated)


def test_block_seats_on_a_welded_block():
    seated = RigidTransform([0.015, 0.0, SEATED_Z])  # On studs x = 0 and 0.03 of a 1x3 (block 4).
    X_WB, _ = _drop(blocks.block_sdf_url(4, "fine"), "block", blocks.block_sdf_url(1, "fine"), _above(seated))
    _assert_seated(X_WB, seated)


@pytest.mark.parametrize("approximation, contact", [("similar", "point"), ("lagged", "hydroelastic_with_fallback")])
@pytest.mark.parametrize("dx, dy", [(0.002, 0.0), (0.0, 0.002)])
def test_misaligned_block_seats_with_robust_settings(approximation, contact, dx, dy):
    """2 mm off the stud grid: the ribs' lead-in centres the block (point contact with "lagged" does not)."""
    seated = _seated_on_plate(1)
    X_WB, _ = _drop(fixtures.fixture_sdf_url("plate_1"), "plate", blocks.block_sdf_url(1, "fine"),
                    _above(seated, dx, dy), approximation=approximation, contact=contact)
    _assert_seated(X_WB, seated)


def test_coarse_block_rests_on_table_without_sinking_or_drifting():
    start = RigidTransform([0.1, 0.05, 0.001])
    X_mid, (diagram, simulator, plant, scene_graph, body) = _drop(
        fixtures.fixture_sdf_url("table"), "table", blocks.block_sdf_url(5, "coarse"), start, duration=0.5)
    simulator.AdvanceTo(1.5)
    plant_context = plant.GetMyContextFromRoot(simulator.get_context())
    X_end = plant.EvalBodyPoseInWorld(plant_context, body)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(simulator.get_context()))
    depths = [pair.depth for pair in query.ComputePointPairPenetration()]
    assert depths and max(depths) < 0.002
    assert abs(X_end.translation()[2]) < 0.001  # Rim on the table top (z = 0).
    assert np.linalg.norm(X_end.translation() - X_mid.translation()) < 0.0005
    _assert_seated(X_end, RigidTransform([0.1, 0.05, 0.0]), tolerance=0.001, angle=0.01)
