"""Proximal Policy Optimization, readable top to bottom (CleanRL's ppo_continuous_action) but importable.

One iteration = :meth:`PPO.collect` (``horizon`` steps of every env into a :class:`RolloutBuffer`) then
:meth:`PPO.update` (GAE, ``num_epochs`` passes of ``num_minibatches`` minibatches with the clipped surrogate,
clipped value loss, entropy and bounds terms, gradient clipping and the KL-adaptive learning rate).
:meth:`PPO.train` loops, logs to TensorBoard and writes ``last.pt`` / ``best.pt`` full-state checkpoints.

Vector env API (``seqdex_drake.envs.vector.ProcessVectorEnv``, ``seqdex_drake.rl.toy_env.TargetVectorEnv``):
``reset(seed=...) -> (obs[n, d], infos)``, ``step(actions[n, a]) -> obs, rewards, terminated, truncated, infos``
with automatic reset; a finished episode's last observation is ``info["final_observation"]``. A vector env
that also has ``step_groups`` / ``step_async`` / ``step_wait`` (``ProcessVectorEnv``) is stepped group by group
(``PPOConfig.grouped_rollouts``): each worker's envs go on as soon as the policy has acted on them.

Observation normalization: the statistics stay fixed during a rollout and its update (so the update's first
probability ratios are exactly 1) and absorb the rollout's observations after the gradient steps.
The critic reads the actor's observation; the model's ``critic_obs_dim`` hook is not fed by ``collect`` yet.

Non-finite values never reach the buffer: a NaN / inf observation, final observation or reward from the env
(sub-task envs already turn simulator failures into truncations with finite observations) is replaced by 0 and
counted (``nonfinite_values``, logged as ``charts/nonfinite_env_values``).

Exact resume: if the vector env has ``state_dict()`` / ``load_state_dict()`` (the toy env does; Drake vector envs
do not, their simulator state is not captured), checkpoints also hold its state, the observation the policy acts
on next and the running episode sums, and :meth:`PPO.train` on a resumed learner restores them into the env it is
given, so a killed and resumed run continues exactly as an uninterrupted one. Otherwise the resumed run starts
fresh episodes (seeded by the config seed and the step count).
"""

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.rl.buffer import RolloutBuffer
from seqdex_drake.rl.checkpoint import capture_rng_state, load_checkpoint, restore_rng_state, save_checkpoint
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.demonstrations import demo_loss
from seqdex_drake.rl.episode_stats import EpisodeStats
from seqdex_drake.rl.losses import (
    adaptive_learning_rate,
    bounds_loss,
    clipped_surrogate_loss,
    clipped_value_loss,
    gaussian_kl,
)
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.rl.seeding import seed_everything
from seqdex_drake.rl.training_loop import run_training

#: ``callback(ppo, metrics)`` after every update; returning ``False`` stops training.
Callback = Callable[["PPO", dict[str, float]], bool | None]

CHECKPOINT_KEYS = ("model", "optimizer", "counters", "config", "dims", "rng", "best", "stats")


