"""PPO hyperparameters: one dataclass, with the paper's per-sub-task values.

The defaults are the paper's appendix tables ("Hyperparameters of PPO", Building Blocks and Tool Positioning),
which match the release's PPO config (an rl_games / bi-dexhands style PPO): hidden sizes [1024, 1024, 512], ELU,
learning rate 3e-4 adapted by KL (desired 0.016), clip 0.2, max grad norm 1, gamma 0.96 (0.9 for Grasp and
Insert), GAE lambda 0.95, initial noise std 0.8, entropy coefficient 0. ``PPOConfig.for_task(name)`` returns the
column of those tables for one sub-task. The task config (``seqdex_drake.tasks.base.TaskConfig``) is a separate type.
"""

import dataclasses
import math
from typing import Any


@dataclasses.dataclass
class PPOConfig:
    """Hyperparameters of one PPO run (algorithm, networks, rollout size, logging and checkpoints)."""

    # ----------------------------------------------------------------------------------------- networks
    actor_hidden_sizes: tuple[int, ...] = (1024, 1024, 512)
    """Hidden layer widths of the actor MLP (paper tables: [1024, 1024, 512])."""
    critic_hidden_sizes: tuple[int, ...] = (1024, 1024, 512)
    """Hidden layer widths of the critic MLP; a separate network from the actor (no shared trunk)."""
    activation: str = "elu"
    """Hidden-layer activation: ``elu`` (paper), ``relu``, ``tanh`` or ``selu``."""
    init_log_std: float = math.log(0.8)
    """Initial log standard deviation of the Gaussian policy (paper: init noise std 0.8)."""
    normalize_observations: bool = True
    """Normalize observations with a running mean / variance kept inside the model (saved with it)."""
    observation_clip: float = 5.0
    """Normalized observations are clipped to [-observation_clip, observation_clip]."""

    # ---------------------------------------------------------------------------------------- optimizer
    learning_rate: float = 3e-4
    """Initial Adam learning rate (paper: 3e-4)."""
    adaptive_lr: bool = True
    """Adapt the learning rate to the KL divergence after every minibatch (rl_games / release schedule):
    ``lr /= lr_factor`` if ``kl > 2 * desired_kl``, ``lr *= lr_factor`` if ``kl < desired_kl / 2``."""
    desired_kl: float = 0.016
    """Target KL divergence between the rollout policy and the updated policy (paper: 0.016)."""
    lr_factor: float = 1.5
    """Multiplicative step of the adaptive learning-rate schedule."""
    min_learning_rate: float = 1e-6
    """Lower clamp of the adaptive learning rate."""
    max_learning_rate: float = 1e-2
    """Upper clamp of the adaptive learning rate."""
    max_grad_norm: float = 1.0
    """Global gradient-norm clip over actor and critic parameters (paper: 1)."""

    # ------------------------------------------------------------------------------------------- losses
    gamma: float = 0.96
    """Discount factor (paper: 0.96; 0.9 for Grasp and Insert)."""
    gae_lambda: float = 0.95
    """GAE lambda (paper: 0.95)."""
    clip_coef: float = 0.2
    """PPO ratio clip range epsilon (paper: 0.2)."""
    clip_value_loss: bool = True
    """Clip the value prediction to ``old_value +- value_clip_coef`` and take the larger loss (rl_games)."""
    value_clip_coef: float = 0.2
    """Clip range of the value prediction when ``clip_value_loss`` is on."""
    entropy_coef: float = 0.0
    """Weight of the entropy bonus (paper: 0)."""
    value_coef: float = 1.0
    """Weight of the value loss ``max((V - R)^2, (V_clipped - R)^2)`` in the total loss (release: 1)."""
    bounds_loss_coef: float = 1e-4
    """Weight of the rl_games bounds loss, a squared penalty on action means outside [-bound, bound]."""
    bounds_loss_bound: float = 1.1
    """Soft bound of the bounds loss on the action mean (rl_games: 1.1, actions live in [-1, 1])."""
    normalize_advantages: bool = True
    """Standardize the advantages of each rollout to zero mean and unit variance before the update."""
    reward_scale: float = 1.0
    """The learner trains on ``reward_scale * reward`` (logged returns stay unscaled): keeps the critic's targets
    near unit size, so that its gradients do not take over the global gradient-norm clip."""
    demo_coef: float = 0.0
    """DAPG's lambda0: weight of the demonstrations' negative log-likelihood in the loss (``rl/demonstrations.py``;
    0: no demonstration term). Needs demonstrations (``PPO.demos``)."""
    demo_decay: float = 0.95
    """DAPG's lambda1: the demonstration weight at update k is ``demo_coef * demo_decay ** k``."""

    # ----------------------------------------------------------------------------------------- rollouts
    num_envs: int = 16
    """Parallel environments (the release used 1024-2048 GPU envs; Drake workers are processes)."""
    horizon: int = 8
    """Environment steps per env per update (paper tables: 'episode-length' 8 or 20, the release's nsteps)."""
    grouped_rollouts: bool = True
    """With a vector env that steps its worker processes separately (``ProcessVectorEnv.step_async``), let each
    worker's envs run through the rollout on their own: the policy acts on a worker's observations as soon as
    they arrive and the workers meet only at the end of the rollout, instead of waiting for the slowest worker at
    every step. The same seed gives the same rollout either way of arrival (the action noise of the whole rollout
    is drawn up front); the numbers differ from the lock-step rollout's (False), which draws it step by step."""
    num_epochs: int = 5
    """Passes over each rollout per update (paper: 5, 10 for the orienting tasks, 2 for Grasp and Insert)."""
    num_minibatches: int = 4
    """Minibatches per epoch; the minibatch size is ``num_envs * horizon // num_minibatches``."""
    clip_actions: bool = True
    """Clip sampled actions to the action space's bounds before stepping the env (the buffer keeps the sample)."""
    total_steps: int = 10_000_000
    """Environment steps (summed over envs) after which ``train`` stops."""

    # ------------------------------------------------------------------------------- run and bookkeeping
    seed: int = 0
    """Seed of python, numpy and torch (``seed_everything``) and of the policy's sampling generator."""
    device: str = "cpu"
    """Torch device of the model and the update (``cpu`` or ``cuda``)."""
    stats_window: int = 100
    """Episodes in the moving window of the logged return, length and success rate (and of best.pt)."""
    checkpoint_every: int = 50
    """Write ``last.pt`` every this many updates (and at the end of training)."""
    checkpoint_seconds: float = 300.0
    """Also write ``last.pt`` after an update that ends this many wall-clock seconds or more after the last write,
    so that a crash loses about this much work at most however long updates take (``inf``: by count only)."""

    # ---------------------------------------------------------------------------------------- presets
    @classmethod
    def for_task(cls, name: str, **overrides: Any) -> "PPOConfig":
        """The paper's PPO hyperparameters for one sub-task (appendix tables), with optional overrides.

        Args:
            name: ``search``, ``orient``, ``grasp``, ``insert``, ``tool_grasp``, ``tool_reorient`` (the paper's
                tables) or ``reach``, ``lower`` (the cheap hand-over chain).
            **overrides: any field of this dataclass, e.g. ``num_envs=8``.
        """
        presets = {**PAPER_TASK_HYPERPARAMETERS, **HANDOVER_TASK_HYPERPARAMETERS}
        if name not in presets:
            raise ValueError(f"no PPO hyperparameters for sub-task {name!r}; known: {sorted(presets)}")
        return dataclasses.replace(cls(), **{**presets[name], **overrides})

    @classmethod
    def for_budget(cls, name: str, **overrides: Any) -> "PPOConfig":
        """The small-budget preset (:data:`BUDGET_HYPERPARAMETERS`) over the sub-task's paper column, with
        optional overrides."""
        return cls.for_task(name, **{**BUDGET_HYPERPARAMETERS, **overrides})

    @classmethod
    def for_preset(cls, name: str, preset: str, residual: bool = False, **overrides: Any) -> "PPOConfig":
        """The config ``seqdex train --preset`` (and ``seqdex pipeline --preset``) builds: ``"paper"``
        (:meth:`for_task`) or ``"budget"`` (:meth:`for_budget`, plus :data:`RESIDUAL_HYPERPARAMETERS` when the
        policy is a residual on a scripted base, ``residual``), then ``overrides``."""
        if preset == "paper":
            return cls.for_task(name, **overrides)
        if preset != "budget":
            raise ValueError(f"unknown PPO preset {preset!r}; presets: paper, budget")
        return cls.for_budget(name, **{**(RESIDUAL_HYPERPARAMETERS if residual else {}), **overrides})

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (lists for tuples), as stored in checkpoints."""
        return {key: list(value) if isinstance(value, tuple) else value
                for key, value in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PPOConfig":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them."""
        fields = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(data) - fields)
        if unknown:
            raise ValueError(f"unknown PPOConfig fields {unknown}; known: {sorted(fields)}")
        return cls(**{key: tuple(value) if isinstance(value, list) else value for key, value in data.items()})

    @property
    def batch_size(self) -> int:
        """Transitions per update: ``num_envs * horizon``."""
        return self.num_envs * self.horizon

    @property
    def minibatch_size(self) -> int:
        """Transitions per gradient step."""
        return self.batch_size // self.num_minibatches


