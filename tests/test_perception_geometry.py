"""Low-poly perception stand-ins: the label camera sees nearly the same image, and nothing else changes."""

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Mesh, ReadObjToTriangleSurfaceMesh, Role, Sphere

from seqdex_drake import LoadScenario, MakeStation
from seqdex_drake.harness import ResolvePackageUrl
from seqdex_drake.scenario import MODELS_DIR
from seqdex_drake.scene.perception_geometry import STAND_IN_FILE, low_poly_shape
from seqdex_drake.scene.piles import LoadPiles


def _vertices(mesh: Mesh) -> np.ndarray:
    source = mesh.source()
    if source.is_path():
        return np.array(ReadObjToTriangleSurfaceMesh(str(source.path())).vertices())
    text = bytes(source.in_memory().mesh_file.contents()).decode()
    return np.array([[float(x) for x in line.split()[1:4]] for line in text.splitlines() if line.startswith("v ")])


@pytest.mark.parametrize("shape", [Sphere(0.012), Capsule(0.01, 0.05), Cylinder(0.02, 0.04),
                                   Ellipsoid(0.01, 0.02, 0.03)])
def test_primitive_stand_ins_are_low_poly_and_on_the_surface(shape):
    stand_in = low_poly_shape(shape)
    assert isinstance(stand_in, Mesh)
    text = bytes(stand_in.source().in_memory().mesh_file.contents()).decode()
    assert 20 <= text.count("\nf ") <= 200
    v = _vertices(stand_in)
    if isinstance(shape, Sphere):
        np.testing.assert_allclose(np.linalg.norm(v, axis=1), shape.radius(), rtol=1e-4)
    elif isinstance(shape, Ellipsoid):
        np.testing.assert_allclose(np.linalg.norm(v / [shape.a(), shape.b(), shape.c()], axis=1), 1.0, rtol=1e-3)
    else:  # Centred on the frame, along z, with the shape's length and radius.
        r, half = shape.radius(), shape.length() / 2 + (shape.radius() if isinstance(shape, Capsule) else 0.0)
        np.testing.assert_allclose([v[:, 2].min(), v[:, 2].max()], [-half, half], atol=1e-6)
        assert np.max(np.linalg.norm(v[:, :2], axis=1)) == pytest.approx(r, rel=1e-4)


def test_meshes_use_their_perception_obj_and_keep_their_scale():
    visual = MODELS_DIR / "blocks" / "block_3" / "visual.obj"
    stand_in = low_poly_shape(Mesh(str(visual), 1.5))
    assert str(stand_in.source().path()).endswith(f"block_3/{STAND_IN_FILE}")
    np.testing.assert_array_equal(stand_in.scale3(), [1.5, 1.5, 1.5])
    full, low = _vertices(Mesh(str(visual))), _vertices(stand_in)
    np.testing.assert_allclose(low.min(axis=0), full.min(axis=0), atol=1e-3)  # Same bounding box.
    np.testing.assert_allclose(low.max(axis=0), full.max(axis=0), atol=1e-3)
    assert low_poly_shape(Box(0.1, 0.1, 0.1)) is None
    assert low_poly_shape(Mesh(str(MODELS_DIR / "tools" / "hammer" / "visual_head.obj"))) is None


def _search_station(low_poly: bool):
    scenario = LoadScenario("building_blocks/search")
    scenario.low_poly_perception = low_poly
    station = MakeStation(scenario)
    context = station.CreateDefaultContext()
    plant = station.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(context)
    pile = LoadPiles(ResolvePackageUrl(scenario.pile_file), scenario.objects)[0]
    for name, q in zip(scenario.objects, pile, strict=True):
        plant.SetPositions(plant_context, plant.GetModelInstanceByName(name), q)
    return station, context, plant, scenario.objects


def test_search_label_image_is_nearly_unchanged_and_other_roles_are_kept():
    images, counts = [], []
    for low_poly in (False, True):
        station, context, plant, names = _search_station(low_poly)
        images.append(station.GetOutputPort("top_down.label_image").Eval(context).data[:, :, 0].copy())
        inspector = station.GetSubsystemByName("scene_graph").model_inspector()
        counts.append({role: len(inspector.GetAllGeometryIds(role))
                       for role in (Role.kIllustration, Role.kProximity, Role.kPerception)})
    full, low = images
    assert counts[0] == counts[1]  # Same numbers: each stand-in took one perception role over.
    labels = [int(plant.GetBodyByName("block", plant.GetModelInstanceByName(name)).index()) for name in names]
    # Where either image shows a block, the labels agree. (The box's floor and the table top are coplanar, so
    # which of the two the background shows depends on the draw order alone.)
    on_blocks = np.isin(full, labels) | np.isin(low, labels)
    assert np.mean(full[on_blocks] == low[on_blocks]) > 0.98
    visible = 0
    for name, label in zip(names, labels, strict=True):
        n_full, n_low = np.count_nonzero(full == label), np.count_nonzero(low == label)
        assert abs(n_low - n_full) <= max(3, 0.15 * n_full), (name, n_full, n_low)
        visible += n_full >= 20
    assert visible >= 10  # The comparison covered many visible blocks.
