"""Run a trained policy outside the CLI: ``seqdex_drake.load_policy(path)`` -> ``policy(observation) -> action``.

::

    import gymnasium as gym
    from seqdex_drake import load_policy

    policy = load_policy("runs/grasp/last.pt")          # the mean action (deterministic) by default
    env = gym.make("seqdex/Grasp-v0")
    observation, info = env.reset(seed=0)
    observation, reward, terminated, truncated, info = env.step(policy(observation))

The checkpoint (``last.pt`` / ``best.pt`` of ``seqdex train``, read with ``torch.load(weights_only=True)`` by
:func:`~seqdex_drake.rl.checkpoint.load_checkpoint`) holds the actor-critic's weights with its observation
normalizer, so the policy takes raw env observations. Actions are clipped to the action bounds recorded in the
checkpoint; fixed action dims (``low == high``, e.g. a wrist-only task's hand) hold their value.
"""

import os
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.observation_spec import ObservationSpec
from seqdex_drake.rl.checkpoint import CheckpointError, load_checkpoint
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.tasks.registry import default_config, task_names
from seqdex_drake.tasks.run_config import observation_spec

#: What a checkpoint must hold for a policy to be rebuilt from it.
POLICY_KEYS = ("model", "config", "dims")
#: The PPOConfig fields that shape the model (the rest only matter to training).
_MODEL_FIELDS = ("actor_hidden_sizes", "critic_hidden_sizes", "activation", "init_log_std",
                 "normalize_observations", "observation_clip")


def _task_of(spec) -> str | None:
    """The registered sub-task whose observation spec is ``spec`` (an ObservationSpec), or None."""
    return next((name for name in task_names() if observation_spec(name, spec.dim) == spec), None)


def _build_model(path: Path, state: dict) -> ActorCritic:
    """The checkpoint's actor-critic (CPU, eval mode) with its weights and normalizer statistics loaded."""
    try:
        dims, weights = state["dims"], state["model"]
        defaults = PPOConfig()
        config = {field: state["config"].get(field, getattr(defaults, field)) for field in _MODEL_FIELDS}
        critic_obs_dim = int(weights["critic_obs_normalizer.mean"].shape[0]) \
            if "critic_obs_normalizer.mean" in weights else None
        with torch.random.fork_rng(devices=[]):  # The initialization's draws must not move the caller's RNG.
            model = ActorCritic(int(dims["obs_dim"]), int(dims["action_dim"]), tuple(config["actor_hidden_sizes"]),
                                tuple(config["critic_hidden_sizes"]), config["activation"],
                                float(config["init_log_std"]), critic_obs_dim, bool(config["normalize_observations"]),
                                float(config["observation_clip"]))
        model.load_state_dict(weights)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as error:
        first_line = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise CheckpointError(f"checkpoint {path}: its model weights do not fit the network its config describes "
                              f"({first_line}); use a checkpoint written by seqdex train") from error
    return model.eval()