#: Per-sub-task columns of the paper's tables "Hyperparameters of PPO in Building Blocks / Tool Positioning".
#: The remaining rows (hidden sizes, clip 0.2, grad norm 1, lr 3e-4, lambda 0.95, noise std 0.8,
#: desired KL 0.016, entropy 0) are identical for every sub-task and are the dataclass defaults.
PAPER_TASK_HYPERPARAMETERS: dict[str, dict[str, Any]] = {
    "search": dict(num_minibatches=4, num_epochs=5, horizon=8, gamma=0.96),
    "orient": dict(num_minibatches=4, num_epochs=10, horizon=20, gamma=0.96),
    "grasp": dict(num_minibatches=8, num_epochs=2, horizon=8, gamma=0.9),
    "insert": dict(num_minibatches=8, num_epochs=2, horizon=8, gamma=0.9),
    "tool_grasp": dict(num_minibatches=4, num_epochs=5, horizon=8, gamma=0.96),
    "tool_reorient": dict(num_minibatches=4, num_epochs=10, horizon=20, gamma=0.96),
}

#: The small-budget preset (``seqdex train --preset budget``; ``../shared/TRAINING.md``, "PPO at small batch"):
#: 2048-transition batches (32 envs x 64 steps), 5 epochs of 4 minibatches, [256, 256, 128] networks (about 0.1 M
#: parameters each, where the paper's are 3.4 M: the learner then costs a few per cent of the env's time on two
#: cores), initial action std 0.5, a fixed learning rate, rewards scaled by 0.1 with an unclipped value loss.
BUDGET_HYPERPARAMETERS: dict[str, Any] = dict(
    actor_hidden_sizes=(256, 256, 128), critic_hidden_sizes=(256, 256, 128), num_envs=32, horizon=64,
    num_epochs=5, num_minibatches=4, gamma=0.98, learning_rate=3e-4, adaptive_lr=False, clip_value_loss=False,
    init_log_std=math.log(0.5), reward_scale=0.1, checkpoint_every=5)

