"""The T-STAR baseline's terminal-state regularizer (Lee et al., "Adversarial Skill Chaining for Long-Horizon
Robot Manipulation via Terminal State Regularization", CoRL 2021), as summarized in the project's FACTS.

One least-squares GAN discriminator per sub-task boundary separates the *next* sub-task's initial states
(label 1, the "expert" side) from the *previous* policy's terminal states (label 0). The previous policy is then
rewarded, once at its switch step and with a large weight (added by the chaining code), with
``1 - (clamp(D(s), 0, 1) - 1)^2``: 1 where the discriminator takes the terminal state for a valid initial state
of the next sub-task, 0 where it is sure it is not.

Training objective per step (the public implementation's "lsgan" loss with a WGAN-GP style penalty):
``mean((D(pos) - 1)^2) + mean(D(neg)^2) + lambda * mean((||grad_x D(x_hat)|| - 1)^2)`` with ``x_hat`` random
interpolations between positive and negative samples (in normalized observation space), lambda = 10.

The penalty is two-sided, so it holds ||grad D|| near 1: D's spread within one class is about that class's std in
normalized units, and D separates sharply only distributions that are far apart relative to their spread (the
public code behaves the same; T-STAR relies on this smoothness for a graded reward).
"""

import copy
import dataclasses
import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from seqdex_drake.atomic import atomic_write


@dataclasses.dataclass
class TStarConfig:
    """Discriminator settings (defaults from T-STAR's public code)."""

    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer sizes of the discriminator MLP."""
    activation: str = "tanh"
    """Hidden activation: "tanh" (T-STAR) or "relu"."""
    lr: float = 1e-4
    """Adam learning rate."""
    grad_penalty: float = 10.0
    """Weight of the gradient penalty."""
    obs_clip: float = 10.0
    """Normalized observations are clipped to +-this."""
    seed: int = 0
    """Seeds the weight initialization and the penalty's interpolation draws."""
    device: str = "cpu"
    """Torch device of the discriminator."""

    def __post_init__(self):
        if self.activation not in ("tanh", "relu"):
            raise ValueError(f"activation must be 'tanh' or 'relu', got {self.activation!r}")
        self.hidden = tuple(int(h) for h in self.hidden)


class TStarDiscriminator(nn.Module):
    """LSGAN discriminator D: observation -> scalar (about 1 for next-task initial states, 0 for terminal ones).

    Observations are standardized by buffers set with :meth:`fit_normalizer` (identity until then; fit it on
    the union of both datasets before training).
    """

    def __init__(self, obs_dim: int, config: TStarConfig | None = None):
        super().__init__()
        self.config = config or TStarConfig()
        self.obs_dim = int(obs_dim)
        device = torch.device(self.config.device)
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            torch.manual_seed(self.config.seed)
            activation = nn.Tanh if self.config.activation == "tanh" else nn.ReLU
            layers, width = [], obs_dim
            for hidden in self.config.hidden:
                layers += [nn.Linear(width, hidden), activation()]
                width = hidden
            self.net = nn.Sequential(*layers, nn.Linear(width, 1))
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))
        self.to(device)
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=self.config.lr)
        self._generator = torch.Generator(device=device).manual_seed(self.config.seed)

    def _tensor(self, states) -> torch.Tensor:
        states = torch.as_tensor(np.asarray(states, dtype=np.float32) if not torch.is_tensor(states) else states,
                                 dtype=torch.float32, device=self.obs_mean.device)
        if states.ndim != 2 or states.shape[1] != self.obs_dim:
            raise ValueError(f"expected states of shape (batch, {self.obs_dim}), got {tuple(states.shape)}")
        return states

    @torch.no_grad()
    def fit_normalizer(self, states) -> None:
        """Sets the observation mean and standard deviation from ``states`` (batch, obs_dim)."""
        states = self._tensor(states)
        self.obs_mean.copy_(states.mean(0))
        self.obs_std.copy_(states.std(0, unbiased=False).clamp_min(1e-6))

    def normalize(self, states) -> torch.Tensor:
        clip = self.config.obs_clip
        return ((self._tensor(states) - self.obs_mean) / self.obs_std).clamp(-clip, clip)

    def forward(self, states) -> torch.Tensor:
        """Raw discriminator output D, shape (batch,)."""
        return self.net(self.normalize(states)).squeeze(-1)

    def gradient_penalty(self, positive, negative) -> torch.Tensor:
        """mean((||grad D(x_hat)|| - 1)^2) over random interpolations x_hat of positive and negative samples (in
        normalized space, paired row by row; the larger set is cut to the smaller's size)."""
        positive, negative = self.normalize(positive), self.normalize(negative)
        count = min(len(positive), len(negative))
        alpha = torch.rand(count, 1, generator=self._generator, device=positive.device)
        mixed = (alpha * positive[:count] + (1 - alpha) * negative[:count]).detach().requires_grad_(True)
        output = self.net(mixed)
        (grad,) = torch.autograd.grad(output.sum(), mixed, create_graph=True)
        return ((grad.norm(2, dim=1) - 1) ** 2).mean()

    def train_step(self, positive, negative) -> dict[str, float]:
        """One Adam step on a batch of next-task initial states (``positive``) and previous-policy terminal states
        (``negative``); returns the loss terms and mean outputs."""
        self.train()
        d_positive, d_negative = self(positive), self(negative)
        positive_loss = ((d_positive - 1) ** 2).mean()
        negative_loss = (d_negative ** 2).mean()
        penalty = self.gradient_penalty(positive, negative)
        loss = positive_loss + negative_loss + self.config.grad_penalty * penalty
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        values = {"loss": loss, "positive_loss": positive_loss, "negative_loss": negative_loss,
                  "grad_penalty": penalty, "positive_output": d_positive.mean(), "negative_output": d_negative.mean()}
        return {name: float(value.detach()) for name, value in values.items()}

    @torch.no_grad()
    def transition_reward(self, states) -> np.ndarray:
        """``1 - (clamp(D, 0, 1) - 1)^2`` in [0, 1], shape (batch,)."""
        self.eval()
        d = self(states).clamp(0.0, 1.0)
        return (1.0 - (d - 1.0) ** 2).cpu().numpy()

    @torch.no_grad()
    def accuracy(self, positive, negative) -> float:
        """Share of samples on the right side of D = 0.5."""
        self.eval()
        right = (self(positive) > 0.5).sum() + (self(negative) <= 0.5).sum()
        return float(right) / (len(positive) + len(negative))

    def training_state(self) -> dict:
        """Weights, normalizer and optimizer state as tensors and plain data (for the chaining checkpoints)."""
        return copy.deepcopy({"obs_dim": self.obs_dim, "config": dataclasses.asdict(self.config),
                              "model": self.state_dict(), "optimizer": self.optimizer.state_dict(),
                              "generator": self._generator.get_state()})  # A snapshot, not live references.

    @classmethod
    def from_training_state(cls, state: dict) -> "TStarDiscriminator":
        """Inverse of :meth:`training_state`."""
        discriminator = cls(state["obs_dim"], TStarConfig(**state["config"]))
        discriminator.load_state_dict(state["model"])
        discriminator.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        discriminator._generator.set_state(state["generator"])
        return discriminator


