"""PPO pieces one by one (GAE, losses, normalizer, networks, config), then determinism, learning and train()."""

import dataclasses
import math

import gymnasium
import numpy as np
import pytest
import torch

from seqdex_drake.rl.buffer import RolloutBuffer, compute_gae
from seqdex_drake.rl.config import PAPER_TASK_HYPERPARAMETERS, PPOConfig
from seqdex_drake.rl.losses import (
    adaptive_learning_rate,
    bounds_loss,
    clipped_surrogate_loss,
    clipped_value_loss,
    gaussian_entropy,
    gaussian_kl,
)
from seqdex_drake.rl.networks import ActorCritic, RunningMeanStd
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv


def small_config(**overrides) -> PPOConfig:
    """Paper defaults with tiny networks and rollouts, so each test runs in about a second."""
    values = dict(actor_hidden_sizes=(32, 32), critic_hidden_sizes=(32, 32), num_envs=8, horizon=16,
                  num_minibatches=4, num_epochs=5, learning_rate=1e-3, seed=3)
    values.update(overrides)
    return PPOConfig(**values)


# ------------------------------------------------------------------------------------------------ GAE
# One env, 4 steps, gamma = lam = 0.5, values [1, 2, 3, 4], rewards all 1:
#   t=0 continues, t=1 truncated (V(final obs) = 6), t=2 terminated, t=3 continues (V(obs after rollout) = 10).
#   deltas: 1 + .5*2 - 1 = 1;  1 + .5*6 - 2 = 2;  1 - 3 = -2 (no bootstrap);  1 + .5*10 - 4 = 2.
#   advantages (gamma*lam = .25, the recursion stops at both episode ends): A3 = 2, A2 = -2, A1 = 2,
#   A0 = 1 + .25*2 = 1.5; returns = A + V = [2.5, 4, 1, 6].
REWARDS = [1.0, 1.0, 1.0, 1.0]
VALUES = [1.0, 2.0, 3.0, 4.0]
TERMINATED = [False, False, True, False]
TRUNCATED = [False, True, False, False]
EXPECTED_ADVANTAGES = [1.5, 2.0, -2.0, 2.0]
EXPECTED_RETURNS = [2.5, 4.0, 1.0, 6.0]


def test_gae_hand_computed_with_truncation_and_termination():
    next_values = [2.0, 6.0, 123.0, 10.0]  # 123: ignored, the step terminated.
    advantages, returns = compute_gae(REWARDS, VALUES, TERMINATED, TRUNCATED, next_values, gamma=0.5, lam=0.5)
    assert advantages.tolist() == pytest.approx(EXPECTED_ADVANTAGES)
    assert returns.tolist() == pytest.approx(EXPECTED_RETURNS)


def test_buffer_bootstraps_truncations_from_final_observation_values():
    buffer = RolloutBuffer(horizon=4, num_envs=1, obs_dim=2, action_dim=1)
    buffer.reset(torch.zeros(1))
    final_values = [0.0, 6.0, 0.0, 0.0]
    for t in range(4):
        buffer.add(torch.zeros(1, 2), torch.zeros(1, 1), [0.0], torch.zeros(1, 1), [REWARDS[t]], [TERMINATED[t]],
                   [TRUNCATED[t]], [VALUES[t]], [final_values[t]])
    buffer.compute_returns(torch.tensor([10.0]), gamma=0.5, lam=0.5)
    assert buffer.advantages[:, 0].tolist() == pytest.approx(EXPECTED_ADVANTAGES)
    assert buffer.returns[:, 0].tolist() == pytest.approx(EXPECTED_RETURNS)
    with pytest.raises(RuntimeError, match="full"):
        buffer.add(torch.zeros(1, 2), torch.zeros(1, 1), [0.0], torch.zeros(1, 1), [0.0], [False], [False], [0.0],
                   [0.0])


class RecordingEnv(TargetVectorEnv):
    """The toy env, remembering the final observations it reported at each step."""

    def step(self, actions):
        result = super().step(actions)
        self.finals = {i: info["final_observation"] for i, info in enumerate(result[4]) if "final_observation" in info}
        self.history.append((self.finals, result[2].copy(), result[3].copy()))
        return result


