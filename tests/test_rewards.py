"""Reward terms on constructed inputs: values and signs of the paper's formulas."""

import numpy as np
import pytest

from seqdex_drake.tasks.registry import default_config
from seqdex_drake.tasks.rewards import (
    goal_reward,
    grasp_reward,
    orient_reward,
    quaternion_angle,
    search_reward,
)

ZERO_ACTION, ZERO_TORQUE = np.zeros(19), np.zeros(16)


def test_penalties_are_negative_and_quadratic():
    weights = default_config("grasp").reward
    terms = grasp_reward(weights, 0.05, np.ones(19), np.full(16, 0.5))
    assert terms["action_penalty"] == pytest.approx(-0.001 * 19)
    assert terms["torque_penalty"] == pytest.approx(-0.003 * 16 * 0.25)


def test_grasp_closeness_is_one_within_e0_and_decays_beyond():
    weights = default_config("grasp").reward
    assert grasp_reward(weights, 0.08, ZERO_ACTION, ZERO_TORQUE)["closeness"] == pytest.approx(1.0)
    far = grasp_reward(weights, 0.5, ZERO_ACTION, ZERO_TORQUE)["closeness"]
    assert far == pytest.approx(np.exp(-5 * 0.4))


def test_search_rewards_pixels_and_penalises_far_fingertips():
    weights = default_config("search").reward
    terms = search_reward(weights, 30, 0.5, ZERO_ACTION, ZERO_TORQUE)
    assert terms["pixels"] == pytest.approx(150.0)
    assert terms["fingertip"] == pytest.approx(0.2 - 0.5)
    assert search_reward(weights, 30, 0.1, ZERO_ACTION, ZERO_TORQUE)["fingertip"] == 0.0


def test_orient_rewards_rotation():
    weights = default_config("orient").reward
    assert orient_reward(weights, 0.7, 0.3, ZERO_ACTION, ZERO_TORQUE)["rotation"] == pytest.approx(0.7)


def test_goal_reward_is_top_at_the_goal():
    weights = default_config("grasp").reward.__class__(progress=1.0, fingertip=0.0, alpha0=20.0, alpha1=1.0, e0=0.06)
    at_goal = goal_reward(weights, 0.0, 0.0, 0.2, ZERO_ACTION, ZERO_TORQUE)
    off = goal_reward(weights, 0.05, 0.3, 0.2, ZERO_ACTION, ZERO_TORQUE)
    assert at_goal["goal"] == pytest.approx(1.0) and off["goal"] < 0.3


def test_quaternion_angle():
    half = np.sqrt(0.5)
    assert quaternion_angle(np.array([1, 0, 0, 0.0]), np.array([1, 0, 0, 0.0])) == pytest.approx(0.0)
    assert quaternion_angle(np.array([half, 0, 0, half]), np.array([1, 0, 0, 0.0])) == pytest.approx(np.pi / 2)
