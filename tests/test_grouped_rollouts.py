"""Step groups: ProcessVectorEnv.step_async / step_wait, and PPO rollouts whose worker groups step on their own."""

import dataclasses

import numpy as np
import pytest
import torch

from seqdex_drake.envs.vector import ProcessVectorEnv
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.registry import default_config

TASK, SEED = "grasp", 7


def test_step_groups_give_what_step_gives():
    """Groups started one by one and collected in arrival order give, env by env, the lock-step results."""
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (4, 4, 19))
    config = dataclasses.replace(default_config(TASK), episode_length=3)  # An autoreset inside the run.
    with ProcessVectorEnv(TASK, 4, seed=SEED, config=config, envs_per_worker=4) as lockstep, \
            ProcessVectorEnv(TASK, 4, seed=SEED, config=config, envs_per_worker=2) as grouped:
        assert grouped.step_groups == [[0, 1], [2, 3]] and lockstep.step_groups == [[0, 1, 2, 3]]
        np.testing.assert_array_equal(lockstep.reset()[0], grouped.reset()[0])
        truncations = 0
        for step_actions in actions:
            expected = lockstep.step(step_actions)
            truncations += int(np.sum(expected[3]))
            for group, indices in enumerate(grouped.step_groups):
                grouped.step_async(group, step_actions[indices])
            results = dict(grouped.step_wait() for _ in grouped.step_groups)
            for group, indices in enumerate(grouped.step_groups):
                observations, rewards, terminated, truncated, infos = results[group]
                np.testing.assert_array_equal(observations, expected[0][indices])
                np.testing.assert_array_equal(rewards, expected[1][indices])
                np.testing.assert_array_equal(terminated, expected[2][indices])
                np.testing.assert_array_equal(truncated, expected[3][indices])
                for info, other in zip(infos, [expected[4][i] for i in indices], strict=True):
                    assert info.keys() == other.keys()
        assert truncations == 4  # Every env's autoreset happened inside the run.


def test_misuse_is_a_clear_error():
    with ProcessVectorEnv(TASK, 2, seed=SEED, envs_per_worker=1) as env:
        with pytest.raises(RuntimeError, match="call reset"):
            env.step_async(0, np.zeros((1, 19)))
        env.reset()
        with pytest.raises(RuntimeError, match="no step group is stepping"):
            env.step_wait()
        with pytest.raises(ValueError, match="expected 1 actions for step group 1"):
            env.step_async(1, np.zeros((2, 19)))
        with pytest.raises(IndexError, match="step group 2 out of range"):
            env.step_async(2, np.zeros((1, 19)))
        env.step_async(0, np.zeros((1, 19)))
        with pytest.raises(RuntimeError, match="already stepping"):
            env.step_async(0, np.zeros((1, 19)))
        with pytest.raises(RuntimeError, match="still stepping"):
            env.step(np.zeros((2, 19)))
        group, (observations, *_) = env.step_wait()
        assert group == 0 and observations.shape == (1, env.single_observation_space.shape[0])
        env.step(np.zeros((2, 19)))  # Usable again.


def _config(**overrides) -> PPOConfig:
    values = dict(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), horizon=4, num_minibatches=2,
                  num_epochs=1, seed=5)
    values.update(overrides)
    return PPOConfig(**values)


def _rollout(envs_per_worker: int, **overrides):
    with ProcessVectorEnv(TASK, 4, seed=SEED, envs_per_worker=envs_per_worker) as env:
        learner = PPO.for_env(_config(**overrides), env)
        metrics = learner.collect(env)
        return learner, metrics


def test_grouped_rollout_is_deterministic_and_replays_in_lockstep():
    """The grouped rollout (2 workers) is the same in two runs, and its buffer is a real rollout: replaying its
    actions in a lock-step vector env of the same envs gives its observations and rewards."""
    first, metrics = _rollout(2)
    second, second_metrics = _rollout(2)
    buffer = first.buffer
    assert buffer.full
    for name in ("obs", "actions", "log_probs", "rewards", "values", "terminated", "truncated"):
        torch.testing.assert_close(getattr(buffer, name), getattr(second.buffer, name), rtol=0, atol=0)
    assert metrics == second_metrics and any(key.startswith("reward/") for key in metrics)
    with ProcessVectorEnv(TASK, 4, seed=SEED, envs_per_worker=4) as env:
        observations, _ = env.reset(seed=first.config.seed)
        np.testing.assert_array_equal(observations, buffer.obs[0].numpy())
        for t in range(buffer.horizon):
            actions = first._env_actions(buffer.actions[t])
            observations, rewards, *_ = env.step(actions)
            np.testing.assert_array_equal(torch.as_tensor(rewards, dtype=buffer.rewards.dtype), buffer.rewards[t])
            if t + 1 < buffer.horizon:
                np.testing.assert_array_equal(observations, buffer.obs[t + 1].numpy())
        np.testing.assert_array_equal(observations, first._next_obs.numpy())


def test_lockstep_rollouts_are_kept_where_asked_or_where_there_is_one_group():
    """``grouped_rollouts=False``, or a single worker, take the lock-step path: the same numbers as each other
    for the same envs and seed (the grouped path draws its noise differently)."""
    lockstep, _ = _rollout(2, grouped_rollouts=False)
    single, _ = _rollout(4)
    torch.testing.assert_close(lockstep.buffer.actions, single.buffer.actions, rtol=0, atol=0)
    grouped, _ = _rollout(2)
    assert not torch.equal(grouped.buffer.actions, lockstep.buffer.actions)