class Policy:
    """A trained sub-task policy as a numpy callable; make one with :func:`load_policy`.

    ``policy(observation)`` takes one observation ``(obs_dim,)`` or a batch ``(n, obs_dim)`` (any real dtype)
    and returns float32 action(s) ``(action_dim,)`` or ``(n, action_dim)``: the Gaussian's mean, or with
    ``deterministic=False`` a sample from it (from the policy's own generator, seeded by ``seed``), clipped to
    the action bounds.

    Attributes:
        path: the checkpoint file.
        task: the registered sub-task whose observation spec the checkpoint records (None if it records none or
            one no registered task has).
        obs_spec: the recorded :class:`~seqdex_drake.observation_spec.ObservationSpec`, or None.
        obs_dim, action_dim: observation and action sizes.
        action_low, action_high: the action bounds (float32 arrays), or None if the checkpoint has none.
        deterministic: the mean action (True) or a sample.
        model: the :class:`~seqdex_drake.rl.networks.ActorCritic` (CPU, eval mode; normalizer inside).
    """

    def __init__(self, path: Path, model: ActorCritic, bounds, obs_spec, deterministic: bool, seed: int | None):
        self.path, self.model, self.deterministic = path, model, bool(deterministic)
        self.obs_dim, self.action_dim = model.obs_dim, model.action_dim
        self.obs_spec = obs_spec
        self.task = None if obs_spec is None else _task_of(obs_spec)
        self.action_low = None if bounds is None else np.asarray(bounds[0], dtype=np.float32)
        self.action_high = None if bounds is None else np.asarray(bounds[1], dtype=np.float32)
        self._generator = torch.Generator()
        if seed is None:
            self._generator.seed()  # A fresh non-deterministic seed for this generator alone.
        else:
            self._generator.manual_seed(int(seed))

    def __repr__(self) -> str:
        return (f"Policy(path='{self.path}', task={self.task!r}, obs_dim={self.obs_dim}, "
                f"action_dim={self.action_dim}, deterministic={self.deterministic})")

    def check_observation_spec(self, expected, what: str = "the env") -> None:
        """Raises ValueError unless the checkpoint's observation spec equals ``expected`` (an ObservationSpec of
        ``what``'s observations); a checkpoint without a recorded spec is checked on its size only."""
        if self.obs_spec is None:
            if expected.dim != self.obs_dim:
                raise ValueError(f"policy {self.path} reads {self.obs_dim}-dim observations, {what} gives "
                                 f"{expected.dim}-dim ones")
            return
        if expected != self.obs_spec:
            raise ValueError(f"policy {self.path} was trained on observations '{self.obs_spec.description}' "
                             f"({self.obs_spec.dim}), {what} gives '{expected.description}' ({expected.dim}); "
                             f"load the checkpoint of that task's run")

    def _observations(self, observation) -> tuple[torch.Tensor, bool]:
        """``observation`` as a float32 [n, obs_dim] tensor and whether it was a single observation."""
        array = np.asarray(observation)
        if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
            raise ValueError(f"observation must be numeric, got dtype {array.dtype}")
        if array.ndim not in (1, 2) or array.shape[-1] != self.obs_dim:
            task = f"the {self.task} policy" if self.task else "this policy"
            raise ValueError(f"observation has shape {array.shape}, but {task} ({self.path}) reads ({self.obs_dim},) "
                             f"or (n, {self.obs_dim}); pass the observations of the env it was trained on")
        return torch.as_tensor(array, dtype=torch.float32).reshape(-1, self.obs_dim), array.ndim == 1

    @torch.no_grad()
    def __call__(self, observation) -> np.ndarray:
        """The action(s) for one observation ``(obs_dim,)`` or a batch ``(n, obs_dim)``."""
        obs, single = self._observations(observation)
        actions = self.model.action_mean(obs)
        if not self.deterministic:
            noise = torch.randn(actions.shape, generator=self._generator)
            actions = actions + self.model.log_std.exp() * noise * self.model.free_actions
        actions = actions.numpy().astype(np.float32)
        if self.action_low is not None:
            actions = np.clip(actions, self.action_low, self.action_high)
        return actions[0] if single else actions


def load_policy(path: str | os.PathLike, deterministic: bool = True, seed: int | None = None,
                task: str | None = None) -> Policy:
    """The policy of a ``seqdex train`` checkpoint as a numpy callable (see :class:`Policy`).

    Args:
        path: a ``last.pt`` / ``best.pt``.
        deterministic: act with the mean action (default) rather than a sample.
        seed: seed of the sampling noise (``deterministic=False`` only; default: a fresh random seed).
        task: if given, the checkpoint must be a policy for this sub-task's observations.

    Raises:
        FileNotFoundError: ``path`` does not exist (the message names it).
        CheckpointError: ``path`` is truncated, corrupt, not a seqdex_drake checkpoint, or its weights do not fit.
        ValueError: ``task`` is not a registered sub-task, or the checkpoint is another task's policy.
    """
    path = Path(path)
    if not path.is_file():
        siblings = sorted(p.name for p in path.parent.glob("*.pt")) if path.parent.is_dir() else []
        raise FileNotFoundError(f"checkpoint {path} does not exist (checkpoints in {path.parent}: "
                                f"{siblings or 'none'}); pass the last.pt / best.pt of a seqdex train run")
    state = load_checkpoint(path, map_location="cpu", required_keys=POLICY_KEYS)
    try:
        recorded = state.get("obs_spec")
        obs_spec = None if recorded is None else ObservationSpec.from_dict(recorded)
        bounds = state["dims"].get("action_bounds")
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise CheckpointError(f"checkpoint {path} has a malformed observation spec or dims ({error}); use a "
                              f"checkpoint written by seqdex train") from error
    policy = Policy(path, _build_model(path, state), bounds, obs_spec, deterministic, seed)
    if task is not None:
        default_config(task)  # ValueError listing the valid tasks for an unknown name.
        policy.check_observation_spec(observation_spec(task, policy.obs_dim), f"sub-task {task!r}")
    if policy.action_low is not None and not (np.isfinite(policy.action_low).all()
                                              and np.isfinite(policy.action_high).all()):
        policy.action_low = policy.action_high = None  # Unbounded dims: nothing to clip to.
    return policy

