"""The process-based vector env: serial equivalence, autoreset, and failures reported instead of hung on."""

import dataclasses
import os
import signal
import time

import numpy as np
import pytest

from seqdex_drake.envs.subtask_env import EnvState, make_env
from seqdex_drake.envs.vector import ProcessVectorEnv, WorkerError
from seqdex_drake.tasks.registry import default_config

TASK = "grasp"  # A light scene: workers start in about a second.
SEED = 7


def _actions(steps: int, num_envs: int) -> np.ndarray:
    """A fixed, moderate action sequence [steps, num_envs, 19]."""
    return np.random.default_rng(0).uniform(-0.5, 0.5, (steps, num_envs, 19))


def _serial_rollout(config, seed: int, actions: np.ndarray) -> list[tuple]:
    """What a serial env seeded ``seed`` gives for ``actions``, with SB3-style autoreset."""
    env = make_env(TASK, config)
    observation, _ = env.reset(seed=seed)
    rollout = [(observation, None, None, None, None)]
    for action in actions:
        observation, reward, terminated, truncated, _ = env.step(action)
        final = None
        if terminated or truncated:
            final = observation
            observation, _ = env.reset()
        rollout.append((observation, reward, terminated, truncated, final))
    return rollout


def _assert_matches_serial(rollout: list[tuple], config, actions: np.ndarray) -> None:
    """Each env's column of a vector ``rollout`` [(observations, rewards, terminated, truncated), ...] (None
    rewards on the reset row) equals what a serial env seeded SEED + index gives for its actions."""
    for index in range(actions.shape[1]):
        serial = _serial_rollout(config, SEED + index, actions[:, index])
        for (observations, rewards, terminated, truncated), (obs, reward, term, trunc, _) in zip(
                rollout, serial, strict=True):
            np.testing.assert_array_equal(observations[index], obs)
            if reward is not None:
                assert (rewards[index], terminated[index], truncated[index]) == (reward, term, trunc)


def _assert_all_dead(vector_env: ProcessVectorEnv) -> None:
    assert vector_env.closed
    assert not any(process.is_alive() for process in vector_env._processes)


def test_two_workers_reproduce_the_serial_envs():
    steps, config = 10, default_config(TASK)
    assert config.episode_length > steps  # No autoreset in this horizon.
    actions = _actions(steps, 2)
    with ProcessVectorEnv(TASK, 2, seed=SEED, config=config) as vector_env:
        assert vector_env.single_observation_space.shape == (159,)
        assert vector_env.observation_space.shape == (2, 159) and vector_env.action_space.shape == (2, 19)
        observations, infos = vector_env.reset()
        assert observations.shape == (2, 159) and len(infos) == 2 and "success" in infos[0]
        vector_rollout = [(observations, None, None, None)]
        for action in actions:
            observations, rewards, terminated, truncated, infos = vector_env.step(action)
            assert rewards.shape == (2,) and terminated.dtype == bool and truncated.dtype == bool
            assert all(key.startswith("reward/") for info in infos for key in info if "/" in key)
            vector_rollout.append((observations, rewards, terminated, truncated))
        states = vector_env.get_states()
    _assert_matches_serial(vector_rollout, config, actions)
    assert all(isinstance(state, EnvState) for state in states)
    assert not np.array_equal(vector_rollout[0][0][0], vector_rollout[0][0][1])  # Different seeds per env.


def test_autoreset_returns_the_new_episode_and_keeps_the_final_one():
    config = dataclasses.replace(default_config(TASK), episode_length=3)
    actions = _actions(7, 1)
    serial = _serial_rollout(config, SEED, actions[:, 0])
    with ProcessVectorEnv(TASK, 1, seed=SEED, config=config) as vector_env:
        observations, _ = vector_env.reset()
        np.testing.assert_array_equal(observations[0], serial[0][0])
        done_steps = []
        for step, action in enumerate(actions, start=1):
            observations, rewards, terminated, truncated, infos = vector_env.step(action)
            observation, reward, _, trunc, final = serial[step]
            np.testing.assert_array_equal(observations[0], observation)
            assert rewards[0] == reward and truncated[0] == trunc
            if truncated[0]:
                done_steps.append(step)
                info = infos[0]
                np.testing.assert_array_equal(info["final_observation"], final)
                assert info["episode"]["length"] == 3
                assert "success" in info["final_info"] and "success" in info["reset_info"]
                assert info["final_info"]["reward/closeness"] == info["reward/closeness"]
            else:
                assert "final_observation" not in infos[0]
        assert done_steps == [3, 6]
        # A reset with an explicit seed reseeds env i with seed + i.
        observations, _ = vector_env.reset(seed=SEED)
        np.testing.assert_array_equal(observations[0], serial[0][0])


def test_reset_with_per_env_initial_states():
    with ProcessVectorEnv(TASK, 2, seed=SEED) as vector_env:
        vector_env.reset()
        vector_env.step(_actions(1, 2)[0])
        states = vector_env.get_states()
        observations, _ = vector_env.step(_actions(2, 2)[1])[:2]
        swapped, _ = vector_env.reset(options=[{"initial_state": states[1]}, {"initial_state": states[0]}])
        restored, _ = vector_env.reset(options=[{"initial_state": state} for state in states])
        assert not np.array_equal(swapped, restored)
        np.testing.assert_array_equal(swapped[::-1], restored)
        with pytest.raises(ValueError, match="2 dicts"):
            vector_env.reset(options=[{}])


