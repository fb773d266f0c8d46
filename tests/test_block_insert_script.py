"""The scripted block Insert (``tasks/scripted/block_insert_script.py``) and the budget block Insert built on it: the
budget
config applies the script as its residual base on yaw-90 goals, the script is Markov in (observation, step) and
reads the reset's grasp off the observation, and the script alone seats a block on its goal and lets go of it."""

import dataclasses

import numpy as np
import pytest
from script_checks import assert_markov, assert_zero_corrections_apply

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.observation_layout import GOAL_POSITION_ERROR
from seqdex_drake.robots.allegro import scale_action_to_limits, unscale_limits_to_action
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import budget_config, default_config
from seqdex_drake.tasks.residual import make_base
from seqdex_drake.tasks.scripted.block_insert_script import (
    JOINT_Q,
    RELEASE_DELTA,
    THUMB_ROTATION,
    TRIPOD_THUMB_ROTATION,
    ScriptedBlockInsert,
    run_episode,
)


@pytest.fixture(scope="module")
def env():
    return make_env("insert", budget_config("insert"))


def test_budget_config_is_a_residual_on_the_script_with_yaw_90_goals():
    config = budget_config("insert")
    assert config.residual == "block_insert_script" and not config.hand_actions and config.observe_time
    assert config.goal_yaws_deg == [90.0] and default_config("insert").goal_yaws_deg == [0.0, 90.0]
    assert isinstance(make_base(config.residual), ScriptedBlockInsert)
    for yaws in ([], [45.0], [float("nan")]):
        with pytest.raises(ValueError, match="goal_yaws_deg must be"):
            TaskConfig(goal_yaws_deg=yaws)
    with pytest.raises(ValueError, match="TaskConfig insert: goal_yaws_deg must be"):
        dataclasses.replace(config, goal_yaws_deg=[30.0])


def test_the_script_is_markov_and_reads_the_grasp_off_the_observation(env):
    observation, _ = env.reset(seed=4)
    assert env.observation_space.shape == (174,) and observation[173] == 0.0  # Goal part and progress entry.
    np.testing.assert_allclose(env.goal[3:], [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)], atol=1e-9)  # Yaw 90.
    np.testing.assert_array_equal(env.action_space.high[:16], 0.0)  # The hand is the script's.
    first = assert_markov(ScriptedBlockInsert, observation, (0, 10, 60, 99, 100, 103, 115, 124), 173)
    # Step 0: the reset's hand targets, from the joint positions and motor torques (PD law).
    np.testing.assert_allclose(first.act(observation, 0)[:16], unscale_limits_to_action(env._hand_target), atol=2e-3)
    moved = observation.copy()
    moved[159] = observation[159] - observation[166] - 0.05  # The goal 5 cm behind the block (along -x) instead
    moved[166] = -0.05  # of ahead of it (the block where it is): the wrist turns back.
    assert first.act(observation, 30)[16] > 0.0 > first.act(moved, 30)[16]
    assert first.act(observation, 115)[18] == 1.0  # The lift, after the release.


def test_zero_corrections_apply_the_script(env):
    """The budget env given zeros applies exactly the script's action of its own observation."""
    assert_zero_corrections_apply(env, ScriptedBlockInsert(), seed=3, steps=15)


@pytest.mark.parametrize("seed", [0, 6])  # A 1x4 and a curved 1x2, each on a 2-layer plate.
def test_the_script_alone_seats_the_block_and_lets_go(env, seed):
    episode = run_episode(env, seed)
    assert episode.success
    assert episode.position_error < 0.008 and episode.rotation_error < 0.1  # Seated, studs home (to a few mm).
    assert env.fingertip_distance() > 0.4  # Released: the hand has lifted away.
    plate = next(name for name in env.objects.names if name.startswith("plate_")
                 and env.objects.positions(env.context)[env.objects.index(name), 4] > 0.0)
    assert plate in env.objects.frozen_names(env.context)  # A fixture: the hand came near, it never woke.
    np.testing.assert_allclose(env.objects.positions(env.context)[env.objects.index(plate), 4:],
                               [0.25, -0.23, 0.618], atol=1e-5)  # (It rose 0.5-1.5 cm when it woke.)


def test_the_wrist_holds_still_when_the_block_is_not_in_hand(env):
    """A block in the pinch is steered; one that is not in hand (dropped, or never grasped: a failed Grasp in a
    chain) is not chased: the wrist holds, the hand keeps its targets."""
    script = ScriptedBlockInsert()
    observation, _ = env.reset(seed=3)
    assert script.holds(observation)
    assert np.linalg.norm(script.act(observation, 20)[16:]) > 0.1  # Carried toward the goal.
    away = np.array(observation, dtype=float)
    away[GOAL_POSITION_ERROR] -= [0.0, 0.12, 0.0]  # The observed block 12 cm from the hand, in the box.
    assert not script.holds(away)
    action = script.act(away, 20)
    np.testing.assert_array_equal(action[16:], 0.0)
    np.testing.assert_allclose(action[:16], script.act(observation, 20)[:16])


