"""Sub-task environments: registry-wide create/reset/step, the paper's observation sizes, gymnasium API."""

import dataclasses

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.registry import default_config, task_names

# The paper's tables; the hand-over chain (reach, lower: not in the paper) uses the base layout and short episodes, as
# does the scripted retrieve (not in the paper: its three grip attempts, carry and set-down take up to 800 steps).
PAPER_OBSERVATION_SIZE = {"search": 160, "orient": 159, "grasp": 159, "insert": 173,
                          "tool_grasp": 159, "tool_reorient": 173, "reach": 159, "lower": 159, "retrieve": 159}
PAPER_EPISODE_LENGTH = {"search": 75, "orient": 75, "grasp": 150, "insert": 125, "tool_grasp": 150,
                        "tool_reorient": 125, "reach": 30, "lower": 15, "retrieve": 800}


@pytest.fixture(scope="module", params=task_names())
def env(request):
    return make_env(request.param)


def test_observation_size_and_episode_length_match_the_paper(env):
    name = env.config.name
    assert env.observation_space.shape == (PAPER_OBSERVATION_SIZE[name],)
    assert env.config.episode_length == PAPER_EPISODE_LENGTH[name]
    assert env.action_space.shape == (19,)  # 16 hand joints + 3D wrist translation.
    # A wrist-only task pins the hand dims (low == high == 0); the others range over [-1, 1].
    hand_range = 0.0 if not env.config.hand_actions else 2.0
    assert np.all(env.action_space.high[:16] - env.action_space.low[:16] == hand_range)
    assert np.all(env.action_space.low[16:] == -1.0) and np.all(env.action_space.high[16:] == 1.0)


def test_a_wrist_only_task_ignores_and_zeroes_the_hand_actions():
    env = make_env("reach")
    env.reset(seed=5)
    wrist = np.array([0.3, -0.2, 0.1])
    pinned, _, _, _, _ = env.step(np.concatenate([np.zeros(16), wrist]))
    env.reset(seed=5)
    ignored, _, _, _, _ = env.step(np.concatenate([np.ones(16), wrist]))
    np.testing.assert_array_equal(pinned, ignored)  # Same state, and the previous action reads 0 for the hand.


def test_reset_and_step_with_zero_and_random_actions(env):
    observation, info = env.reset(seed=3)
    assert observation.shape == env.observation_space.shape and np.all(np.isfinite(observation))
    for action in [np.zeros(19), *[env.action_space.sample() for _ in range(4)]]:
        observation, reward, terminated, truncated, info = env.step(action)
        assert np.all(np.isfinite(observation)) and np.isfinite(reward)
        assert not info["simulator_error"]
        terms = {k: v for k, v in info.items() if k.startswith("reward/")}
        assert terms and reward == pytest.approx(sum(terms.values()))


def test_reset_is_deterministic_for_a_seed(env):
    first, _ = env.reset(seed=11)
    env.step(np.full(19, 0.3))
    second, _ = env.reset(seed=11)
    np.testing.assert_array_equal(first, second)


def test_saved_state_restores_exactly(env):
    """A restored state continues exactly as the original did: the same actions give the same observations.
    At the restore itself the motor-tactile entries are recomputed for the state (the torques the motors will
    exert from it), where the running episode reported those its last plant step applied."""
    if env.config.residual:  # A scripted base reads the episode's step count, which a restored episode starts at 0
        # (forward initialization starts a new episode there): the restored physics is compared without the base.
        env = make_env(env.config.name, dataclasses.replace(env.config, residual=""))
    env.reset(seed=5)
    env.step(np.full(19, -0.2))
    state = env.get_state()
    observation = env.observation()
    actions = np.random.default_rng(0).uniform(-1, 1, size=(4, 19))  # 4 steps: control and plant steps meet.
    original = [env.step(action)[0] for action in actions]
    env.reset(seed=6)
    restored, _ = env.reset(options={"initial_state": state})
    tactile = slice(143, 159)
    np.testing.assert_array_equal(np.delete(observation, np.r_[tactile]), np.delete(restored, np.r_[tactile]))
    again, _ = env.reset(options={"initial_state": state})
    np.testing.assert_array_equal(restored, again)
    np.testing.assert_array_equal(original, [env.step(action)[0] for action in actions])


