"""Fault tolerance: killed workers (restarted, or WorkerError), simulator blow-ups and NaN actions as flagged
truncations, and the learner's guard that keeps non-finite values out of the rollout buffer."""

import dataclasses
import os
import signal

import numpy as np
import pytest
import torch

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.envs.vector import ProcessVectorEnv, WorkerError
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv
from seqdex_drake.tasks.registry import default_config

TASK, SEED = "grasp", 5
CONFIG = dataclasses.replace(default_config(TASK), episode_length=6)


def tiny_config(**overrides) -> PPOConfig:
    values = dict(actor_hidden_sizes=(16, 16), critic_hidden_sizes=(16, 16), num_envs=2, horizon=4,
                  num_minibatches=2, num_epochs=2, learning_rate=1e-3, seed=1, checkpoint_every=100)
    values.update(overrides)
    return PPOConfig(**values)


def _kill_worker_after_first_update(vector_env, index: int):
    def callback(ppo: PPO, metrics: dict) -> None:
        if ppo.num_updates == 1:
            os.kill(vector_env.pids[index], signal.SIGKILL)
    return callback


def test_a_killed_worker_is_restarted_and_reported_as_a_lost_truncated_episode():
    with ProcessVectorEnv(TASK, 2, seed=SEED, config=CONFIG, max_restarts=1, timeout=120.0) as vector_env:
        observations, _ = vector_env.reset()
        observations, *_ = vector_env.step(np.zeros((2, 19)))
        old_pids = vector_env.pids
        os.kill(old_pids[0], signal.SIGKILL)
        after, rewards, terminated, truncated, infos = vector_env.step(np.zeros((2, 19)))
        assert truncated.tolist() == [True, False] and not terminated.any() and rewards[0] == 0.0
        info = infos[0]
        assert info["worker_restarted"] and "SIGKILL" in info["worker_error"] and "success" not in info
        np.testing.assert_array_equal(info["final_observation"], observations[0])  # What the caller last saw.
        assert vector_env.restarts == [1, 0] and vector_env.lost_episodes == 1
        assert vector_env.pids[0] != old_pids[0] and vector_env.pids[1] == old_pids[1]
        # The rebuilt env was reset with the documented seed: seed + index + num_envs * restarts.
        serial = make_env(TASK, CONFIG)
        np.testing.assert_array_equal(after[0], serial.reset(seed=SEED + 0 + 2 * 1)[0])
        vector_env.step(np.zeros((2, 19)))  # Both envs keep stepping.
        os.kill(vector_env.pids[1], signal.SIGKILL)  # A second failure exceeds the budget of one restart.
        with pytest.raises(WorkerError, match=r"worker 1 failed.*SIGKILL.*restart budget of 1 used up"):
            vector_env.step(np.zeros((2, 19)))
        assert vector_env.closed


@pytest.mark.parametrize("max_restarts", [1, 0])
def test_training_survives_a_killed_worker_only_with_restarts_on(tmp_path, max_restarts):
    vector_env = ProcessVectorEnv(TASK, 2, seed=SEED, config=CONFIG, max_restarts=max_restarts, timeout=120.0)
    try:
        ppo = PPO.for_env(tiny_config(), vector_env)
        train = lambda: ppo.train(vector_env, tmp_path, total_steps=3 * 2 * 4, progress=False,  # noqa: E731
                                  callbacks=[_kill_worker_after_first_update(vector_env, 1)])
        if max_restarts == 0:  # Today's default: the failure stops training, naming the worker.
            with pytest.raises(WorkerError, match="worker 1 failed.*SIGKILL"):
                train()
            assert vector_env.closed
            return
        metrics = train()
        assert ppo.num_updates == 3 and ppo.global_step == 3 * 2 * 4
        assert vector_env.lost_episodes == 1 and metrics["charts/lost_episodes"] == 1.0
        assert torch.isfinite(ppo.buffer.obs).all() and torch.isfinite(ppo.buffer.rewards).all()
    finally:
        vector_env.close()


def test_simulator_blow_up_and_nan_actions_are_flagged_truncations():
    env = make_env(TASK, CONFIG)
    env.reset(seed=SEED)
    env.plant.SetVelocities(env.plant_context, np.full(env.plant.num_velocities(), 1e300))  # Diverges.
    observation, reward, terminated, truncated, info = env.step(np.zeros(19))
    assert truncated and not terminated and reward == 0.0 and info["simulator_error"]
    assert np.isfinite(observation).all()

    with ProcessVectorEnv(TASK, 2, seed=SEED, config=CONFIG) as vector_env:
        vector_env.reset()
        actions = np.zeros((2, 19))
        actions[1, 3] = np.nan
        observations, rewards, terminated, truncated, infos = vector_env.step(actions)
        assert truncated.tolist() == [False, True] and infos[1]["nan_action"] and not infos[0]["nan_action"]
        assert np.isfinite(observations).all() and np.isfinite(infos[1]["final_observation"]).all()
        assert "reset_info" in infos[1]  # Autoreset into a fresh episode.


class NaNEmittingEnv(TargetVectorEnv):
    """The toy env, emitting NaN / inf in observations, rewards and final observations now and then."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.calls = 0

    def step(self, actions):
        observations, rewards, terminated, truncated, infos = super().step(actions)
        self.calls += 1
        if self.calls % 3 == 0:
            observations[0, 2] = np.nan
            rewards[1] = np.inf
        for info in infos:
            if "final_observation" in info:
                info["final_observation"] = np.full_like(info["final_observation"], -np.inf)
        return observations, rewards, terminated, truncated, infos


def test_nan_from_the_env_never_reaches_the_buffer():
    env = NaNEmittingEnv(num_envs=2, episode_length=3, failure_distance=10.0, seed=0)  # No terminations.
    ppo = PPO.for_env(tiny_config(horizon=6), env)
    for _ in range(2):
        metrics = {**ppo.collect(env), **ppo.update()}
        buffer = ppo.buffer
        for name in ("obs", "rewards", "values", "returns", "advantages"):
            assert torch.isfinite(getattr(buffer, name)).all(), name
        assert all(np.isfinite(value) for key, value in metrics.items() if key.startswith("losses/")
                   and key != "losses/explained_variance")
    # Every 3rd step: one observation entry and one reward; every 3rd step both envs truncate (3 entries each).
    assert ppo.nonfinite_values == 4 * (2 + 2 * 3) and metrics["charts/nonfinite_env_values"] == ppo.nonfinite_values
    model_parameters = torch.cat([parameter.reshape(-1) for parameter in ppo.model.parameters()])
    assert torch.isfinite(model_parameters).all()