def test_collect_stores_final_observation_values_for_truncations_only():
    env = RecordingEnv(num_envs=3, episode_length=3, failure_distance=0.9, seed=1)
    env.history = []
    ppo = PPO.for_env(small_config(horizon=7), env)
    ppo.collect(env)
    buffer = ppo.buffer
    assert buffer.truncated.any() and buffer.terminated.any()  # Both kinds of episode end occur.
    for t, (finals, terminated, truncated) in enumerate(env.history):
        for i in range(env.num_envs):
            if truncated[i]:
                expected = ppo.model.value(torch.as_tensor(finals[i])[None])[0]
                assert buffer.final_values[t, i].item() == pytest.approx(expected.item(), abs=1e-6)
            else:
                assert buffer.final_values[t, i].item() == 0.0
            assert bool(buffer.terminated[t, i]) == terminated[i] and bool(buffer.truncated[t, i]) == truncated[i]


def test_collect_requires_final_observation_on_truncation():
    class NoFinalObservation(TargetVectorEnv):
        def step(self, actions):
            obs, rewards, terminated, truncated, infos = super().step(actions)
            return obs, rewards, terminated, truncated, [{} for _ in infos]

    env = NoFinalObservation(num_envs=2, episode_length=1, failure_distance=10.0)
    with pytest.raises(KeyError, match="final_observation"):
        PPO.for_env(small_config(horizon=2), env).collect(env)


# --------------------------------------------------------------------------------------------- losses
def test_clipped_surrogate_uses_the_clipped_objective_when_clipping_is_active():
    old = torch.zeros(3)
    log_probs = torch.log(torch.tensor([1.5, 0.5, 0.5]))
    advantages = torch.tensor([1.0, -1.0, 1.0])
    loss, clip_fraction = clipped_surrogate_loss(log_probs, old, advantages, clip_coef=0.2)
    # r=1.5, A=1: clipped (-1.2) is the max;  r=0.5, A=-1: clipped (0.8 > 0.5);  r=0.5, A=1: unclipped (-0.5).
    assert loss.item() == pytest.approx((-1.2 + 0.8 - 0.5) / 3)
    assert clip_fraction.item() == pytest.approx(1.0)
    loss, clip_fraction = clipped_surrogate_loss(old, old, advantages, clip_coef=0.2)  # Ratio 1: plain -A.
    assert loss.item() == pytest.approx(-advantages.mean().item()) and clip_fraction.item() == 0.0


def test_clipped_value_loss():
    values, old_values, returns = torch.tensor([1.0, 0.1]), torch.tensor([0.0, 0.0]), torch.tensor([1.0, 0.5])
    # Sample 0: unclipped 0, clipped prediction 0.2 -> 0.64.  Sample 1: within the clip, (0.1 - 0.5)^2 = 0.16.
    assert clipped_value_loss(values, old_values, returns, 0.2).item() == pytest.approx((0.64 + 0.16) / 2)
    assert clipped_value_loss(values, old_values, returns, None).item() == pytest.approx((0.0 + 0.16) / 2)


def test_gaussian_entropy_and_kl_are_analytic():
    model = ActorCritic(3, 2, (8,), (8,), init_log_std=0.0)
    with torch.no_grad():
        model.log_std.copy_(torch.tensor([-0.3, 0.7]))
    _, entropy, _, _ = model.evaluate(torch.randn(5, 3), torch.randn(5, 2))
    analytic = sum(0.5 * math.log(2 * math.pi * math.e * math.exp(2 * s)) for s in (-0.3, 0.7))
    assert entropy.tolist() == pytest.approx([analytic] * 5, rel=1e-6)
    assert gaussian_entropy(model.log_std).item() == pytest.approx(analytic, rel=1e-6)
    mean_a, mean_b = torch.randn(4, 2), torch.randn(4, 2)
    std_a, std_b = torch.tensor([0.5, 1.2]), torch.tensor([0.9, 0.4])
    reference = torch.distributions.kl_divergence(torch.distributions.Normal(mean_a, std_a),
                                                  torch.distributions.Normal(mean_b, std_b)).sum(-1)
    assert torch.allclose(gaussian_kl(mean_a, std_a.log(), mean_b, std_b.log()), reference, atol=1e-6)


