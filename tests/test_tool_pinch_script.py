"""The yaw-planned tool pinch (``tasks/scripted/tool_pinch_script.py``): its hand shapes put the tips where
planned, it is a function of (observation, step), its plan holds once the jaws close, and in real simulations it
lifts the hammer where the fist cannot (a positive yaw, the head toward the thumb) as well as where the fist can,
and the light ladle, which turns with a plan that follows it."""

import dataclasses

import numpy as np
import pytest

from seqdex_drake.cli.main import main
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.observation_layout import PREVIOUS_ACTION
from seqdex_drake.robots.allegro import FINGERTIP_FRAMES
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.scripted.tool_pinch_script import PINCH_DIGITS, R_PalmW, ScriptedToolPinch


@pytest.fixture(scope="module")
def pinch():
    return ScriptedToolPinch()


@pytest.fixture(scope="module")
def env():
    return make_env("tool_grasp", dataclasses.replace(budget_config("tool_grasp"), residual="tool_pinch_script"))


def _tips(pinch, q):
    plant = pinch._plant
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    return np.array([plant.CalcPointsPositions(context, plant.GetFrameByName(FINGERTIP_FRAMES[digit]), np.zeros(3),
                                               plant.world_frame()).ravel() for digit in PINCH_DIGITS])


@pytest.mark.parametrize("yaw_key", [-60, 0, 30])
def test_the_contact_shape_puts_the_tips_on_the_planned_points(pinch, yaw_key):
    shapes = pinch.pinch_shapes(yaw_key)
    assert len(shapes) == len(pinch.gaps) + 1
    np.testing.assert_allclose(_tips(pinch, shapes[-2]), pinch.tip_targets(yaw_key / 100, 0.0), atol=1e-3)
    # The squeeze aims past contact, across the handle: the index and middle tips toward the thumb, the thumb
    # toward them.
    yaw = yaw_key / 100
    n_Palm = R_PalmW @ [np.cos(yaw), np.sin(yaw), 0.0]
    across = (_tips(pinch, shapes[-1]) - _tips(pinch, shapes[-2])) @ n_Palm
    assert across[0] < -1e-3 and across[1] < -1e-3 and across[2] > 1e-3


def test_at_large_positive_yaw_the_index_abduction_stays_within_its_limit(pinch):
    for shape in pinch.pinch_shapes(60):
        assert abs(shape[0]) <= pinch.abduction_limit + 1e-6
    assert abs(pinch.pinch_shapes(20)[-2][0]) > 0.0  # Below the threshold the abduction is free.


def test_the_action_is_a_function_of_observation_and_step(env):
    observation, _ = env.reset(seed=3)
    fresh, cached = ScriptedToolPinch(), ScriptedToolPinch()
    for step in (0, 20, 40):
        cached.act(observation, step)
    for step in (0, 20, 40, 55, 70, 100):
        np.testing.assert_array_equal(fresh.act(observation, step), cached.act(observation, step))
        assert np.all(np.abs(fresh.act(observation, step)) <= 1.0)
    np.testing.assert_array_equal(fresh.act(observation, 100)[16:], 0.0)  # Held still after the lift.


def test_once_the_jaws_close_the_plan_is_the_one_the_hand_was_sent(pinch, env):
    observation, _ = env.reset(seed=3)
    _, yaw = pinch.grasp_point_and_yaw(observation)
    observed = int(round(yaw * 100))
    sent = observation.astype(float)
    sent[PREVIOUS_ACTION][:16] = pinch.hand_action(pinch.pinch_shapes(observed + 25), pinch.close_at + 5)
    assert pinch.planned_yaw_key(sent, pinch.close_at + 6, yaw) == observed + 25  # The tool turned; the plan holds.
    assert pinch.planned_yaw_key(sent, pinch.close_at - 1, yaw) == observed  # Before closing, the tool's yaw.
    # A previous action that is no plan of this pinch (a state another controller left): the tool's yaw.
    assert pinch.planned_yaw_key(observation, pinch.close_at + 6, yaw) == observed