def fit_tstar(data: dict, source_dim: int, seed: int, steps: int, use_failures: bool, path: Path,
              log: Callable[[str], None], source: str, target: str) -> dict:
    """Trains the discriminator of the ``source`` -> ``target`` boundary on transition ``data`` (its
    ``histories`` [n, h, d] and ``successes`` [n]: whether ``target`` succeeded from each terminal state) and
    saves its training state to ``path`` (atomically). Positives are the terminal states ``target`` succeeded
    from (all of them with ``use_failures`` when none did). With no positives it trains nothing, removes
    ``path`` and says so through ``log``. Returns figures for the run's log."""
    last = torch.as_tensor(data["histories"][:, -1], dtype=torch.float32)
    positive = last[torch.as_tensor(data["successes"])]
    if len(positive) == 0 and use_failures:
        positive = last
    if len(positive) == 0:  # Nothing to tell apart: no discriminator, a zero bonus (said loudly).
        log(f"warning: T-STAR: no {target} execution succeeded from {source}'s terminal states, so its "
            f"discriminator has no positive examples; the transition reward is 0 (fine-tuning {source} on its own "
            f"reward). Train {target} longer for a real T-STAR run.")
        Path(path).unlink(missing_ok=True)
        return {"positives": 0}
    discriminator = TStarDiscriminator(source_dim, TStarConfig(seed=seed))
    discriminator.fit_normalizer(last)
    for _ in range(steps):
        losses = discriminator.train_step(positive, last)
    payload = io.BytesIO()
    torch.save(discriminator.training_state(), payload)
    atomic_write(path, lambda file: file.write(payload.getvalue()))
    return {"positives": len(positive), "accuracy": discriminator.accuracy(positive, last), "loss": losses["loss"]}


def tstar_bonus(path: Path) -> Callable[[np.ndarray], float]:
    """The transition reward of the discriminator saved at ``path`` by :func:`fit_tstar`, as a function of an
    observation history (its last row is scored); 0 everywhere when none was saved (no positive examples)."""
    if not Path(path).is_file():
        return lambda history: 0.0
    discriminator = TStarDiscriminator.from_training_state(torch.load(path, weights_only=False))
    return lambda history: float(discriminator.transition_reward(history[-1:])[0])