def test_the_release_goes_by_the_grasp_in_hand(env):
    """Insert's own tripod opens by RELEASE_DELTA; another grasp (the thumb's rotation well off its lower limit, as
    in Grasp's jaw pinch) relaxes: its targets become the measured joint positions."""
    script = ScriptedBlockInsert()
    observation, _ = env.reset(seed=3)
    assert script.release_kind(observation) == "tripod"
    held = script.act(observation, 0)[:16]
    previous = np.array(observation, dtype=float)
    previous[124:140] = held  # As if the held grasp had been applied: the release adds a sixth of RELEASE_DELTA.
    np.testing.assert_allclose(scale_action_to_limits(script.act(previous, 100)[:16]),
                               scale_action_to_limits(held) + RELEASE_DELTA / 6, atol=1e-9)
    pinch = previous.copy()
    pinch[JOINT_Q.start + THUMB_ROTATION] = TRIPOD_THUMB_ROTATION + 0.2
    assert script.release_kind(pinch) == "relax"
    np.testing.assert_allclose(script.act(pinch, 100)[:16], unscale_limits_to_action(pinch[JOINT_Q]), atol=1e-12)
    assert ScriptedBlockInsert(release="tripod").release_kind(pinch) == "tripod"
    with pytest.raises(ValueError, match="release must be"):
        ScriptedBlockInsert(release="open")


def test_a_jaw_held_block_is_let_go_once_down_at_the_seat(env):
    """Grasp's jaw pinch (a grasp that relaxes) lets go as soon as the funnel has the block down at the seat, and the
    wrist lifts once it has dropped onto the studs; above the seat it is held and steered; Insert's own tripod
    keeps its timed release."""
    script = ScriptedBlockInsert()
    observation, _ = env.reset(seed=3)
    pinch = np.array(observation, dtype=float)
    pinch[JOINT_Q.start + THUMB_ROTATION] = TRIPOD_THUMB_ROTATION + 0.2
    at = {}
    for name, height in (("above", script.seat + 0.005), ("seat", script.seat), ("dropped", 0.002)):
        at[name] = pinch.copy()
        at[name][GOAL_POSITION_ERROR.start + 2] = -height  # goal - block: the block's bottom this high above it.
    assert not script.released(at["above"], 20) and script.released(at["seat"], 20)
    np.testing.assert_allclose(script.act(at["seat"], 20)[:16], unscale_limits_to_action(pinch[JOINT_Q]), atol=1e-12)
    np.testing.assert_array_equal(script.act(at["seat"], 20)[16:], np.zeros(3))  # Let go: the wrist holds.
    assert not script.lifting(at["seat"], 20) and script.lifting(at["dropped"], 20)
    np.testing.assert_array_equal(script.act(at["dropped"], 20)[16:], [0.0, 0.0, 1.0])
    tripod = np.array(observation, dtype=float)
    tripod[GOAL_POSITION_ERROR.start + 2] = -script.seat
    assert script.release_kind(tripod) == "tripod" and not script.released(tripod, 20)  # Timed: step 100.
    assert not ScriptedBlockInsert(seated_dz=None).released(at["seat"], 20)


def test_letting_go_at_the_seat_places_a_block_the_timed_release_loses():
    """A real hand-off: Grasp's scripted pickup (seed 4, a 1x3), carried over its goal as the chain carries it. Held
    at the seat until step 100 the block turns in the jaws on the studs and ends tilted on them; let go once down
    at the seat it drops onto them and is placed."""
    grasp, insert = make_env("grasp", budget_config("grasp")), make_env("insert", budget_config("insert"))
    grasp.reset(seed=4)
    for _ in range(grasp.config.episode_length):
        *_, info = grasp.step(np.zeros(19))
    assert info["success"]
    state = grasp.get_state()
    outcomes = {}
    for seated_dz in (None, 0.001):
        insert._unbound_base.seated_dz = seated_dz  # The env's script (its residual base), both rules.
        insert.reset(seed=4, options={"initial_state": state})
        for _ in range(insert.config.episode_length):
            *_, info = insert.step(np.zeros(19))
        outcomes[seated_dz] = (bool(info["success"]), insert.task.goal_errors(insert))
    assert not outcomes[None][0] and outcomes[0.001][0], outcomes
