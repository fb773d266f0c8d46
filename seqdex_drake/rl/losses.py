"""The pieces of the PPO loss and the KL-adaptive learning rate, as pure functions (each unit-tested)."""

import math

import torch


def clipped_surrogate_loss(log_probs: torch.Tensor, old_log_probs: torch.Tensor, advantages: torch.Tensor,
                           clip_coef: float) -> tuple[torch.Tensor, torch.Tensor]:
    """PPO's clipped policy loss ``mean(max(-A r, -A clip(r, 1 - eps, 1 + eps)))`` with ``r = pi / pi_old``.

    Returns:
        ``(loss, clip_fraction)``: the scalar loss and the fraction of samples with ``|r - 1| > eps``.
    """
    ratio = torch.exp(log_probs - old_log_probs)
    unclipped = -advantages * ratio
    clipped = -advantages * torch.clamp(ratio, 1.0 - clip_coef, 1.0 + clip_coef)
    clip_fraction = ((ratio - 1.0).abs() > clip_coef).float().mean()
    return torch.max(unclipped, clipped).mean(), clip_fraction


def clipped_value_loss(values: torch.Tensor, old_values: torch.Tensor, returns: torch.Tensor,
                       clip_coef: float | None) -> torch.Tensor:
    """Squared value error; with ``clip_coef`` the pessimistic ``max`` of the plain and the clipped error, where
    the clipped prediction is ``old_values + clip(values - old_values, -clip_coef, clip_coef)`` (rl_games)."""
    unclipped = (values - returns).square()
    if clip_coef is None:
        return unclipped.mean()
    clipped_values = old_values + torch.clamp(values - old_values, -clip_coef, clip_coef)
    return torch.max(unclipped, (clipped_values - returns).square()).mean()


def gaussian_kl(old_mean: torch.Tensor, old_log_std: torch.Tensor, new_mean: torch.Tensor,
                new_log_std: torch.Tensor) -> torch.Tensor:
    """KL(old || new) of diagonal Gaussians, summed over the last (action) dim: [B, A] -> [B]."""
    old_var, new_var = torch.exp(2.0 * old_log_std), torch.exp(2.0 * new_log_std)
    kl = new_log_std - old_log_std + (old_var + (old_mean - new_mean).square()) / (2.0 * new_var) - 0.5
    return kl.sum(-1)


def gaussian_entropy(log_std: torch.Tensor) -> torch.Tensor:
    """Entropy of a diagonal Gaussian, summed over the last dim: ``sum(0.5 + 0.5 log(2 pi) + log_std)``."""
    return (0.5 + 0.5 * math.log(2.0 * math.pi) + log_std).sum(-1)


def bounds_loss(means: torch.Tensor, bound: float) -> torch.Tensor:
    """rl_games' bounds loss: squared excess of the action means beyond [-bound, bound], summed over actions."""
    high = torch.clamp_min(means - bound, 0.0).square()
    low = torch.clamp_max(means + bound, 0.0).square()
    return (high + low).sum(-1).mean()


def adaptive_learning_rate(learning_rate: float, kl: float, desired_kl: float, factor: float = 1.5,
                           min_learning_rate: float = 1e-6, max_learning_rate: float = 1e-2) -> float:
    """rl_games' KL-threshold schedule: divide by ``factor`` when ``kl > 2 desired``, multiply when
    ``kl < desired / 2``, otherwise keep; clamped to [min, max]."""
    if kl > 2.0 * desired_kl:
        learning_rate /= factor
    elif kl < 0.5 * desired_kl:
        learning_rate *= factor
    return min(max(learning_rate, min_learning_rate), max_learning_rate)
