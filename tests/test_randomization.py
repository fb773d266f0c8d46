"""Domain randomization (``envs/randomization.py``): the paper's ranges, parameters landing in the Drake
contexts (read back from the plant context and the SceneGraph context's inspector), determinism per seed,
disabled groups, resampling every N plant steps, and every registered task stepping with the paper's table."""

import dataclasses

import numpy as np
import pytest
from pydrake.common import RandomGenerator

from seqdex_drake.envs.randomization import RandomizationConfig
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.registry import default_config, task_names


def paper_env(name: str, **overrides):
    config = default_config(name)
    config.randomization = dataclasses.replace(RandomizationConfig.paper(), **overrides)
    return make_env(name, config)


@pytest.fixture(scope="module")
def env():
    return paper_env("orient")


def context_inspector(env):
    scene_graph = env.objects.scene_graph
    return scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(env.context)).inspector()


def friction(inspector, geometry) -> float:
    return inspector.GetProximityProperties(geometry).GetProperty("material", "coulomb_friction").static_friction()


def test_sampled_values_respect_the_paper_ranges(env):
    samples = [env.randomizer.sample_physical(RandomGenerator(seed)) for seed in range(400)]

    def stacked(field):
        return np.concatenate([getattr(s, field) for s in samples])

    for field, (lo, hi) in {"robot_mass": (0.5, 1.5), "object_mass": (0.5, 1.5), "robot_friction": (0.7, 1.3),
                            "object_friction": (0.5, 1.5), "object_scale": (0.95, 1.05),
                            "kp_scale": (0.99, 1.01), "damping_scale": (0.99, 1.01)}.items():
        values = stacked(field)
        assert lo <= values.min() and values.max() <= hi, field
        width = hi - lo  # The draws fill the range: both ends reached within 2% of its width.
        assert values.min() < lo + 0.02 * width and values.max() > hi - 0.02 * width, field
        if field in ("kp_scale", "damping_scale"):  # Log-uniform: the logs are uniform.
            values, lo, hi = np.log(values), np.log(lo), np.log(hi)
        assert np.median(values) == pytest.approx((lo + hi) / 2, abs=0.05 * (hi - lo)), field
    gravity = np.array([s.gravity_offset for s in samples])
    assert np.all(np.abs(gravity.mean(axis=0)) < 0.08) and np.allclose(gravity.std(axis=0), 0.4, rtol=0.15)
    assert np.std(stacked("lower_offset")) == pytest.approx(0.01, rel=0.1)
    assert np.std(stacked("upper_offset")) == pytest.approx(0.01, rel=0.1)


def test_noise_statistics(env):
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    randomizer = env.randomizer
    obs_means, act_means, obs_steps = [], [], []
    size = env.observation_space.shape[0]
    for _ in range(100):  # Episodes: fresh correlated noise, no physical resample (not due, not reseeded).
        randomizer.on_reset(rng, reseed=False, task_reset=False)
        obs = np.array([randomizer.perturb_observation(np.zeros(size, np.float32)) for _ in range(100)])
        act = np.array([randomizer.perturb_action(np.zeros(19)) for _ in range(100)])
        obs_means.append(obs.mean(axis=0))
        act_means.append(act.mean(axis=0))
        obs_steps.append(obs - obs.mean(axis=0))
    # Per-episode means: correlated std (plus uncorrelated std / 10); deviations: uncorrelated std.
    assert np.std(act_means) == pytest.approx(np.hypot(0.015, 0.005), rel=0.1)
    assert np.std(obs_means) == pytest.approx(np.hypot(0.001, 0.0002), rel=0.1)
    assert np.std(obs_steps) == pytest.approx(0.002, rel=0.05)
    assert np.std([randomizer.perturb_action(np.zeros(19)) - act_means[-1] for _ in range(500)]) == \
        pytest.approx(0.05, rel=0.1)


def test_parameters_land_in_the_context(env):
    env.reset(seed=4)
    randomizer, plant, plant_context = env.randomizer, env.plant, env.plant_context
    sample, inspector = randomizer.sample, context_inspector(env)
    for body, m0, f in zip(randomizer.robot_mass_bodies, randomizer.robot_mass0, sample.robot_mass, strict=True):
        assert body.get_mass(plant_context) == pytest.approx(m0 * f)
    frozen = env.objects.frozen_mask(env.context)
    for body, m0, f, is_frozen in zip(env.objects.bodies, randomizer.object_mass0, sample.object_mass, frozen,
                                      strict=True):
        assert body.get_mass(plant_context) == pytest.approx(m0 * (env.scenario.freeze.mass_scale if is_frozen else f))
    for geometries, factors in ((randomizer.robot_geometries, sample.robot_friction),
                                (randomizer.object_geometries, sample.object_friction)):
        for body_geometries, f in zip(geometries, factors, strict=True):
            for g in body_geometries:
                nominal = randomizer.nominal_proximity[g].GetProperty("material", "coulomb_friction")
                assert friction(inspector, g) == pytest.approx(nominal.static_friction() * f)
    for k, (actuator, joint) in enumerate(zip(randomizer.actuators, randomizer.joints, strict=True)):
        kp, kd = randomizer.nominal_gains[k]
        gains = actuator.get_controller_gains()
        assert (gains.p, gains.d) == pytest.approx((kp * sample.kp_scale[k], kd * sample.damping_scale[k]))
        assert joint.GetDampingVector(plant_context) == pytest.approx(
            randomizer.nominal_damping[k] * sample.damping_scale[k])
        lower, upper = randomizer.nominal_limits[k]
        assert joint.position_lower_limits() == pytest.approx(lower + sample.lower_offset[k])
        assert joint.position_upper_limits() == pytest.approx(upper + sample.upper_offset[k])
    assert plant.gravity_field().gravity_vector() == pytest.approx([0, 0, -9.81] + sample.gravity_offset)
    for body, geometries, s in zip(env.objects.bodies, randomizer.object_all_geometries, sample.object_scale,
                                   strict=True):
        for g in geometries:
            assert inspector.GetShape(g).scale3() == pytest.approx([s, s, s])
        assert body.CalcCenterOfMassInBodyFrame(plant_context) == pytest.approx(body.default_com() * s)