def test_a_tool_grip_may_set_its_own_squeeze(pinch):
    assert pinch.for_object("spoon").force == 1.2 and pinch.for_object("hammer").force == pinch.force == 2.0


@pytest.mark.parametrize("seed", [0, 2, 10])  # Yaw +0.22 (the fist fails), -0.37, +0.72 (abduction held).
def test_the_pinch_lifts_the_hammer_without_turning_it(env, seed):
    env.reset(seed=seed)
    for _ in range(env.config.episode_length):
        _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
        if terminated or truncated:
            break
    rise, turned = env.task._lift_and_turn(env)
    assert info["success"] and rise > 0.1 and turned < 0.3


def test_rollout_runs_a_named_base_alone_and_refuses_it_with_a_checkpoint(tmp_path, capsys):
    assert main(["rollout", "--task", "tool_grasp", "--zero-action", "--base", "tool_pinch_script", "--test",
                 "--episodes", "1"]) == 0
    assert "the tool_pinch_script base alone" in capsys.readouterr().out
    assert main(["rollout", "--task", "tool_grasp", "--zero-action", "--base", "fist", "--test"]) == 2
    assert "unknown residual base; valid bases: tool_grasp_script, tool_pinch_script" in capsys.readouterr().err
    assert main(["rollout", "--task", "tool_grasp", "--base", "tool_pinch_script", "--checkpoint", "x.pt"]) == 2
    assert "add --zero-action" in capsys.readouterr().err
    assert main(["rollout", "--task", "grasp", "--zero-action", "--base", "tool_pinch_script", "--test"]) == 2
    err = capsys.readouterr().err
    assert "acts in the tool_grasp env, not grasp's; bases for grasp: block_grasp_script" in err
    assert "Traceback" not in err


def test_collect_writes_the_hand_offs_of_a_base_alone(tmp_path, capsys):
    """``seqdex collect --zero-action --base tool_pinch_script``: the pinch's successful terminal states become tool
    Reorient's start buffer (forward initialization from a scripted stage)."""
    from seqdex_drake.chaining.terminal_buffer import TerminalBuffer

    out = tmp_path / "pinch.npz"
    assert main(["collect", "--task", "tool_grasp", "--zero-action", "--base", "tool_pinch_script", "--episodes", "2",
                 "--seed", "1", "--out", str(out)]) == 0
    assert "2 successes out of 2 tool_grasp episodes" in capsys.readouterr().out
    buffer = TerminalBuffer.load(out, expected_task="tool_reorient")
    assert len(buffer) == 2 and all(buffer.successes)
    assert main(["collect", "--task", "tool_grasp", "--base", "tool_pinch_script", "--out", str(out)]) == 2
    assert "add --zero-action" in capsys.readouterr().err


def test_every_residual_base_names_the_task_it_acts_in():
    from seqdex_drake.tasks.registry import task_names
    from seqdex_drake.tasks.residual import BASE_TASKS, RESIDUAL_BASES

    assert set(BASE_TASKS) == set(RESIDUAL_BASES) and set(BASE_TASKS.values()) <= set(task_names())


def _ladle_episode(seed: int) -> tuple[float, float]:
    env = make_env("tool_grasp", dataclasses.replace(budget_config("tool_grasp"), residual="tool_pinch_script",
                                                     object_types=[2]))
    env.reset(seed=seed)
    for _ in range(env.config.episode_length):
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
        if terminated or truncated:
            break
    return env.task._lift_and_turn(env)


def test_the_held_plan_lifts_the_ladle_where_a_plan_that_follows_it_turns_it(monkeypatch):
    """Tuning seed 2: the 145 g ladle turns a little in the closing jaws; re-planned from its observed yaw every
    step, the fingers follow it round (1.4 rad); with the plan held it is lifted within the 0.3 rad test."""
    rise, turned = _ladle_episode(2)
    assert rise > 0.1 and turned < 0.3
    monkeypatch.setattr(ScriptedToolPinch, "planned_yaw_key", lambda self, observation, step, yaw: round(yaw * 100))
    rise, turned = _ladle_episode(2)
    assert rise > 0.1 and turned > 0.6
