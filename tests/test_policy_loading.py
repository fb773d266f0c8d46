"""``seqdex_drake.load_policy`` (a trained policy as a numpy callable) and ``seqdex rollout`` (its evaluation on any
sub-task, a chain's last one included), on a tiny lower policy from ``seqdex train --test``."""

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import seqdex_drake
from seqdex_drake.cli.main import main
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.rl.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from seqdex_drake.rl.policy_loading import Policy, load_policy
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.run_config import TEST_EPISODE_LENGTH, task_config

pytestmark = pytest.mark.filterwarnings("ignore:.*maximum and minimum values are equal")


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """``last.pt`` of ``seqdex train --task lower --test`` (two envs, one update: the normalizer has statistics)."""
    run_dir = tmp_path_factory.mktemp("policy") / "lower"
    assert main(["train", "--task", "lower", "--test", "--run-dir", str(run_dir), "--num-envs", "2"]) == 0
    return run_dir / "last.pt"


@pytest.fixture(scope="module")
def observations():
    """Observations of the lower env (a few steps of two episodes), (n, 159)."""
    env = make_env("lower")
    rows = []
    for seed in (0, 1):
        rows.append(env.reset(seed=seed)[0])
        rows += [env.step(np.r_[np.zeros(16), 0.5, -0.5, -1.0])[0] for _ in range(3)]
    return np.stack(rows)