def test_scale_keeps_the_collision_filters_and_resolves_penetration(env):
    env.reset(seed=5)
    candidates = set(context_inspector(env).GetCollisionCandidates())
    randomizer = env.randomizer
    randomizer.apply_physical(randomizer.sample_physical(RandomGenerator(99)), include_scale=True)
    assert set(context_inspector(env).GetCollisionCandidates()) == candidates  # Freezer filters re-declared.
    assert randomizer.apply_pose_noise(RandomGenerator(3))  # A lone block: noise applied, then lifted free.
    scene_graph = env.objects.scene_graph
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(env.context))
    target = set(randomizer.object_geometries[env.objects.index(env.target_object)])
    assert all(p.depth <= 0 for p in query.ComputePointPairPenetration() if (p.id_A in target) != (p.id_B in target))


def test_same_seed_gives_identical_samples(env):
    first, _ = env.reset(seed=7)
    sample = env.randomizer.sample
    pose = env.object_pose().GetAsMatrix4()
    stepped = env.step(np.full(19, 0.1))[0]
    second, _ = env.reset(seed=7)
    for field in dataclasses.fields(sample):
        np.testing.assert_array_equal(getattr(sample, field.name), getattr(env.randomizer.sample, field.name))
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(pose, env.object_pose().GetAsMatrix4())
    np.testing.assert_array_equal(stepped, env.step(np.full(19, 0.1))[0])
    env.reset(seed=8)
    assert not np.array_equal(sample.object_mass, env.randomizer.sample.object_mass)


def test_resample_every_n_plant_steps():
    env = paper_env("orient", resample_every_sim_steps=50)
    env.reset(seed=1)
    randomizer = env.randomizer
    first, shapes = randomizer.sample, np.array([context_inspector(env).GetShape(g).scale3() for g in
                                                 randomizer.object_geometries[0]])
    for _ in range(5):  # 5 x 1/60 s = 41 plant steps of 2 ms: not yet.
        env.step(np.zeros(19))
    assert randomizer.sample is first
    for _ in range(2):  # 58 plant steps: re-drawn, but the geometry only changes at the next reset.
        env.step(np.zeros(19))
    assert randomizer.sample is not first
    assert not np.array_equal(first.robot_mass, randomizer.sample.robot_mass)
    np.testing.assert_array_equal(
        [context_inspector(env).GetShape(g).scale3() for g in randomizer.object_geometries[0]], shapes)
    env.reset()
    assert context_inspector(env).GetShape(randomizer.object_geometries[0][0]).scale3()[0] == \
        pytest.approx(randomizer.sample.object_scale[0])


def test_disabled_groups_change_nothing():
    plain = make_env("orient")
    observation, _ = plain.reset(seed=3)
    assert not plain.randomizer.enabled
    np.testing.assert_array_equal(observation, plain.observation())  # No observation noise.
    partial = paper_env("orient", gravity=False, object_mass=False, joint_limits=False, observation_noise=False)
    partial.reset(seed=3)
    assert partial.plant.gravity_field().gravity_vector() == pytest.approx([0, 0, -9.81])
    frozen = partial.objects.frozen_mask(partial.context)
    for body, is_frozen in zip(partial.objects.bodies, frozen, strict=True):
        expected = body.default_mass() * (partial.scenario.freeze.mass_scale if is_frozen else 1.0)
        assert body.get_mass(partial.plant_context) == pytest.approx(expected)
    for joint, (lower, upper) in zip(partial.randomizer.joints, partial.randomizer.nominal_limits, strict=True):
        np.testing.assert_array_equal(joint.position_lower_limits(), lower)
        np.testing.assert_array_equal(joint.position_upper_limits(), upper)
    assert partial.randomizer.sample.robot_mass is not None  # The groups left on still draw.
    for name in ("gravity_offset", "object_mass", "lower_offset"):
        assert getattr(partial.randomizer.sample, name) is None


@pytest.mark.parametrize("name", task_names())
def test_every_task_resets_and_steps_with_the_paper_config(name):
    env = paper_env(name, resample_every_sim_steps=20)
    rng = np.random.default_rng(0)
    for seed in (0, None):  # The second reset applies the object scale drawn by the mid-episode resamples.
        observation, _ = env.reset(seed=seed)
        assert np.all(np.isfinite(observation))
        for _ in range(4):
            observation, reward, _, _, info = env.step(rng.uniform(-1, 1, 19))
            assert np.all(np.isfinite(observation)) and np.isfinite(reward)
            assert not info["simulator_error"], info.get("error")
    if name == "search":  # The target lies in a pile: no pose noise (it would interpenetrate its neighbours).
        assert not env.randomizer.apply_pose_noise(RandomGenerator(1))
