"""TargetPixelCounter: the target's pixels from a render of its region equal those of the whole label image."""

import numpy as np
import pytest
from pydrake.geometry import HalfSpace
from pydrake.math import RigidTransform

from seqdex_drake.envs.randomization import _scaled_shape
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.sensors.target_pixels import TargetPixelCounter, _shape_points

CAMERA = "top_down"


@pytest.fixture(scope="module")
def search_env():
    return make_env("search")


def _setup(env):
    sensor = env.station.GetSubsystemByName(f"camera_{CAMERA}")
    scene_graph = env.objects.scene_graph
    return sensor, scene_graph, scene_graph.GetMyMutableContextFromRoot(env.context)


def _full_count(env, label: int) -> int:
    image = env.station.GetOutputPort(f"{CAMERA}.label_image").Eval(env.station.GetMyContextFromRoot(env.context))
    return int(np.count_nonzero(image.data == label))


def _counts(env, counter, body) -> tuple[int, int]:
    """(the counter's count, the whole image's count) of ``body`` in the env's current state."""
    _, scene_graph, sg_context = _setup(env)
    query_object = scene_graph.get_query_output_port().Eval(sg_context)
    X_WB = env.plant.EvalBodyPoseInWorld(env.plant_context, body).GetAsMatrix34().tolist()
    frame_id = env.plant.GetBodyFrameIdOrThrow(body.index())
    return counter.count(query_object, int(body.index()), frame_id, X_WB), _full_count(env, int(body.index()))


def test_the_region_render_counts_what_the_whole_image_shows(search_env):
    env = search_env
    sensor, _, _ = _setup(env)
    counter = TargetPixelCounter.from_sensor(sensor)
    rng = np.random.default_rng(0)
    seen = []
    for seed in range(2):
        env.reset(seed=seed)
        for _ in range(6):
            env.step(rng.uniform(-1, 1, env.action_space.shape))
            roi, full = _counts(env, counter, env.object_body())
            assert roi == full
            seen.append(full)
    windows = {(w, h) for (_, _, w, h) in counter._cameras}
    assert sum(count > 0 for count in seen) >= 6  # The targets were visible, at least partly, in most states.
    assert all(w * h < 128 * 128 for w, h in windows)  # Only regions were rendered.
    # The env's observation counts the same way.
    assert env.raw_observation()[159] == _full_count(env, env._observation_target.label)


def test_a_target_outside_the_image_has_no_pixels_and_costs_no_render(search_env):
    env = search_env
    env.reset(seed=0)
    counter = TargetPixelCounter.from_sensor(_setup(env)[0])
    body = env.object_body()
    env.objects.set_pose(env.context, env.target_object, RigidTransform([0.25, 3.0, 0.7]), frozen=True)
    assert _counts(env, counter, body) == (0, 0)
    assert not counter._cameras  # No render was needed.


def test_geometry_scaled_in_the_context_is_followed(search_env):
    env = search_env
    env.reset(seed=1)
    sensor, scene_graph, sg_context = _setup(env)
    counter = TargetPixelCounter.from_sensor(sensor)
    body = env.object_body()
    before = _counts(env, counter, body)
    assert before[0] == before[1] > 0
    inspector = scene_graph.model_inspector()
    for geometry in inspector.GetGeometries(env.plant.GetBodyFrameIdOrThrow(body.index())):
        scene_graph.ChangeShape(sg_context, env.plant.get_source_id(), geometry,
                                _scaled_shape(inspector.GetShape(geometry), 1.6), RigidTransform())
    after = _counts(env, counter, body)
    assert after[0] == after[1] > before[1]


def test_a_camera_on_a_body_frame_counts_the_same(search_env):
    env = search_env
    env.reset(seed=0)
    sensor, _, _ = _setup(env)
    world_counter = TargetPixelCounter.from_sensor(sensor)
    # The same camera, mounted on the table's frame instead of the world's: the counter asks for its pose.
    table = next(b for b in env.plant.GetBodiesWeldedTo(env.plant.world_body()) if b.index() != 0)
    X_WT = env.plant.EvalBodyPoseInWorld(env.plant_context, table)
    frame_counter = TargetPixelCounter(sensor.default_color_render_camera(),
                                       env.plant.GetBodyFrameIdOrThrow(table.index()),
                                       X_WT.inverse() @ sensor.default_X_PB())
    assert frame_counter._X_CW is None
    assert _counts(env, frame_counter, env.object_body()) == _counts(env, world_counter, env.object_body())


def test_a_shape_without_bounds_is_a_clear_error():
    with pytest.raises(ValueError, match="no bounds for a perception shape of type HalfSpace"):
        _shape_points(HalfSpace())