def test_an_exception_in_a_worker_is_raised_with_its_traceback():
    vector_env = ProcessVectorEnv(TASK, 2, seed=SEED)
    vector_env.reset()
    with pytest.raises(WorkerError, match=r"(?s)worker 0 failed.*ValueError: action must have shape \(19,\)") as error:
        vector_env.step(np.zeros((2, 23)))  # The env itself checks the action shape.
    assert error.value.index == 0 and "Traceback" in error.value.detail
    _assert_all_dead(vector_env)
    with pytest.raises(RuntimeError, match="closed"):
        vector_env.step(np.zeros((2, 19)))


def test_a_worker_that_fails_to_build_is_reported_at_construction():
    config = dataclasses.replace(default_config(TASK), scenario="building_blocks/no_such_scenario")
    with pytest.raises(WorkerError, match="(?s)worker 0 failed.*no_such_scenario"):
        ProcessVectorEnv(TASK, 1, config=config, timeout=60.0)


def test_a_killed_worker_is_reported_not_hung_on():
    vector_env = ProcessVectorEnv(TASK, 2, seed=SEED, timeout=60.0)
    vector_env.reset()
    os.kill(vector_env.pids[1], signal.SIGKILL)
    start = time.monotonic()
    with pytest.raises(WorkerError, match="worker 1 failed.*SIGKILL") as error:
        vector_env.step(np.zeros((2, 19)))
    assert error.value.index == 1 and time.monotonic() - start < 10.0  # Seen via the sentinel, not the timeout.
    _assert_all_dead(vector_env)


def test_a_stalled_worker_times_out_and_is_killed_on_close():
    vector_env = ProcessVectorEnv(TASK, 2, seed=SEED, timeout=60.0)
    vector_env.reset()
    vector_env.timeout = 1.5
    os.kill(vector_env.pids[0], signal.SIGSTOP)  # Alive but never answers.
    start = time.monotonic()
    with pytest.raises(WorkerError, match=r"worker 0 failed: no answer within 1.5 s \(process alive: True\)"):
        vector_env.step(np.zeros((2, 19)))
    assert time.monotonic() - start < 10.0
    _assert_all_dead(vector_env)


def test_close_is_idempotent_and_usable_as_a_context_manager():
    with ProcessVectorEnv(TASK, 1, seed=SEED) as vector_env:
        assert len(vector_env) == 1
        vector_env.close()
        _assert_all_dead(vector_env)
        vector_env.close()
    vector_env.close()
    with pytest.raises(RuntimeError, match="closed"):
        vector_env.reset()
    with pytest.raises(ValueError, match="num_envs"):
        ProcessVectorEnv(TASK, 0)
    with pytest.raises(ValueError, match="valid tasks: search"):
        ProcessVectorEnv("dance", 1)


def test_several_envs_per_worker_reproduce_the_serial_envs_and_restart_together():
    config = dataclasses.replace(default_config(TASK), episode_length=4)  # One autoreset per env in 6 steps.
    actions = _actions(6, 3)
    with ProcessVectorEnv(TASK, 3, seed=SEED, config=config, envs_per_worker=2, max_restarts=2,
                          timeout=120.0) as vector_env:
        assert vector_env.num_workers == 2 and len(set(vector_env.pids)) == 2
        assert vector_env.pids[0] == vector_env.pids[1] != vector_env.pids[2]
        rollout = [(vector_env.reset()[0], None, None, None)]
        for action in actions:
            rollout.append(vector_env.step(action)[:4])
        _assert_matches_serial(rollout, config, actions)
        # Killing the process of envs 0 and 1 loses both episodes; both restart in one new process.
        old_pids = vector_env.pids
        os.kill(old_pids[0], signal.SIGKILL)
        after, rewards, terminated, truncated, infos = vector_env.step(np.zeros((3, 19)))
        assert truncated.tolist() == [True, True, False] and rewards[:2].tolist() == [0.0, 0.0]
        assert infos[0]["worker_restarted"] and infos[1]["worker_restarted"] and "worker_restarted" not in infos[2]
        assert vector_env.restarts == [1, 1, 0] and vector_env.lost_episodes == 2
        pids = vector_env.pids
        assert pids[0] == pids[1] != old_pids[0] and pids[2] == old_pids[2]
        serial = make_env(TASK, config)
        np.testing.assert_array_equal(after[1], serial.reset(seed=SEED + 1 + 3 * 1)[0])
        vector_env.step(np.zeros((3, 19)))


def test_an_env_that_raises_is_named_and_its_process_mates_are_not_blamed():
    vector_env = ProcessVectorEnv(TASK, 2, seed=SEED, envs_per_worker=2)
    vector_env.reset()
    with pytest.raises(WorkerError, match=r"(?s)worker 1 failed.*initial_state") as error:
        vector_env.reset(options=[None, {"initial_state": "not a state"}])
    assert error.value.index == 1
    _assert_all_dead(vector_env)
    with pytest.raises(ValueError, match="envs_per_worker"):
        ProcessVectorEnv(TASK, 2, envs_per_worker=0)


def test_the_default_layout_is_one_process_per_core(monkeypatch):
    from seqdex_drake.envs.vector import default_envs_per_worker

    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1})  # A 2-core machine.
    assert [default_envs_per_worker(n) for n in (1, 2, 3, 16)] == [1, 1, 2, 8]
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: set(range(16)))
    assert [default_envs_per_worker(n) for n in (2, 16, 17)] == [1, 1, 2]
    with ProcessVectorEnv(TASK, 3, seed=SEED, envs_per_worker=None) as vector_env:  # One process per core.
        assert vector_env.envs_per_worker == default_envs_per_worker(3)