def test_bad_actions(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(19,\)"):
        env.step(np.zeros(23))
    observation, reward, terminated, truncated, info = env.step(np.full(19, np.nan))
    assert truncated and info["nan_action"] and np.all(np.isfinite(observation))


def test_gymnasium_env_checker():
    check_env(make_env("grasp"), skip_render_check=True)


def test_unknown_task_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid tasks: search"):
        default_config("dance")


def test_a_block_at_its_insert_goal_succeeds_with_the_top_reward():
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RigidTransform, RotationMatrix

    env = make_env("insert")
    env.reset(seed=2)
    goal = env.goal
    X_goal = RigidTransform(Quaternion(goal[3:] / np.linalg.norm(goal[3:])), goal[:3])
    env.objects.set_pose(env.context, env.target_object, X_goal, frozen=True)
    terms = env.task.reward_terms(env, np.zeros(19))
    assert env.task.is_success(env)
    assert terms["goal"] == pytest.approx(1.0, abs=1e-6)
    # The 180 deg yaw flip of a symmetric brick counts as the goal too.
    flipped = RigidTransform(X_goal.rotation() @ RotationMatrix.MakeZRotation(np.pi), X_goal.translation())
    env.objects.set_pose(env.context, env.target_object, flipped, frozen=True)
    assert env.task.is_success(env)


def test_a_block_in_free_fall_fails_grasp():
    from pydrake.math import RigidTransform

    env = make_env("grasp")
    env.reset(seed=4)
    env.objects.set_pose(env.context, env.target_object, RigidTransform([0.25, 0.19, 1.0]))
    assert not env.task.is_success(env)  # High up, but the fingertips are far from it: not a grasp.
    for _ in range(10):
        env.step(np.zeros(19))
    assert not env.task.is_success(env)


def test_restoring_a_hand_off_state_sets_the_tasks_start_values():
    source = make_env("tool_grasp")
    source.reset(seed=1)
    source.step(np.zeros(19))
    state = source.get_state()  # Stands in for a tool Grasp terminal state (forward initialization).
    target = make_env("tool_reorient")
    target.reset(options={"initial_state": state})
    flipped = target.goal[3:]
    held = target.observation()[111 + 3:111 + 7]  # The tool's quaternion in the observation.
    from seqdex_drake.tasks.rewards import quaternion_angle

    assert quaternion_angle(flipped, held) == pytest.approx(np.pi, abs=1e-3)  # Goal: flipped about y.
    grasp = make_env("grasp")
    grasp.reset(seed=2)
    grasp_state = grasp.get_state()
    grasp.reset(seed=3)
    grasp.reset(options={"initial_state": grasp_state})
    assert grasp.task.start_height == pytest.approx(grasp.object_position()[2])


def test_reach_clearance_term_follows_the_hand_height():
    import dataclasses

    from seqdex_drake.tasks.handover_common import hand_center
    from seqdex_drake.tasks.reach import CLEARANCE_HIGH, CLEARANCE_LOW

    config = default_config("reach")
    assert config.reward.clearance == 0.0  # Off by default: Reach's reward ignores the height.
    config = dataclasses.replace(config, reward=dataclasses.replace(config.reward, clearance=0.5))
    env = make_env("reach", config)
    env.reset(seed=2)
    _, _, _, _, info = env.step(np.zeros(19))
    height = hand_center(env)[2] - env.object_position()[2]
    expected = 0.5 * np.clip((height - CLEARANCE_LOW) / (CLEARANCE_HIGH - CLEARANCE_LOW), 0.0, 1.0)
    assert 0.0 < expected and info["reward/clearance"] == pytest.approx(expected)


def test_orient_success_is_the_block_standing_upright():
    """Orient's success test (the block's z axis within acos(0.6) of world z), read from the observation's
    quaternion, on constructed states: upright, tilted just inside and just outside the threshold, on its side."""
    from pydrake.math import RigidTransform, RollPitchYaw

    env = make_env("orient")
    env.reset(seed=0)
    p_WB = env.object_pose().translation()
    threshold = env.config.success_threshold[0]
    tilt = np.arccos(threshold)
    for roll, expected in ((0.0, True), (tilt - 0.01, True), (tilt + 0.01, False), (np.pi / 2, False)):
        env.plant.SetFreeBodyPose(env.plant_context, env.object_body(), RigidTransform(RollPitchYaw(roll, 0, 0), p_WB))
        assert env.object_pose().rotation().matrix()[2, 2] == pytest.approx(np.cos(roll))
        assert env.task.is_success(env) is expected, roll


def test_scenario_overrides_change_the_envs_physics():
    import dataclasses

    config = dataclasses.replace(default_config("grasp"), scenario_overrides="{plant_config: {time_step: 0.001}}")
    env = make_env("grasp", config)
    assert env.scenario.plant_config.time_step == 0.001 and env.plant.time_step() == 0.001
    assert env.scenario.plant_config.discrete_contact_approximation == "lagged"  # The rest as the scenario has it.
    with pytest.raises(Exception, match="bogus"):
        make_env("grasp", dataclasses.replace(config, scenario_overrides="{bogus: 1}"))


def test_block_resets_leave_the_open_hand_clear_of_the_box():
    """The hovering open hand's fingertips reach 14.6 cm along +x and its palm 13 cm back: blocks sampled near the
    far or near wall put them inside it (21 of 150 resets), where no action could free them."""
    env = make_env("grasp")
    plant = env.plant
    hand = {int(index) for index in plant.GetBodyIndices(plant.GetModelInstanceByName("allegro"))}
    station_context = env.station.GetMyContextFromRoot(env.context)
    for seed in range(60):
        env.reset(seed=seed)
        query = env.station.GetOutputPort("query_object").Eval(station_context)
        inspector = query.inspector()
        touching = [pair for pair in query.ComputePointPairPenetration()
                    if {int(plant.GetBodyFromFrameId(inspector.GetFrameId(g)).index())
                        for g in (pair.id_A, pair.id_B)} & hand]
        assert not touching, f"seed {seed}: the open hand starts in contact ({touching[0].depth:.3f} m deep)"