class PPO:
    """The PPO learner: model, optimizer, rollout buffer, counters and RNG of one training run.

    Constructing it seeds everything with ``config.seed`` (as SB3 does), so two learners with the same config
    and env produce identical runs.

    Args:
        config: the hyperparameters.
        obs_dim: size of the observation vector.
        action_dim: size of the action vector.
        action_low, action_high: action bounds; sampled actions are clipped to them before stepping the env when
            ``config.clip_actions`` (the buffer keeps the unclipped sample for the log-probability).
    """

    def __init__(self, config: PPOConfig, obs_dim: int, action_dim: int,
                 action_low: Sequence[float] | None = None, action_high: Sequence[float] | None = None):
        self.config = config
        seed_everything(config.seed)
        self.device = torch.device(config.device)
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.action_low = None if action_low is None else torch.as_tensor(action_low, dtype=torch.float32)
        self.action_high = None if action_high is None else torch.as_tensor(action_high, dtype=torch.float32)
        fixed = None
        if action_low is not None and action_high is not None:  # Dims with low == high are not the policy's.
            low, high = np.asarray(action_low, dtype=np.float32), np.asarray(action_high, dtype=np.float32)
            fixed = np.where(low == high, low, np.nan)
        self.model = ActorCritic.from_config(obs_dim, action_dim, config, fixed_actions=fixed).to(self.device)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.learning_rate)
        self.generator = torch.Generator().manual_seed(config.seed)  # Action noise and minibatch shuffles.
        self.learning_rate = config.learning_rate
        self.global_step = 0
        self.num_updates = 0
        self.best = {"metric": None, "value": -math.inf}
        self.stats = EpisodeStats(config.num_envs, config.stats_window)
        self.buffer: RolloutBuffer | None = None
        self._env = None
        self._next_obs: torch.Tensor | None = None
        self._saved_env_state: dict | None = None  # From a checkpoint; train() restores it into its env.
        self.nonfinite_values = 0
        """Non-finite observation / reward entries from the env replaced by 0 so far."""
        self.demos = None
        """Demonstrations for the DAPG term (``rl.demonstrations.Demonstrations``; with ``config.demo_coef``)."""
        self.obs_spec: dict | None = None
        """What the policy reads (an ObservationSpec as a dict), recorded by whoever builds the learner for a task
        and checked by the commands that load a checkpoint for a task; None when not recorded."""

    @classmethod
    def for_env(cls, config: PPOConfig, vec_env) -> "PPO":
        """A learner sized for ``vec_env`` (its spaces, and ``num_envs`` taken from the env)."""
        config = dataclasses.replace(config, num_envs=len(vec_env))
        action_space = vec_env.single_action_space
        bounded = np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))
        return cls(config, int(np.prod(vec_env.single_observation_space.shape)), int(np.prod(action_space.shape)),
                   action_space.low if bounded else None, action_space.high if bounded else None)

    # ------------------------------------------------------------------------------------------ acting
    def _tensor(self, array) -> torch.Tensor:
        return torch.as_tensor(np.asarray(array), dtype=torch.float32, device=self.device)

    def _finite(self, array) -> np.ndarray:
        """``array`` with NaN / inf entries replaced by 0 (and counted in ``nonfinite_values``)."""
        array = np.asarray(array)
        bad = ~np.isfinite(array)
        if bad.any():
            self.nonfinite_values += int(bad.sum())
            array = np.where(bad, 0.0, array).astype(array.dtype)
        return array

    @torch.no_grad()
    def act(self, obs: torch.Tensor, deterministic: bool = False, noise: torch.Tensor | None = None):
        """Actions [n, a] (sampled, or the mean), their log-probabilities [n], the means [n, a], values [n].
        ``noise``: the standard normal draws [n, a] to sample with (default: drawn now from the generator)."""
        means = self.model.action_mean(obs)
        std, free = self.model.log_std.exp(), self.model.free_actions
        if deterministic:
            actions = means
        else:
            if noise is None:
                noise = torch.randn(means.shape, generator=self.generator)
            noise = noise.to(self.device)
            actions = means + std * noise * free  # Fixed dims stay at their value (see ActorCritic).
        log_probs = (torch.distributions.Normal(means, std).log_prob(actions) * free).sum(-1)
        return actions, log_probs, means, self.model.value(obs)

    def _env_actions(self, actions: torch.Tensor) -> np.ndarray:
        if self.config.clip_actions and self.action_low is not None:
            actions = torch.clamp(actions, self.action_low.to(actions), self.action_high.to(actions))
        return actions.cpu().numpy()

    def _attach(self, vec_env) -> None:
        """Starts fresh episodes on ``vec_env`` (seeded by the config seed and the step count)."""
        result = vec_env.reset(seed=self.config.seed + self.global_step)
        obs = result[0] if isinstance(result, tuple) else result
        self._env, self._next_obs = vec_env, self._tensor(self._finite(obs))
        self.stats.reset_envs(len(obs))

    # ----------------------------------------------------------------------------------------- rollout
    def collect(self, vec_env, steps: int | None = None) -> dict[str, float]:
        """Steps every env ``steps`` times (default ``config.horizon``) with the current policy into the buffer.

        A new ``vec_env`` (or the first call, or the first after :meth:`resume`) is reset first.

        Returns:
            ``reward/<term>`` means per env step over this rollout and ``charts/rollout_*`` episode figures.
        """
        steps = steps or self.config.horizon
        if vec_env is not self._env:
            self._attach(vec_env)
        num_envs = self._next_obs.shape[0]
        if self.buffer is None or (self.buffer.horizon, self.buffer.num_envs) != (steps, num_envs):
            self.buffer = RolloutBuffer(steps, num_envs, self.obs_dim, self.action_dim, device=self.device)
        self.buffer.reset(self.model.log_std)
        self._next_obs = self._next_obs.clone()  # Updated in place below, env by env.
        groups = getattr(vec_env, "step_groups", None) if hasattr(vec_env, "step_async") else None
        if self.config.grouped_rollouts and groups is not None and len(groups) > 1:
            self._collect_grouped(vec_env, steps, groups)
        else:
            for _ in range(steps):
                obs = self._next_obs
                actions, log_probs, means, values = self.act(obs)
                results = vec_env.step(self._env_actions(actions))
                self._record(range(num_envs), self.buffer.step, obs, actions, log_probs, means, values, results)
                self.buffer.step += 1
        self.global_step += num_envs * steps
        metrics = self.stats.rollout_metrics()
        metrics["charts/nonfinite_env_values"] = float(self.nonfinite_values)
        if hasattr(vec_env, "lost_episodes"):  # Episodes cut short by a restarted worker (envs.vector_base).
            metrics["charts/lost_episodes"] = float(vec_env.lost_episodes)
        return metrics

    def _collect_grouped(self, vec_env, steps: int, groups: list[list[int]]) -> None:
        """The rollout with each step group (worker) stepping on its own: the policy acts on a group's
        observations as soon as they arrive and sends it its next step. The action noise of the whole rollout
        is drawn up front and the episode bookkeeping replayed in (step, group) order, so the rollout does not
        depend on the order in which the groups arrive."""
        noise = torch.randn((steps, self._next_obs.shape[0], self.action_dim), generator=self.generator)
        progress, acted, records = [0] * len(groups), {}, []

        def launch(group: int) -> None:
            index = torch.as_tensor(groups[group])
            obs = self._next_obs[index.to(self.device)]
            acted[group] = (obs, *self.act(obs, noise=noise[progress[group], index]))
            vec_env.step_async(group, self._env_actions(acted[group][1]))

        for group in range(len(groups)):
            launch(group)
        while acted:
            group, results = vec_env.step_wait()
            t = progress[group]
            records.append((t, group, self._record(groups[group], t, *acted.pop(group), results, stats=False)))
            progress[group] += 1
            if progress[group] < steps:
                launch(group)
        self.buffer.step = steps
        for _, group, step in sorted(records, key=lambda record: record[:2]):
            self.stats.record_step(*step, indices=groups[group])

    def _record(self, indices, t: int, obs, actions, log_probs, means, values, results, stats: bool = True) -> tuple:
        """Stores the step ``t`` of envs ``indices`` (the policy's side and the env's ``results``) in the buffer,
        sets their next observations and, with ``stats``, accounts the step in the episode statistics. Returns
        what the statistics take: (rewards made finite, terminated, truncated, infos)."""
        next_obs, rewards, terminated, truncated, infos = results
        next_obs, rewards = self._finite(next_obs), self._finite(np.asarray(rewards, dtype=np.float64))
        terminated, truncated = np.asarray(terminated, dtype=bool), np.asarray(truncated, dtype=bool)
        final_values = torch.zeros(len(indices), device=self.device)
        bootstrap = np.flatnonzero(truncated & ~terminated)
        if len(bootstrap):
            if any("final_observation" not in infos[i] for i in bootstrap):
                raise KeyError("a truncated episode's info lacks 'final_observation'; the vector env must "
                               "autoreset SB3-style (see seqdex_drake.envs.vector)")
            final_obs = self._tensor(self._finite(np.stack([infos[i]["final_observation"] for i in bootstrap])))
            with torch.no_grad():
                final_values[torch.as_tensor(bootstrap, device=self.device)] = self.model.value(final_obs)
        scaled = rewards if self.config.reward_scale == 1.0 else rewards * self.config.reward_scale
        self.buffer.add_at(t, list(indices), obs, actions, log_probs, means, scaled, terminated, truncated, values,
                           final_values)
        if stats:
            self.stats.record_step(rewards, terminated, truncated, infos)
        self._next_obs[torch.as_tensor(list(indices), device=self.device)] = self._tensor(next_obs)
        return rewards, terminated, truncated, infos

    # ------------------------------------------------------------------------------------------ update
    def _set_learning_rate(self, learning_rate: float) -> None:
        self.learning_rate = learning_rate
        for group in self.optimizer.param_groups:
            group["lr"] = learning_rate

    def update(self) -> dict[str, float]:
        """One PPO update on the collected rollout; returns the ``losses/*`` means and ``charts/learning_rate``."""
        config, buffer, model = self.config, self.buffer, self.model
        if buffer is None or not buffer.full:
            raise RuntimeError("update() needs a full rollout: call collect() first")
        with torch.no_grad():
            buffer.compute_returns(model.value(self._next_obs), config.gamma, config.gae_lambda)
        advantages = buffer.advantages.reshape(-1)
        if config.normalize_advantages and advantages.numel() > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        sums = dict.fromkeys(("policy", "value", "entropy", "bounds", "approx_kl", "clip_fraction", "demo_nll"), 0.0)
        demo_weight = self.demo_weight()
        count = 0
        for _ in range(config.num_epochs):
            for batch in buffer.minibatches(config.num_minibatches, self.generator, advantages):
                log_probs, entropy, values, means = model.evaluate(batch["obs"], batch["actions"])
                policy_loss, clip_fraction = clipped_surrogate_loss(log_probs, batch["log_probs"],
                                                                    batch["advantages"], config.clip_coef)
                value_loss = clipped_value_loss(values, batch["values"], batch["returns"],
                                                config.value_clip_coef if config.clip_value_loss else None)
                entropy = entropy.mean()
                bound_loss = bounds_loss(means, config.bounds_loss_bound)
                loss = (policy_loss + config.value_coef * value_loss - config.entropy_coef * entropy
                        + config.bounds_loss_coef * bound_loss)
                if demo_weight > 0.0:  # DAPG: the demonstrations' NLL, weight lambda0 * lambda1^k.
                    demo = demo_loss(model, self.demos, len(batch["obs"]), self.generator)
                    loss = loss + demo_weight * demo
                    sums["demo_nll"] += demo.item()
                with torch.no_grad():
                    kl = gaussian_kl(batch["means"], buffer.policy_log_std, means, model.log_std).mean().item()
                if config.adaptive_lr:  # Before the step, as in the release: the KL of the pre-step policy.
                    self._set_learning_rate(adaptive_learning_rate(
                        self.learning_rate, kl, config.desired_kl, config.lr_factor, config.min_learning_rate,
                        config.max_learning_rate))
                self.optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), config.max_grad_norm)
                self.optimizer.step()
                for key, value in (("policy", policy_loss), ("value", value_loss), ("entropy", entropy),
                                   ("bounds", bound_loss), ("approx_kl", kl), ("clip_fraction", clip_fraction)):
                    sums[key] += value.item() if torch.is_tensor(value) else value
                count += 1
        model.update_normalizer(buffer.obs.reshape(-1, self.obs_dim))
        self.num_updates += 1
        returns, values = buffer.returns.reshape(-1), buffer.values.reshape(-1)
        explained = 1.0 - (returns - values).var() / returns.var() if returns.var() > 0 else torch.tensor(math.nan)
        metrics = {f"losses/{key}": value / count for key, value in sums.items()}
        metrics["losses/demo_weight"] = demo_weight
        metrics.update({"losses/explained_variance": float(explained), "charts/learning_rate": self.learning_rate,
                        "charts/log_std": model.log_std.mean().item()})
        return metrics

    def demo_weight(self) -> float:
        """The DAPG weight of the next update: ``demo_coef * demo_decay ** num_updates`` (0 without demos)."""
        if self.demos is None or self.config.demo_coef <= 0.0:
            return 0.0
        return self.config.demo_coef * self.config.demo_decay ** self.num_updates

    # ------------------------------------------------------------------------------------------- train
    def train(self, vec_env, run_dir: str | Path, total_steps: int | None = None,
              callbacks: Sequence[Callback] = (), progress: bool = True, stop=None) -> dict[str, float]:
        """Collects and updates until ``global_step >= total_steps`` (default ``config.total_steps``).

        Logs every update's metrics to TensorBoard in ``run_dir`` (``charts/``, ``losses/``, ``reward/<term>``,
        ``charts/SPS``), writes ``run_dir/last.pt`` every ``config.checkpoint_every`` updates, after an update that
        ends ``config.checkpoint_seconds`` or more after the last write, and at the end, and ``run_dir/best.pt``
        whenever the windowed success rate (mean return if the env reports no ``success``) beats the best so far.
        Returns the last update's metrics (before any update: the episode window, a resumed run's saved one).

        SIGINT and SIGTERM stop the run cleanly: the update in progress finishes and ``last.pt`` is written. With
        ``stop``, a caller's :class:`~seqdex_drake.rl.stop_signals.StopSignals` (already installed), the method then
        returns and ``stop.received`` names the signal. Without, handlers are installed for the call only and the
        signal goes on to the previous ones once ``last.pt`` is saved (SIGINT: ``KeyboardInterrupt`` as before, so a
        caller that trains in phases stops too; SIGTERM: exit). A second signal raises ``KeyboardInterrupt`` at once.
        If the rollout in progress fails once a stop was requested (a terminal's Ctrl-C also reaches the env worker
        processes, which exit), ``last.pt`` holds the learner as the last update left it, without an env state (a
        resume starts fresh episodes).
        """
        return run_training(self, vec_env, run_dir, total_steps, callbacks, progress, stop)

    # ------------------------------------------------------------------------------------- checkpoints
    def _env_state(self) -> dict | None:
        """The attached env's state, the next observation and the running episode sums, if the env has a
        ``state_dict()``; else None."""
        if self._env is None or self._next_obs is None or not callable(getattr(self._env, "state_dict", None)):
            return None
        return {"vec_env": self._env.state_dict(), "next_obs": self._next_obs.cpu().clone(),
                "running_return": self.stats._running_return.tolist(),
                "running_length": self.stats._running_length.tolist()}

    def _restore_env(self, vec_env, saved: dict) -> None:
        """Puts ``vec_env`` and the learner back where the checkpoint left them (or leaves ``vec_env`` to be
        reset by :meth:`collect` if it cannot load a state)."""
        self._saved_env_state = None
        if not callable(getattr(vec_env, "load_state_dict", None)):
            return
        if len(vec_env) != len(saved["next_obs"]):
            raise ValueError(f"the checkpoint was written with {len(saved['next_obs'])} envs, the vector env "
                             f"has {len(vec_env)}; resume with the same num_envs")
        vec_env.load_state_dict(saved["vec_env"])
        self._env, self._next_obs = vec_env, saved["next_obs"].to(self.device)
        self.stats.reset_envs(len(vec_env))
        self.stats._running_return[:] = saved["running_return"]
        self.stats._running_length[:] = saved["running_length"]

    def state_dict(self) -> dict:
        """Everything needed to continue training exactly (see ``seqdex_drake.rl.checkpoint``)."""
        bounds = None if self.action_low is None else (self.action_low.tolist(), self.action_high.tolist())
        env_state = self._env_state()
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "counters": {"global_step": self.global_step, "num_updates": self.num_updates,
                         "num_episodes": self.stats.num_episodes, "learning_rate": self.learning_rate},
            "config": self.config.to_dict(),
            "dims": {"obs_dim": self.obs_dim, "action_dim": self.action_dim, "action_bounds": bounds},
            "rng": capture_rng_state({"policy": self.generator}),
            "best": dict(self.best),
            "stats": self.stats.state_dict(),
            **({} if env_state is None else {"env": env_state}),
            "nonfinite_values": self.nonfinite_values,
            "obs_spec": self.obs_spec,
        }

    def load_state_dict(self, state: dict) -> None:
        """Restores :meth:`state_dict`'s output. :meth:`train` then restores the saved env state into its env if
        both have one; otherwise (and for a bare :meth:`collect`) the next rollout starts fresh episodes."""
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        counters = state["counters"]
        self.global_step, self.num_updates = int(counters["global_step"]), int(counters["num_updates"])
        self.learning_rate = float(counters["learning_rate"])
        self.best = dict(state["best"])
        self.stats.load_state_dict(state["stats"])
        restore_rng_state(state["rng"], {"policy": self.generator})
        self._env, self._next_obs, self.buffer = None, None, None
        self._saved_env_state = state.get("env")
        self.nonfinite_values = int(state.get("nonfinite_values", 0))
        self.obs_spec = state.get("obs_spec")

    def save(self, path: str | Path) -> Path:
        """Writes a full-state checkpoint atomically."""
        return save_checkpoint(path, self.state_dict())

    @classmethod
    def resume(cls, path: str | Path, device: str | None = None) -> "PPO":
        """A learner rebuilt from a checkpoint (config, model, optimizer, counters, RNG, best metric, stats).

        Args:
            path: a ``last.pt`` / ``best.pt`` written by :meth:`save` or :meth:`train`.
            device: override of the saved ``config.device`` (e.g. resume a GPU run on CPU).
        """
        state = load_checkpoint(path, map_location=device or "cpu", required_keys=CHECKPOINT_KEYS)
        config = PPOConfig.from_dict(state["config"])
        if device is not None:
            config = dataclasses.replace(config, device=device)
        dims = state["dims"]
        bounds = dims["action_bounds"] or (None, None)
        ppo = cls(config, dims["obs_dim"], dims["action_dim"], bounds[0], bounds[1])
        ppo.load_state_dict(state)
        return ppo