def test_bounds_loss_and_adaptive_learning_rate():
    assert bounds_loss(torch.tensor([[1.5, -2.0, 0.5]]), 1.1).item() == pytest.approx(0.4**2 + 0.9**2)
    assert adaptive_learning_rate(3e-4, kl=0.05, desired_kl=0.016) == pytest.approx(2e-4)
    assert adaptive_learning_rate(3e-4, kl=0.001, desired_kl=0.016) == pytest.approx(4.5e-4)
    assert adaptive_learning_rate(3e-4, kl=0.016, desired_kl=0.016) == 3e-4
    assert adaptive_learning_rate(1e-2, kl=0.0, desired_kl=0.016) == 1e-2
    assert adaptive_learning_rate(1e-6, kl=1.0, desired_kl=0.016) == 1e-6


# ------------------------------------------------------------------------------------ model and config
def test_running_mean_std_matches_numpy_over_batches():
    rng = np.random.default_rng(0)
    batches = [rng.normal(loc=[3.0, -1.0], scale=[2.0, 0.1], size=(n, 2)) for n in (1, 7, 50, 3)]
    normalizer = RunningMeanStd(2, clip=5.0)
    assert torch.equal(normalizer(torch.tensor([[0.5, 9.0]])), torch.tensor([[0.5, 5.0]]))  # Identity, clipped.
    for batch in batches:
        normalizer.update(torch.as_tensor(batch))
    data = np.concatenate(batches)
    np.testing.assert_allclose(normalizer.mean.numpy(), data.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(normalizer.var.numpy(), data.var(axis=0), rtol=1e-12)
    assert normalizer.count.item() == len(data)
    normalized = normalizer(torch.as_tensor(data, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(normalized.mean(axis=0), 0.0, atol=1e-5)
    assert np.abs(normalizer(torch.tensor([[1e6, -1e6]])).numpy()).max() == 5.0
    assert {"obs_normalizer.mean", "obs_normalizer.var", "obs_normalizer.count"} <= set(
        ActorCritic(2, 1, (4,), (4,)).state_dict())


def test_actor_and_critic_are_separate_and_critic_input_is_optional():
    model = ActorCritic(5, 2, (16, 8), (12,), critic_obs_dim=9)
    assert not {id(p) for p in model.actor.parameters()} & {id(p) for p in model.critic.parameters()}
    assert model.critic[0].in_features == 9 and model.actor[0].in_features == 5
    assert model.value(torch.zeros(4, 5), torch.zeros(4, 9)).shape == (4,)
    with pytest.raises(ValueError, match="critic_obs"):
        model.value(torch.zeros(4, 5))
    assert ActorCritic(5, 2, (4,), (4,)).log_std.exp().tolist() == pytest.approx([0.8, 0.8])  # Paper's init noise std.


def test_config_for_task_matches_paper_tables_and_round_trips():
    assert PPOConfig().actor_hidden_sizes == (1024, 1024, 512) and PPOConfig().desired_kl == 0.016
    assert PPOConfig.for_task("grasp", horizon=4).horizon == 4  # Overrides win over the paper's values.
    grasp = PPOConfig.for_task("grasp", num_envs=4)
    assert (grasp.gamma, grasp.num_minibatches, grasp.num_epochs, grasp.horizon, grasp.num_envs) == (0.9, 8, 2, 8, 4)
    orient = PPOConfig.for_task("tool_reorient")
    assert (orient.gamma, orient.num_epochs, orient.horizon) == (0.96, 10, 20)
    assert set(PAPER_TASK_HYPERPARAMETERS) == {"search", "orient", "grasp", "insert", "tool_grasp", "tool_reorient"}
    assert PPOConfig.from_dict(grasp.to_dict()) == grasp
    with pytest.raises(ValueError, match="handoff"):
        PPOConfig.for_task("handoff")
    with pytest.raises(ValueError, match="bogus"):
        PPOConfig.from_dict({"bogus": 1})


# ------------------------------------------------------------------------------- whole-algorithm runs
def run_updates(config: PPOConfig, updates: int) -> list[dict]:
    env = TargetVectorEnv(num_envs=config.num_envs, seed=11)
    ppo = PPO.for_env(config, env)
    return [{**ppo.collect(env), **ppo.update()} for _ in range(updates)]


def test_same_seed_runs_are_identical_and_other_seeds_differ():
    first, second = run_updates(small_config(), 3), run_updates(small_config(), 3)
    assert first == second
    assert run_updates(small_config(seed=4), 3) != first


def test_ppo_learns_the_target_task():
    config = small_config(seed=0)  # Over seeds 0-7 the final/initial distance ratio is 0.23-0.46.
    env = TargetVectorEnv(num_envs=config.num_envs, seed=0)
    ppo = PPO.for_env(config, env)
    distances = []
    for _ in range(20):
        distances.append(-ppo.collect(env)["reward/distance"])
        ppo.update()
    assert distances[0] > 0.6  # The initial policy (mean ~0, std 0.8) is far from the target 0.5.
    assert np.mean(distances[-3:]) < 0.5 * distances[0]
    action = ppo.act(torch.as_tensor(env.reset()[0]), deterministic=True)[0]
    assert np.abs(action.numpy() - 0.5).max() < 0.2


def test_train_logs_checkpoints_and_stops_on_callback(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = small_config(num_envs=4, horizon=8, checkpoint_every=2, stats_window=4)
    env = TargetVectorEnv(num_envs=4)
    ppo = PPO.for_env(config, env)
    seen = []
    metrics = ppo.train(env, tmp_path, total_steps=10_000, progress=False,
                        callbacks=[lambda learner, m: seen.append(learner.num_updates) or len(seen) < 3])
    assert seen == [1, 2, 3] and ppo.global_step == 3 * 4 * 8
    assert (tmp_path / "last.pt").is_file() and (tmp_path / "best.pt").is_file()
    assert ppo.best["metric"] == "charts/success_rate"
    assert PPO.resume(tmp_path / "last.pt").num_updates == 3
    tags = set(EventAccumulator(str(tmp_path)).Reload().Tags()["scalars"])
    expected = {"charts/SPS", "charts/learning_rate", "charts/success_rate", "charts/episode_return",
                "losses/policy", "losses/value", "losses/entropy", "losses/approx_kl", "losses/clip_fraction",
                "reward/alive", "reward/distance"}
    assert expected <= tags and expected <= set(metrics)
    resumed = PPO.resume(tmp_path / "last.pt")
    resumed.train(TargetVectorEnv(num_envs=4), tmp_path, total_steps=4 * 4 * 8, progress=False)
    assert resumed.num_updates == 4 and dataclasses.asdict(resumed.config) == dataclasses.asdict(ppo.config)


def test_fixed_action_dims_are_pinned_and_left_out_of_log_probabilities(tmp_path):
    """A dim with low == high (a wrist-only task's hand) is the env's, not the policy's: its mean is the fixed value,
    it is never explored, and it adds nothing to log-probabilities or entropies; checkpoints keep the pin and a
    model saved before pins existed still loads (every dim free)."""
    env = TargetVectorEnv(num_envs=4, action_dim=3, seed=0)
    env.single_action_space = gymnasium.spaces.Box(np.array([-1, 0.25, -1], np.float32),
                                                   np.array([1, 0.25, 1], np.float32))
    ppo = PPO.for_env(small_config(), env)
    assert ppo.model.free_actions.tolist() == [True, False, True]
    obs = torch.randn(64, 3)
    actions, log_probs, means, _ = ppo.act(obs)
    assert torch.all(actions[:, 1] == 0.25) and torch.all(means[:, 1] == 0.25)
    assert actions[:, 0].std() > 0.1
    normal = torch.distributions.Normal(means, ppo.model.log_std.exp())
    expected = normal.log_prob(actions)[:, [0, 2]].sum(-1)
    torch.testing.assert_close(log_probs, expected)
    evaluated, entropy, _, _ = ppo.model.evaluate(obs, actions)
    torch.testing.assert_close(evaluated, expected)
    torch.testing.assert_close(entropy, normal.entropy()[:, [0, 2]].sum(-1))
    ppo.save(tmp_path / "pinned.pt")
    assert PPO.resume(tmp_path / "pinned.pt").model.free_actions.tolist() == [True, False, True]
    state = {k: v for k, v in ActorCritic(3, 3, (8,), (8,)).state_dict().items() if k != "action_fixed"}
    old = ActorCritic(3, 3, (8,), (8,))
    old.load_state_dict(state)
    assert bool(old.free_actions.all())