#: On top of the budget preset, for a residual policy (``TaskConfig.residual``: the policy corrects a scripted base,
#: ``tasks/residual.py``). Exploration starts at std 0.1: tool Grasp's script keeps its successes under that noise
#: on the wrist (6 of 6 seeds; 5 of 6 at 0.2), where noise of 0.05 on all 19 dims halves them and 0.1 loses them
#: all (the fingers' targets jitter every step). A fixed learning rate of 3e-4 moved the policy by a KL of 0.1-0.8
#: per update and the script's success fell (results/tool_positioning.md); the KL-adaptive rate (target 0.008,
#: adapted per minibatch) bounds each update. Rollouts of one whole episode (150 steps x 32 envs: 32 episodes per
#: update, where a 64-step rollout saw about 14) and gamma 0.99, so the lift late in the episode credits the approach.
RESIDUAL_HYPERPARAMETERS: dict[str, Any] = dict(
    init_log_std=math.log(0.1), adaptive_lr=True, desired_kl=0.008, learning_rate=1e-4, horizon=150, gamma=0.99)

#: The cheap hand-over chain (``tasks/handover_common.py``): not in the paper; small networks and long rollouts
#: so that each stage learns in a few thousand steps on two CPU workers.
HANDOVER_TASK_HYPERPARAMETERS: dict[str, dict[str, Any]] = {
    # A fixed learning rate and an unclipped value loss: with 240-step batches the KL rule drove the rate to ~0,
    # and clipping unnormalized values to +-0.2 per update kept the critic from learning (explained variance < 0).
    # 3e-4 rather than 1e-3: at 1e-3 the mean KL per update was 0.2-0.65 (Reach, wrist dims only), at 3e-4 0.03-0.06
    # with better deterministic success at 12k steps (0.43 against 0.20, one seed, 30 episodes).
    name: dict(actor_hidden_sizes=(128, 128), critic_hidden_sizes=(128, 128), num_envs=2, horizon=120,
               num_minibatches=4, num_epochs=10, gamma=0.96, learning_rate=3e-4, adaptive_lr=False,
               clip_value_loss=False, init_log_std=math.log(0.5), checkpoint_every=10)
    for name in ("reach", "lower")
}
