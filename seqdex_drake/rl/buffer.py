"""Rollout storage and generalized advantage estimation with correct time-limit handling.

Episode ends come in two kinds (gymnasium semantics, used by ``seqdex_drake.envs``):

- ``terminated``: the MDP ended (task failure, e.g. the object left the table). The return after it is zero, so
  the step's target is its reward alone.
- ``truncated``: the episode was cut off by a time limit or a simulator failure. The MDP did not end, so the
  step's target bootstraps from the value of the episode's final observation (``info["final_observation"]``;
  the env has already auto-reset, so the next stored observation belongs to a new episode).

Either kind stops the advantage recursion: nothing flows back across an episode boundary.
"""

from collections.abc import Iterator

import torch


def compute_gae(rewards: torch.Tensor, values: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor,
                next_values: torch.Tensor, gamma: float, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimates and value targets.

    All arguments are [T, ...] with time first (extra dims are envs).

    Args:
        rewards: reward of step t.
        values: V(s_t), the value of the observation the action was taken in.
        terminated: step t ended the episode by termination (no bootstrap).
        truncated: step t ended the episode by truncation (bootstrap from ``next_values[t]``).
        next_values: V(s_{t+1}) of the observation step t reached *in the same episode*: the next stored
            observation's value, the final observation's value for a truncated step, and the value of the
            observation after the rollout for the last step. Ignored for terminated steps.
        gamma: discount.
        lam: GAE lambda.

    Returns:
        ``(advantages, returns)`` with ``returns = advantages + values``.
    """
    rewards, values, next_values = (torch.as_tensor(x, dtype=torch.float32) for x in (rewards, values, next_values))
    terminated = torch.as_tensor(terminated, dtype=torch.bool, device=rewards.device)
    truncated = torch.as_tensor(truncated, dtype=torch.bool, device=rewards.device)
    not_terminated = (~terminated).to(rewards.dtype)
    continues = (~(terminated | truncated)).to(rewards.dtype)
    deltas = rewards + gamma * next_values * not_terminated - values
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        running = deltas[t] + gamma * lam * continues[t] * running
        advantages[t] = running
    return advantages, advantages + values


class RolloutBuffer:
    """Fixed-size storage of ``horizon`` steps of ``num_envs`` environments, time-major.

    Args:
        horizon: steps per env per rollout.
        num_envs: number of environments.
        obs_dim: size of an observation.
        action_dim: size of an action.
        critic_obs_dim: size of the critic's separate observation, or ``None`` if it reads ``obs``.
        device: torch device of the storage.
    """

    def __init__(self, horizon: int, num_envs: int, obs_dim: int, action_dim: int,
                 critic_obs_dim: int | None = None, device: str | torch.device = "cpu"):
        self.horizon, self.num_envs = horizon, num_envs
        self.device = torch.device(device)

        def zeros(*shape, dtype=torch.float32):
            return torch.zeros((horizon, num_envs, *shape), dtype=dtype, device=self.device)

        self.obs = zeros(obs_dim)
        self.critic_obs = zeros(critic_obs_dim) if critic_obs_dim is not None else None
        self.actions = zeros(action_dim)
        self.log_probs = zeros()
        self.means = zeros(action_dim)
        self.rewards = zeros()
        self.terminated = zeros(dtype=torch.bool)
        self.truncated = zeros(dtype=torch.bool)
        self.values = zeros()
        self.final_values = zeros()  # V(final observation) for truncated steps; 0 elsewhere.
        self.advantages = zeros()
        self.returns = zeros()
        # The policy's log-std while this rollout was collected (for the analytic KL of the update).
        self.policy_log_std = torch.zeros(action_dim, device=self.device)
        self.step = 0

    def reset(self, policy_log_std: torch.Tensor) -> None:
        """Starts a new rollout collected by a policy with this log-std."""
        self.step = 0
        self.policy_log_std = policy_log_std.detach().to(self.device).clone()

    @property
    def full(self) -> bool:
        return self.step == self.horizon

    def add(self, obs, actions, log_probs, means, rewards, terminated, truncated, values, final_values,
            critic_obs=None) -> None:
        """Stores one step of every env (tensors or arrays with leading dim ``num_envs``)."""
        if self.full:
            raise RuntimeError(f"rollout buffer is full ({self.horizon} steps); call reset() first")
        self._store(self.step, slice(None), obs=obs, actions=actions, log_probs=log_probs, means=means,
                    rewards=rewards, terminated=terminated, truncated=truncated, values=values,
                    final_values=final_values, critic_obs=critic_obs)
        self.step += 1

    def add_at(self, t: int, indices: list[int], obs, actions, log_probs, means, rewards, terminated, truncated,
               values, final_values) -> None:
        """Stores step ``t`` of envs ``indices`` only (leading dim ``len(indices)``), without advancing ``step``:
        a rollout whose env groups step on their own (``PPO._collect_grouped``) sets ``step`` when all are in."""
        if not 0 <= t < self.horizon:
            raise IndexError(f"step {t} is outside the rollout's {self.horizon} steps")
        self._store(t, torch.as_tensor(indices, device=self.device), obs=obs, actions=actions, log_probs=log_probs,
                    means=means, rewards=rewards, terminated=terminated, truncated=truncated, values=values,
                    final_values=final_values)

    def _store(self, t: int, rows, **values) -> None:
        """Writes each named value into row(s) ``rows`` of step ``t`` of its storage (skipping absent storage)."""
        for name, value in values.items():
            storage = getattr(self, name)
            if storage is not None:
                storage[t, rows] = torch.as_tensor(value, dtype=storage.dtype, device=self.device)

    def next_values(self, last_values: torch.Tensor) -> torch.Tensor:
        """V(s_{t+1}) within each episode: the next step's value, ``final_values`` where truncated, and
        ``last_values`` (the value of the observation after the rollout) for the last step."""
        next_values = torch.cat([self.values[1:], last_values.reshape(1, -1).to(self.values)], dim=0)
        return torch.where(self.truncated, self.final_values, next_values)

    def compute_returns(self, last_values: torch.Tensor, gamma: float, lam: float) -> None:
        """Fills ``advantages`` and ``returns`` of the full rollout."""
        if not self.full:
            raise RuntimeError(f"rollout holds {self.step} of {self.horizon} steps")
        self.advantages, self.returns = compute_gae(self.rewards, self.values, self.terminated, self.truncated,
                                                    self.next_values(last_values), gamma, lam)

    def flat(self) -> dict[str, torch.Tensor]:
        """Every per-transition field flattened to [horizon * num_envs, ...]."""
        names = ["obs", "actions", "log_probs", "means", "values", "advantages", "returns"]
        if self.critic_obs is not None:
            names.append("critic_obs")
        return {name: getattr(self, name).reshape(self.horizon * self.num_envs, *getattr(self, name).shape[2:])
                for name in names}

    def minibatches(self, num_minibatches: int, generator: torch.Generator | None = None,
                    advantages: torch.Tensor | None = None) -> Iterator[dict[str, torch.Tensor]]:
        """Yields ``num_minibatches`` disjoint random minibatches covering the rollout (a remainder is dropped).

        Args:
            num_minibatches: number of minibatches.
            generator: torch generator of the shuffle (CPU), for reproducibility.
            advantages: replaces the stored advantages (e.g. normalized ones), flattened [horizon * num_envs].
        """
        data = self.flat()
        if advantages is not None:
            data["advantages"] = advantages
        size = self.horizon * self.num_envs
        if not 1 <= num_minibatches <= size:
            raise ValueError(f"num_minibatches must be in [1, {size}], got {num_minibatches}")
        permutation = torch.randperm(size, generator=generator).to(self.device)
        minibatch_size = size // num_minibatches
        for start in range(0, minibatch_size * num_minibatches, minibatch_size):
            indices = permutation[start:start + minibatch_size]
            yield {name: value[indices] for name, value in data.items()}
