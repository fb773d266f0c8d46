"""Full-state checkpoints: exact resume, atomic writes, clear errors for missing and corrupt files."""

import os
import random

import numpy as np
import pytest
import torch

from seqdex_drake.rl import checkpoint as checkpoint_module
from seqdex_drake.rl.checkpoint import (
    CheckpointError,
    capture_rng_state,
    load_checkpoint,
    restore_rng_state,
    save_checkpoint,
)
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv


def small_config(**overrides) -> PPOConfig:
    values = dict(actor_hidden_sizes=(32, 32), critic_hidden_sizes=(32, 32), num_envs=4, horizon=8,
                  num_minibatches=2, num_epochs=3, learning_rate=1e-3, seed=5, stats_window=8)
    values.update(overrides)
    return PPOConfig(**values)


def trained_learner(updates: int = 2) -> PPO:
    env = TargetVectorEnv(num_envs=4, seed=2)
    ppo = PPO.for_env(small_config(), env)
    for _ in range(updates):
        ppo.collect(env)
        ppo.update()
    return ppo


def draw_random_numbers(ppo: PPO) -> tuple:
    """The next numbers of every generator a training run uses."""
    return (random.random(), float(np.random.random()), torch.rand(3).tolist(),
            torch.rand(3, generator=ppo.generator).tolist())


def next_update(ppo: PPO) -> dict:
    """Collect and update on a freshly built env (both learners start new episodes after the checkpoint)."""
    env = TargetVectorEnv(num_envs=4, seed=2)
    return {**ppo.collect(env), **ppo.update()}


def test_round_trip_restores_model_optimizer_counters_and_rng(tmp_path):
    original = trained_learner()
    original.best = {"metric": "charts/success_rate", "value": 0.25}
    draw_random_numbers(original)  # Move every generator away from its freshly seeded state (as env code would).
    path = original.save(tmp_path / "last.pt")
    expected_numbers = draw_random_numbers(original)
    restore_rng_state(load_checkpoint(path)["rng"], {"policy": original.generator})  # Undo the draws.

    resumed = PPO.resume(path)
    assert draw_random_numbers(resumed) == expected_numbers
    restore_rng_state(load_checkpoint(path)["rng"], {"policy": resumed.generator})

    model_state, resumed_state = original.model.state_dict(), resumed.model.state_dict()
    assert model_state.keys() == resumed_state.keys()
    for key in model_state:  # Bit-equal (``action_fixed`` holds NaN for free dims, hence equal_nan).
        torch.testing.assert_close(model_state[key], resumed_state[key], rtol=0, atol=0, equal_nan=True)
    assert resumed.model.obs_normalizer.count.item() == 2 * 4 * 8  # Normalizer buffers travelled.
    optimizer_state, resumed_optimizer = original.optimizer.state_dict(), resumed.optimizer.state_dict()
    assert optimizer_state["param_groups"] == resumed_optimizer["param_groups"]
    for key, state in optimizer_state["state"].items():
        assert all(torch.equal(state[name], resumed_optimizer["state"][key][name]) for name in state)
    assert (resumed.global_step, resumed.num_updates, resumed.stats.num_episodes, resumed.learning_rate) == (
        original.global_step, original.num_updates, original.stats.num_episodes, original.learning_rate)
    assert resumed.best == original.best and resumed.config == original.config
    assert list(resumed.stats.returns) == list(original.stats.returns)

    # The next update after loading equals the next update of the uninterrupted learner...
    uninterrupted = next_update(original)
    assert next_update(resumed) == uninterrupted
    assert resumed.num_updates == original.num_updates == 3
    # ... and a same-config learner that did not load the checkpoint does not match (the test can fail).
    assert next_update(PPO.for_env(small_config(), TargetVectorEnv(num_envs=4))) != uninterrupted


def test_rng_state_covers_numpy_generators():
    generator = np.random.default_rng(7)
    state = capture_rng_state({"env": generator})
    expected = generator.normal(size=3)
    restore_rng_state(state, {"env": generator})
    np.testing.assert_array_equal(generator.normal(size=3), expected)
    with pytest.raises(CheckpointError, match="other"):
        restore_rng_state(state, {"other": np.random.default_rng()})


def test_failed_replace_keeps_previous_checkpoint_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    path = save_checkpoint(tmp_path / "last.pt", {"step": 1, "weights": torch.ones(3)})

    def failing_replace(source, destination):
        raise OSError("simulated crash before the rename")

    monkeypatch.setattr(checkpoint_module.os, "replace", failing_replace)
    with pytest.raises(OSError, match="simulated crash"):
        save_checkpoint(path, {"step": 2, "weights": torch.zeros(3)})
    monkeypatch.undo()
    assert sorted(os.listdir(tmp_path)) == ["last.pt"]
    loaded = load_checkpoint(path)
    assert loaded["step"] == 1 and torch.equal(loaded["weights"], torch.ones(3))


def test_failure_while_writing_keeps_previous_checkpoint(tmp_path, monkeypatch):
    path = save_checkpoint(tmp_path / "last.pt", {"step": 1})
    real_save = torch.save

    def half_written_save(obj, file):
        real_save(obj, file)
        file.truncate(10)  # A partly written file, then the process "dies".
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint_module.torch, "save", half_written_save)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, {"step": 2})
    monkeypatch.undo()
    assert sorted(os.listdir(tmp_path)) == ["last.pt"] and load_checkpoint(path)["step"] == 1


def test_missing_and_corrupt_files_give_clear_errors(tmp_path):
    missing = tmp_path / "run" / "last.pt"
    with pytest.raises(FileNotFoundError, match=f"{missing}.*does not exist"):
        PPO.resume(missing)

    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00not a checkpoint at all" * 10)
    with pytest.raises(CheckpointError, match=f"{garbage} is corrupt.*delete it"):
        load_checkpoint(garbage)

    truncated = trained_learner(updates=1).save(tmp_path / "truncated.pt")
    truncated.write_bytes(truncated.read_bytes()[: truncated.stat().st_size // 2])
    with pytest.raises(CheckpointError, match="truncated.pt is corrupt"):
        PPO.resume(truncated)

    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(CheckpointError, match="not a seqdex_drake training checkpoint"):
        load_checkpoint(foreign)

    incomplete = save_checkpoint(tmp_path / "incomplete.pt", {"model": {}})
    with pytest.raises(CheckpointError, match="lacks"):
        PPO.resume(incomplete)
