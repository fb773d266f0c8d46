"""The actor-critic model: separate actor and critic MLPs, a diagonal Gaussian policy, observation normalizers.

The observation normalizer lives INSIDE the model (registered buffers), as in rl_games: saving the model's
``state_dict`` saves the statistics too, so a deployed policy (the Drake policy LeafSystem) normalizes exactly as
in training. The critic may take a different (privileged) observation: pass ``critic_obs_dim`` and give
``critic_obs`` to :meth:`ActorCritic.value`; it then has its own normalizer.
"""

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from seqdex_drake.rl.config import PPOConfig

ACTIVATIONS = {"elu": nn.ELU, "relu": nn.ReLU, "tanh": nn.Tanh, "selu": nn.SELU}


class RunningMeanStd(nn.Module):
    """Running mean and (population) variance of a stream of batches, with normalization and clipping.

    Statistics are float64 buffers (``mean``, ``var``, ``count``) merged with the parallel-variance formula of
    Chan et al., so after any sequence of :meth:`update` calls they equal numpy's ``mean`` / ``var`` over all
    rows seen. Before the first update the normalizer is the identity (mean 0, variance 1), up to the clip.

    Args:
        shape: shape of one observation.
        clip: normalized values are clipped to [-clip, clip].
        epsilon: added to the variance under the square root.
    """

    def __init__(self, shape: int | Sequence[int], clip: float = 5.0, epsilon: float = 1e-8):
        super().__init__()
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        self.clip = clip
        self.epsilon = epsilon
        self.register_buffer("mean", torch.zeros(shape, dtype=torch.float64))
        self.register_buffer("var", torch.ones(shape, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, batch: torch.Tensor) -> None:
        """Merges the rows of ``batch`` [B, *shape] into the statistics."""
        batch = batch.reshape(-1, *self.mean.shape).to(torch.float64)
        batch_count = batch.shape[0]
        if batch_count == 0:
            return
        batch_mean = batch.mean(dim=0)
        batch_var = batch.var(dim=0, unbiased=False)
        total = self.count + batch_count
        delta = batch_mean - self.mean
        m2 = self.var * self.count + batch_var * batch_count + delta.square() * self.count * batch_count / total
        self.mean.add_(delta * batch_count / total)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """``clip((obs - mean) / sqrt(var + epsilon))`` in ``obs``'s dtype."""
        normalized = (obs - self.mean.to(obs.dtype)) / torch.sqrt(self.var.to(obs.dtype) + self.epsilon)
        return normalized.clamp(-self.clip, self.clip)


def mlp(input_dim: int, hidden_sizes: Sequence[int], output_dim: int, activation: str, output_gain: float):
    """An MLP with orthogonal initialization (gain sqrt(2) inside, ``output_gain`` on the last layer)."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; known: {sorted(ACTIVATIONS)}")
    layers, width = [], input_dim
    for hidden in hidden_sizes:
        linear = nn.Linear(width, hidden)
        nn.init.orthogonal_(linear.weight, math.sqrt(2.0))
        nn.init.zeros_(linear.bias)
        layers += [linear, ACTIVATIONS[activation]()]
        width = hidden
    output = nn.Linear(width, output_dim)
    nn.init.orthogonal_(output.weight, output_gain)
    nn.init.zeros_(output.bias)
    return nn.Sequential(*layers, output)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs; a Gaussian policy with a state-independent, learned log-std.

    Args:
        obs_dim: size of the (actor) observation vector.
        action_dim: size of the action vector.
        actor_hidden_sizes: hidden widths of the actor.
        critic_hidden_sizes: hidden widths of the critic.
        activation: a key of :data:`ACTIVATIONS`.
        init_log_std: initial value of every action's log-std.
        critic_obs_dim: size of the critic's input; ``None`` means the critic reads the actor's observation.
        normalize_observations: normalize inputs with running statistics (else the normalizers stay identity).
        observation_clip: clip range of normalized observations.
        fixed_actions: per action dim, NaN for a dim the policy chooses, or the value of a dim it does not (an
            action space whose low equals its high there, e.g. the hand of a wrist-only task). A fixed dim's mean
            is that value and it is neither explored nor counted in log-probabilities and entropies: exploring
            dims the env ignores only adds noise to the PPO ratio (16 of 19 dims for a wrist-only task).
    """

    def __init__(self, obs_dim: int, action_dim: int, actor_hidden_sizes: Sequence[int] = (1024, 1024, 512),
                 critic_hidden_sizes: Sequence[int] = (1024, 1024, 512), activation: str = "elu",
                 init_log_std: float = math.log(0.8), critic_obs_dim: int | None = None,
                 normalize_observations: bool = True, observation_clip: float = 5.0,
                 fixed_actions: Sequence[float] | None = None):
        super().__init__()
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.critic_obs_dim = obs_dim if critic_obs_dim is None else critic_obs_dim
        self.asymmetric = critic_obs_dim is not None
        self.normalize_observations = normalize_observations
        self.obs_normalizer = RunningMeanStd(obs_dim, clip=observation_clip)
        self.critic_obs_normalizer = RunningMeanStd(self.critic_obs_dim, clip=observation_clip) \
            if self.asymmetric else None
        self.actor = mlp(obs_dim, actor_hidden_sizes, action_dim, activation, output_gain=0.01)
        self.critic = mlp(self.critic_obs_dim, critic_hidden_sizes, 1, activation, output_gain=1.0)
        self.log_std = nn.Parameter(torch.full((action_dim,), float(init_log_std)))
        fixed = torch.full((action_dim,), math.nan) if fixed_actions is None else \
            torch.as_tensor(np.asarray(fixed_actions, dtype=np.float32))
        if fixed.shape != (action_dim,):
            raise ValueError(f"fixed_actions must have {action_dim} entries, got {tuple(fixed.shape)}")
        self.register_buffer("action_fixed", fixed)

    @classmethod
    def from_config(cls, obs_dim: int, action_dim: int, config: PPOConfig, critic_obs_dim: int | None = None,
                    fixed_actions: Sequence[float] | None = None) -> "ActorCritic":
        """The model that ``config`` describes."""
        return cls(obs_dim, action_dim, config.actor_hidden_sizes, config.critic_hidden_sizes, config.activation,
                   config.init_log_std, critic_obs_dim, config.normalize_observations, config.observation_clip,
                   fixed_actions)

    @property
    def free_actions(self) -> torch.Tensor:
        """[A] bool: the action dims the policy chooses (the rest are fixed, see ``fixed_actions``)."""
        return torch.isnan(self.action_fixed)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # Checkpoints written before fixed action dims existed have no ``action_fixed``: every dim was free.
        state_dict.setdefault(prefix + "action_fixed", torch.full_like(self.action_fixed, math.nan))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    # -------------------------------------------------------------------------------- normalization
    def update_normalizer(self, obs: torch.Tensor, critic_obs: torch.Tensor | None = None) -> None:
        """Merges a batch of raw observations into the running statistics (no-op if normalization is off)."""
        if not self.normalize_observations:
            return
        self.obs_normalizer.update(obs)
        if self.asymmetric:
            if critic_obs is None:
                raise ValueError("this model has a separate critic input: pass critic_obs")
            self.critic_obs_normalizer.update(critic_obs)

    def _actor_input(self, obs: torch.Tensor) -> torch.Tensor:
        return self.obs_normalizer(obs) if self.normalize_observations else obs

    def _critic_input(self, obs: torch.Tensor, critic_obs: torch.Tensor | None) -> torch.Tensor:
        if not self.asymmetric:
            return self._actor_input(obs)
        if critic_obs is None:
            raise ValueError("this model has a separate critic input: pass critic_obs")
        return self.critic_obs_normalizer(critic_obs) if self.normalize_observations else critic_obs

    # ------------------------------------------------------------------------------------- outputs
    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        """The policy's mean action for raw observations [B, obs_dim] (the deterministic deployment action)."""
        mean = self.actor(self._actor_input(obs))
        free = self.free_actions
        return mean if bool(free.all()) else torch.where(free, mean, self.action_fixed.to(mean))

    def distribution(self, obs: torch.Tensor) -> torch.distributions.Normal:
        """The diagonal Gaussian policy for raw observations [B, obs_dim]."""
        mean = self.action_mean(obs)
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))

    def value(self, obs: torch.Tensor, critic_obs: torch.Tensor | None = None) -> torch.Tensor:
        """State values [B] (``critic_obs`` is required only when the model was built with ``critic_obs_dim``)."""
        return self.critic(self._critic_input(obs, critic_obs)).squeeze(-1)

    def evaluate(self, obs: torch.Tensor, actions: torch.Tensor, critic_obs: torch.Tensor | None = None):
        """Log-probabilities [B], entropies [B], values [B] and action means [B, A] for a batch of transitions
        (log-probabilities and entropies over the free action dims)."""
        distribution, free = self.distribution(obs), self.free_actions
        return ((distribution.log_prob(actions) * free).sum(-1), (distribution.entropy() * free).sum(-1),
                self.value(obs, critic_obs), distribution.mean)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """The mean action, so that a traced or exported model is the deterministic policy."""
        return self.action_mean(obs)