def test_load_policy_is_the_trained_deterministic_policy(checkpoint, observations):
    assert seqdex_drake.load_policy is load_policy and seqdex_drake.Policy is Policy  # The lazy re-export.
    rng_before = torch.get_rng_state()
    policy = load_policy(checkpoint)
    assert (policy.task, policy.obs_dim, policy.action_dim, policy.deterministic) == ("lower", 159, 19, True)
    assert policy.obs_spec.dim == 159 and policy.obs_spec.description.startswith("lower:")
    np.testing.assert_array_equal(policy.action_low, [0.0] * 16 + [-1.0] * 3)
    np.testing.assert_array_equal(policy.action_high, [0.0] * 16 + [1.0] * 3)
    assert "task='lower'" in repr(policy)
    actions = policy(observations)
    assert actions.shape == (len(observations), 19) and actions.dtype == np.float32
    # What training's learner does (normalizer inside the model), deterministic and clipped to the bounds.
    ppo = PPO.resume(checkpoint)
    expected = ppo.act(torch.as_tensor(observations, dtype=torch.float32), deterministic=True)[0].numpy()
    np.testing.assert_allclose(actions, np.clip(expected, ppo.action_low.numpy(), ppo.action_high.numpy()),
                               rtol=1e-6, atol=1e-7)
    assert policy.model.obs_normalizer.count > 0
    with torch.no_grad():
        raw = policy.model.actor(torch.as_tensor(observations, dtype=torch.float32)).numpy()
    assert not np.allclose(raw[:, 16:], actions[:, 16:])  # The observations are normalized before the actor.
    assert not actions[:, :16].any()  # The wrist-only task's hand dims stay at their fixed 0.
    # Same answer every call (to float32 rounding between batch sizes); the caller's torch RNG untouched.
    np.testing.assert_array_equal(policy(observations), actions)
    single = policy(observations[3])
    assert single.shape == (19,)
    np.testing.assert_allclose(single, actions[3], rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(policy(observations[3].astype(np.float64).tolist()), single)
    assert torch.equal(torch.get_rng_state(), rng_before)


def test_stochastic_policy_is_seeded_and_within_bounds(checkpoint, observations):
    mean = load_policy(checkpoint)(observations)
    first, second = (load_policy(checkpoint, deterministic=False, seed=3) for _ in range(2))
    samples = first(observations)
    np.testing.assert_array_equal(samples, second(observations))
    assert not np.allclose(samples, mean) and not samples[:, :16].any()
    assert (samples >= first.action_low).all() and (samples <= first.action_high).all()
    assert not np.array_equal(first(observations), samples)  # The generator moves on.


def test_actions_are_clipped_to_the_bounds(checkpoint, observations):
    policy = load_policy(checkpoint)
    with torch.no_grad():
        policy.model.actor[-1].weight.mul_(1e4)  # Means far outside [-1, 1].
        means = policy.model.action_mean(torch.as_tensor(observations, dtype=torch.float32)).numpy()
    assert np.abs(means[:, 16:]).max() > 1.0
    actions = policy(observations)
    np.testing.assert_array_equal(actions, np.clip(means, -1.0, 1.0) * np.r_[np.zeros(16), np.ones(3)])


def test_observation_and_task_mismatches_are_clear_errors(checkpoint):
    policy = load_policy(checkpoint)
    for bad in (np.zeros(158), np.zeros((2, 3, 159)), np.zeros((4, 160))):
        with pytest.raises(ValueError, match=r"the lower policy .* reads \(159,\) or \(n, 159\)"):
            policy(bad)
    with pytest.raises(ValueError, match="numeric"):
        policy(np.array(["a"] * 159))
    with pytest.raises(ValueError, match="'reach'"):
        load_policy(checkpoint, task="reach")  # Same size, another task's observations.
    with pytest.raises(ValueError, match="valid tasks"):
        load_policy(checkpoint, task="juggle")
    assert load_policy(checkpoint, task="lower").task == "lower"


def test_unusable_files_are_clear_errors(checkpoint, tmp_path):
    missing = tmp_path / "nothing.pt"
    with pytest.raises(FileNotFoundError, match="nothing.pt does not exist"):
        load_policy(missing)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(checkpoint.read_bytes()[: checkpoint.stat().st_size // 2])
    garbage = tmp_path / "notes.pt"
    garbage.write_text("not a checkpoint\n")
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    for path, text in ((truncated, "corrupt or unreadable"), (garbage, "corrupt or unreadable"),
                       (foreign, "not a seqdex_drake training checkpoint")):
        with pytest.raises(CheckpointError, match=text) as error:
            load_policy(path)
        assert str(path) in str(error.value)
    state = load_checkpoint(checkpoint)
    state.pop("format"), state.pop("version")
    no_model = tmp_path / "no_model.pt"
    save_checkpoint(no_model, {key: value for key, value in state.items() if key != "model"})
    with pytest.raises(CheckpointError, match=r"lacks \['model'\]"):
        load_policy(no_model)
    resized = tmp_path / "resized.pt"
    save_checkpoint(resized, {**state, "config": {**state["config"], "actor_hidden_sizes": [32]}})
    with pytest.raises(CheckpointError, match="do not fit"):
        load_policy(resized)


def test_policy_drives_the_gym_env(checkpoint):
    policy, env = load_policy(checkpoint), gym.make("seqdex/Lower-v0")
    observation, _ = env.reset(seed=2)
    steps, done = 0, False
    while not done:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        steps, done = steps + 1, terminated or truncated
    assert truncated and steps == 15 and not info["simulator_error"]


def _rollout(checkpoint, out, *extra):
    return main(["rollout", "--task", "lower", "--checkpoint", str(checkpoint), "--test", "--out", str(out),
                 *extra])


def test_rollout_on_a_chain_last_task(checkpoint, tmp_path, capsys):
    out = tmp_path / "results" / "lower.json"
    assert _rollout(checkpoint, out, "--episodes", "3", "--seed", "4") == 0
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert (result["task"], result["episodes"], result["seed"], result["test"]) == ("lower", 3, 4, True)
    episodes = result["per_episode"]
    assert [episode["seed"] for episode in episodes] == [4, 5, 6]
    assert all(episode["length"] == TEST_EPISODE_LENGTH or episode["terminated"] for episode in episodes)
    assert result["success_rate"] == sum(episode["success"] for episode in episodes) / 3
    assert result["mean_return"] == pytest.approx(np.mean([episode["return"] for episode in episodes]))
    assert f"success rate {result['success_rate']:.3f}" in printed and f"{result['mean_return']:.3f}" in printed
    # The first episode is the loaded policy's deterministic episode from reset(seed=4).
    policy, env = load_policy(checkpoint), make_env("lower", task_config("lower", True))
    observation, _ = env.reset(seed=4)
    total, done = 0.0, False
    while not done:
        observation, reward, terminated, truncated, _ = env.step(policy(observation))
        total, done = total + reward, terminated or truncated
    assert episodes[0]["return"] == pytest.approx(total, rel=1e-12)
    # Deterministic: the same command gives the same episodes.
    again = tmp_path / "again.json"
    assert _rollout(checkpoint, again, "--episodes", "3", "--seed", "4") == 0
    assert json.loads(again.read_text())["per_episode"] == episodes


def test_rollout_uses_the_runs_task_variant(checkpoint, tmp_path):
    record = json.loads((checkpoint.parent / "config.json").read_text())
    out = tmp_path / "recorded.json"
    assert _rollout(checkpoint, out, "--episodes", "1") == 0
    assert json.loads(out.read_text())["preset"] == record.get("preset", "paper")
    assert _rollout(checkpoint, out, "--episodes", "1", "--preset", "paper") == 0
    assert json.loads(out.read_text())["preset"] == "paper"
    alone = tmp_path / "alone" / "policy.pt"  # The record beside the checkpoint decides; without one: paper.
    alone.parent.mkdir()
    alone.write_bytes(checkpoint.read_bytes())
    (alone.parent / "config.json").write_text('{"preset": "budget"}')
    assert _rollout(alone, out, "--episodes", "1") == 0
    assert json.loads(out.read_text())["preset"] == "budget"
    (alone.parent / "config.json").unlink()
    assert _rollout(alone, out, "--episodes", "1") == 0
    assert json.loads(out.read_text())["preset"] == "paper"


@pytest.mark.parametrize("case", ["out_is_a_directory", "out_under_a_file", "missing_checkpoint", "other_task",
                                  "no_episodes"])
def test_rollout_bad_input_fails_before_rolling_out(checkpoint, tmp_path, capsys, case):
    (tmp_path / "file.txt").write_text("x")
    argv = ["rollout", "--task", "lower", "--checkpoint", str(checkpoint), "--test"]
    argv, text = {
        "out_is_a_directory": (argv + ["--out", str(tmp_path)], "is a directory"),
        "out_under_a_file": (argv + ["--out", str(tmp_path / "file.txt" / "r.json")], "not a directory"),
        "missing_checkpoint": (["rollout", "--task", "lower", "--checkpoint", str(tmp_path / "x.pt")],
                               "x.pt does not exist"),
        "other_task": (["rollout", "--task", "reach", "--checkpoint", str(checkpoint), "--test"], "the reach env"),
        "no_episodes": (argv + ["--episodes", "0"], "--episodes must be >= 1"),
    }[case]
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert text in captured.err and "Traceback" not in captured.err
    assert "success rate" not in captured.out
