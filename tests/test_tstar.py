"""The T-STAR baseline's discriminator: it separates two state distributions, its reward is in [0, 1] and
favours the positive side, the gradient penalty behaves, and its training state round-trips."""

import numpy as np
import pytest
import torch

from seqdex_drake.chaining.tstar import TStarConfig, TStarDiscriminator

DIM = 6


def gaussians(rng, count: int):
    """Next-task initial states (positive) around +1 and terminal states (negative) around -1 per axis, class
    std 0.25, offset and scaled like raw observations so the normalizer matters.

    The separation is generous on purpose: T-STAR's two-sided penalty holds ||grad D|| near 1 (in normalized
    units), so D's spread within a class is about the class's normalized std sigma and the accuracy at D = 0.5
    saturates near Phi(0.5 / sigma); here sigma ~ 0.24, a ceiling of about 0.98."""
    positive = rng.normal(1.0, 0.25, (count, DIM)) * 3.0 + 10.0
    negative = rng.normal(-1.0, 0.25, (count, DIM)) * 3.0 + 10.0
    return positive.astype(np.float32), negative.astype(np.float32)


def trained(steps: int = 300, seed: int = 0) -> tuple[TStarDiscriminator, np.random.Generator]:
    rng = np.random.default_rng(seed)
    discriminator = TStarDiscriminator(DIM, TStarConfig(seed=seed))
    discriminator.fit_normalizer(np.concatenate(gaussians(rng, 1000)))
    for _ in range(steps):
        positive, negative = gaussians(rng, 64)
        discriminator.train_step(positive, negative)
    return discriminator, rng


def test_defaults_follow_tstar():
    config = TStarConfig()
    assert config.hidden == (256, 256) and config.activation == "tanh"
    assert config.lr == 1e-4 and config.grad_penalty == 10.0
    discriminator = TStarDiscriminator(DIM, config)
    linears = [m for m in discriminator.net if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears] == [256, 256, 1]
    assert sum(isinstance(m, torch.nn.Tanh) for m in discriminator.net) == 2


def test_separates_two_gaussians_and_rewards_positives():
    discriminator, rng = trained()
    positive, negative = gaussians(rng, 2000)
    assert discriminator.accuracy(positive, negative) > 0.9
    reward_positive = discriminator.transition_reward(positive)
    reward_negative = discriminator.transition_reward(negative)
    for reward in (reward_positive, reward_negative):
        assert reward.shape == (2000,) and reward.min() >= 0.0 and reward.max() <= 1.0
    assert reward_positive.mean() > reward_negative.mean() + 0.4
    untrained = TStarDiscriminator(DIM)
    untrained.fit_normalizer(np.concatenate([positive, negative]))
    assert untrained.accuracy(positive, negative) < 0.8  # The training, not the initialization, separates them.


def test_reward_formula():
    discriminator = TStarDiscriminator(2)
    states = np.zeros((1, 2), np.float32)
    for raw, expected in ((-0.5, 0.0), (0.0, 0.0), (0.5, 0.75), (1.0, 1.0), (3.0, 1.0)):
        with torch.no_grad():
            discriminator.net[-1].weight.zero_()
            discriminator.net[-1].bias.fill_(raw)
        assert discriminator.transition_reward(states)[0] == pytest.approx(expected)


def test_gradient_penalty_and_losses():
    rng = np.random.default_rng(3)
    discriminator = TStarDiscriminator(DIM)
    positive, negative = gaussians(rng, 32)
    penalty = discriminator.gradient_penalty(positive, negative[:20])
    assert penalty.ndim == 0 and torch.isfinite(penalty) and float(penalty.detach()) > 0
    penalty.backward()  # Differentiable with respect to the weights (the penalty trains D)...
    output_bias = discriminator.net[-1].bias
    assert output_bias.grad is None  # ...except the output bias, which no input gradient depends on.
    others = [p for p in discriminator.net.parameters() if p is not output_bias]
    assert all(p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0 for p in others)
    info = discriminator.train_step(positive, negative)
    assert info["loss"] == pytest.approx(info["positive_loss"] + info["negative_loss"] + 10 * info["grad_penalty"])
    assert all(np.isfinite(value) for value in info.values())
    with pytest.raises(ValueError, match=f"\\(batch, {DIM}\\)"):
        discriminator.train_step(positive[:, :3], negative)


def test_training_state_round_trip_continues_identically():
    first, rng = trained(steps=20, seed=1)
    state = first.training_state()
    second = TStarDiscriminator.from_training_state(state)
    positive, negative = gaussians(rng, 64)
    info_first = first.train_step(positive, negative)
    info_second = second.train_step(positive, negative)
    assert info_first == info_second
    np.testing.assert_array_equal(first.transition_reward(positive), second.transition_reward(positive))
