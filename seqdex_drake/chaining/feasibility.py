"""The transition feasibility function F (paper Sec. 3.2, eq. 1) and the switching score c = F / h (Sec. 3.3).

F^i maps the last H observations of the previous sub-task's episode, ending at the transition state
s^{i-1}_T = s^i_0, to the return that policy pi^i collects when started from that state. It is trained by L2
regression (eq. 1) and used (a) as an auxiliary reward when fine-tuning pi^{i-1} and (b) as a stage identifier:
switch to pi^i when c = F^i / h^i > 1.

Models:

- :class:`TemporalFeasibility` ("Ours"): per-step linear embedding, a positional encoding indexed *backwards from
  the transition state* (the last step is position 0, so histories of any length 1..``max_history`` line up at
  the state that matters), a pre-norm ``nn.TransformerEncoder`` (multi-head self-attention), the last token
  (or the masked mean) pooled into an MLP head giving a scalar.
- :class:`MlpFeasibility` ("Ours w/o temporal", the ablation's 0-step history): an MLP on the last observation.

History convention: a history is ``(H, obs_dim)``, oldest first, ending at the transition state. An episode with
fewer than H steps is left-padded by repeating its first observation (:func:`pad_history`), i.e. the object is
taken as having rested in its first observed state; no mask is needed then. The attention model also accepts a
``padding_mask`` (``True`` = padded step, must be on the left; the last step must be real) for callers that pad
otherwise.

Both models normalize observations inside (buffers fitted on the training set) and predict returns in return
units (the regression runs on standardized returns; the mean and scale are buffers of the model).

Labels (``FeasibilityConfig.label``): ``"return"`` regresses the next policy's return (paper eq. 1; h from the
successful returns, :func:`feasibility_threshold`); ``"success"`` regresses its success, 0 or 1 (the authors'
release labels F with success), so F estimates the probability that the next policy succeeds from the state
and h = :data:`SUCCESS_THRESHOLD` (c > 1: more likely to succeed than not). The success label is the one to use
where a sub-task's returns do not order its outcomes (Orient in the pile: successful episodes with negative
returns). Either way the fit reports the validation AUC of F against success (:func:`roc_auc`).
"""

import abc
import dataclasses
import math

import numpy as np
import torch
from torch import nn

from seqdex_drake.chaining.feasibility_metrics import r_squared, roc_auc

LABELS = ("return", "success")
"""What F regresses: the next policy's return (paper eq. 1) or its success (0/1, the release's label)."""
SUCCESS_THRESHOLD = 0.5
"""h of a success-labelled F: switch when the predicted success probability exceeds one half."""


@dataclasses.dataclass
class FeasibilityConfig:
    """Model and training settings of one feasibility function."""

    history: int = 10
    """H: observations per input, ending at the transition state (paper: 10; ablation 0/5/10/15). H = 0 is
    "w/o temporal": the last observation only, through :class:`MlpFeasibility`."""
    temporal: bool = True
    """True: the attention model over H steps; False: the "Ours w/o temporal" MLP on the last observation."""
    d_model: int = 128
    """Width of the per-step embedding and of the attention layers."""
    heads: int = 4
    """Attention heads (must divide ``d_model``)."""
    layers: int = 2
    """Transformer encoder layers."""
    feedforward: int = 256
    """Hidden width of each encoder layer's feed-forward block."""
    dropout: float = 0.1
    """Dropout in the encoder layers and the heads."""
    positional: str = "learned"
    """Positional encoding, indexed backwards from the last step: "learned" or "sinusoidal"."""
    pooling: str = "last"
    """Token pooling before the head: "last" (the transition state's token) or "mean" (over unpadded steps)."""
    max_history: int = 32
    """Longest history the positional encoding covers."""
    mlp_hidden: tuple[int, ...] = (256, 256)
    """Hidden sizes of the w/o-temporal MLP."""
    lr: float = 3e-4
    """AdamW learning rate."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    batch_size: int = 256
    """Minibatch size."""
    epochs: int = 100
    """Passes over the training split."""
    val_fraction: float = 0.1
    """Share of the data held out for validation (at least one sample when there are 10 or more)."""
    grad_clip: float = 1.0
    """Gradient-norm clip (0 disables)."""
    obs_clip: float = 10.0
    """Normalized observations are clipped to +-this."""
    keep_best: bool = True
    """Return the weights of the epoch with the lowest validation loss (training loss without a validation set)."""
    label: str = "return"
    """The regression target (:data:`LABELS`): "return" (paper eq. 1) or "success" (0/1; see the module
    docstring)."""
    seed: int = 0
    """Seeds initialization, the split, shuffling and dropout (training does not disturb global RNG state)."""
    device: str = "cpu"
    """Torch device for training; the returned model is on this device."""

    def __post_init__(self):
        if not 0 <= self.history <= self.max_history:
            raise ValueError(f"history must be in [0, max_history={self.max_history}], got {self.history}")
        if self.d_model % self.heads:
            raise ValueError(f"heads ({self.heads}) must divide d_model ({self.d_model})")
        if self.positional not in ("learned", "sinusoidal"):
            raise ValueError(f"positional must be 'learned' or 'sinusoidal', got {self.positional!r}")
        if self.label not in LABELS:
            raise ValueError(f"label must be one of {LABELS}, got {self.label!r}")
        if self.pooling not in ("last", "mean"):
            raise ValueError(f"pooling must be 'last' or 'mean', got {self.pooling!r}")
        self.mlp_hidden = tuple(int(h) for h in self.mlp_hidden)

    @property
    def uses_attention(self) -> bool:
        """True for the temporal attention model (``temporal`` and H >= 1)."""
        return self.temporal and self.history > 0

    @property
    def input_length(self) -> int:
        """Steps the model reads: H, or 1 for the w/o-temporal MLP."""
        return self.history if self.uses_attention else 1


def pad_history(observations: np.ndarray, length: int) -> np.ndarray:
    """The last ``length`` rows of ``observations`` (T, obs_dim); if T < length, left-padded with copies of the
    first row. Also works batched on (B, T, obs_dim)."""
    observations = np.asarray(observations)
    if observations.ndim < 2 or observations.shape[-2] == 0:
        raise ValueError(f"need at least one observation of shape (T, obs_dim), got {observations.shape}")
    steps = observations.shape[-2]
    if steps >= length:
        return observations[..., steps - length:, :]
    first = np.take(observations, [0], axis=-2)
    pad = np.repeat(first, length - steps, axis=-2)
    return np.concatenate([pad, observations], axis=-2)


class _FeasibilityModel(nn.Module, abc.ABC):
    """Shared parts: observation normalizer and return scale buffers, input checks, numpy prediction."""

    def __init__(self, obs_dim: int, config: FeasibilityConfig):
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.config = config
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))
        self.register_buffer("return_mean", torch.zeros(()))
        self.register_buffer("return_std", torch.ones(()))

    def fit_normalizers(self, histories: torch.Tensor, returns: torch.Tensor) -> None:
        """Sets the observation statistics (over every step of every history) and the return scale."""
        flat = histories.reshape(-1, self.obs_dim).to(self.obs_mean)
        self.obs_mean.copy_(flat.mean(0))
        self.obs_std.copy_(flat.std(0, unbiased=False).clamp_min(1e-6))
        returns = returns.to(self.return_mean)
        self.return_mean.copy_(returns.mean())
        self.return_std.copy_(returns.std(unbiased=False).clamp_min(1e-6))

    def normalize(self, history: torch.Tensor) -> torch.Tensor:
        if history.ndim != 3 or history.shape[-1] != self.obs_dim:
            raise ValueError(f"expected a history of shape (batch, steps, {self.obs_dim}), got {tuple(history.shape)}")
        clip = self.config.obs_clip
        return ((history - self.obs_mean) / self.obs_std).clamp(-clip, clip)

    @abc.abstractmethod
    def forward_normalized(self, history: torch.Tensor, padding_mask: torch.Tensor | None = None) -> torch.Tensor:
        """The standardized return (the regression target's scale), shape (batch,)."""

    def forward(self, history: torch.Tensor, padding_mask: torch.Tensor | None = None) -> torch.Tensor:
        """F in return units, shape (batch,)."""
        return self.forward_normalized(history, padding_mask) * self.return_std + self.return_mean

    @torch.no_grad()
    def predict(self, history: np.ndarray) -> np.ndarray:
        """F for numpy histories (T, obs_dim) or (B, T, obs_dim), padded/cut to the model's input length with
        :func:`pad_history`; returns a float (single history) or a (B,) array. Runs in eval mode."""
        history = np.asarray(history, dtype=np.float32)
        single = history.ndim == 2
        batch = pad_history(history[None] if single else history, self.config.input_length)
        was_training = self.training
        self.eval()
        try:
            values = self(torch.as_tensor(batch, device=self.obs_mean.device)).cpu().numpy()
        finally:
            self.train(was_training)
        return float(values[0]) if single else values


class TemporalFeasibility(_FeasibilityModel):
    """Multi-head self-attention over the last H observations (the paper's F); input (batch, T, obs_dim) with
    1 <= T <= ``config.max_history`` (T is normally ``config.history``)."""

    def __init__(self, obs_dim: int, config: FeasibilityConfig):
        super().__init__(obs_dim, config)
        width = config.d_model
        self.embed = nn.Linear(obs_dim, width)
        if config.positional == "learned":
            self.position = nn.Parameter(torch.randn(config.max_history, width) * 0.02)
        else:
            steps = torch.arange(config.max_history, dtype=torch.float32)[:, None]
            rates = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
            table = torch.zeros(config.max_history, width)
            table[:, 0::2] = torch.sin(steps * rates)
            table[:, 1::2] = torch.cos(steps * rates[: width // 2])
            self.register_buffer("position", table)
        layer = nn.TransformerEncoderLayer(width, config.heads, config.feedforward, config.dropout,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, config.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(width)
        self.head = nn.Sequential(nn.Linear(width, width), nn.GELU(), nn.Dropout(config.dropout), nn.Linear(width, 1))

    def forward_normalized(self, history: torch.Tensor, padding_mask: torch.Tensor | None = None) -> torch.Tensor:
        """The standardized return, shape (batch,); ``padding_mask`` (batch, T) marks padded steps with True."""
        x = self.normalize(history)
        steps = x.shape[1]
        if not 1 <= steps <= self.config.max_history:
            raise ValueError(f"history length must be in [1, {self.config.max_history}], got {steps}")
        if padding_mask is not None:
            padding_mask = padding_mask.to(device=x.device, dtype=torch.bool)
            if padding_mask.shape != x.shape[:2]:
                raise ValueError(f"padding_mask must have shape {tuple(x.shape[:2])}, got {tuple(padding_mask.shape)}")
            if padding_mask[:, -1].any():
                raise ValueError("the last step (the transition state) must not be padded; pad on the left")
        # Position 0 is the last step: flip the first `steps` rows so the table is indexed from the end.
        tokens = self.embed(x) + self.position[:steps].flip(0)
        encoded = self.norm(self.encoder(tokens, src_key_padding_mask=padding_mask))
        if self.config.pooling == "last":
            pooled = encoded[:, -1]
        else:
            valid = torch.ones_like(encoded[..., 0]) if padding_mask is None else (~padding_mask).to(encoded)
            pooled = (encoded * valid[..., None]).sum(1) / valid.sum(1, keepdim=True)
        return self.head(pooled).squeeze(-1)


class MlpFeasibility(_FeasibilityModel):
    """"Ours w/o temporal": an MLP on the last observation only (the ablation's 0-step history). Accepts the same
    (batch, T, obs_dim) input as :class:`TemporalFeasibility` and reads only step T-1."""

    def __init__(self, obs_dim: int, config: FeasibilityConfig):
        super().__init__(obs_dim, config)
        layers, width = [], obs_dim
        for hidden in config.mlp_hidden:
            layers += [nn.Linear(width, hidden), nn.ELU(), nn.Dropout(config.dropout)]
            width = hidden
        self.mlp = nn.Sequential(*layers, nn.Linear(width, 1))

    def forward_normalized(self, history: torch.Tensor, padding_mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.mlp(self.normalize(history)[:, -1]).squeeze(-1)


def build_feasibility_model(obs_dim: int, config: FeasibilityConfig) -> _FeasibilityModel:
    """:class:`TemporalFeasibility` if ``config.uses_attention``, else :class:`MlpFeasibility`."""
    return (TemporalFeasibility if config.uses_attention else MlpFeasibility)(obs_dim, config)


def _mse(model: _FeasibilityModel, histories: torch.Tensor, targets: torch.Tensor, batch: int) -> float:
    """Mean squared error on standardized returns, in eval mode, in chunks."""
    model.eval()
    total = 0.0
    with torch.no_grad():
        for start in range(0, len(targets), batch):
            error = model.forward_normalized(histories[start:start + batch]) - targets[start:start + batch]
            total += float((error ** 2).sum())
    return total / max(len(targets), 1)


def train_feasibility(histories, returns, config: FeasibilityConfig,
                      successes=None) -> tuple[_FeasibilityModel, dict]:
    """Fits F by L2 regression of its label onto the transition history (paper eq. 1).

    Args:
        histories: (N, T, obs_dim) observation histories ending at the transition states; cut or left-padded
            (:func:`pad_history`) to ``config.input_length``.
        returns: (N,) the regression targets: returns of the next policy started from those states (or, for
            ``config.label == "success"``, its successes as 0/1: :func:`feasibility_targets`).
        config: model and training settings; training is deterministic for ``config.seed`` (on CPU).
        successes: optional (N,) booleans, the next policy's successes: adds ``train_auc`` / ``val_auc``, how
            well F orders successful hand-overs above failed ones (:func:`roc_auc`; NaN where a split lacks one
            of the two outcomes).

    Returns:
        The model (eval mode, on ``config.device``) and metrics: ``train_mse`` / ``val_mse`` (standardized
        targets, eval mode), ``val_rmse`` (target units), ``val_r2``, ``best_epoch``, ``n_train``, ``n_val``
        (and the AUCs with ``successes``).
    """
    histories = pad_history(np.asarray(histories, dtype=np.float32), config.input_length)
    returns = np.asarray(returns, dtype=np.float32).reshape(-1)
    if histories.ndim != 3 or len(histories) != len(returns) or len(returns) < 2:
        raise ValueError(f"need (N, T, obs_dim) histories and N >= 2 returns, got {histories.shape} and "
                         f"{returns.shape}")
    if not (np.isfinite(histories).all() and np.isfinite(returns).all()):
        raise ValueError("histories and returns must be finite")
    device = torch.device(config.device)
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        torch.manual_seed(config.seed)
        generator = torch.Generator().manual_seed(config.seed)
        count = len(returns)
        order = torch.randperm(count, generator=generator)
        n_val = int(round(config.val_fraction * count)) if count >= 10 else 0
        n_val = max(n_val, 1) if count >= 10 and config.val_fraction > 0 else n_val
        val_index, train_index = order[:n_val], order[n_val:]
        x_all = torch.as_tensor(histories, device=device)
        y_all = torch.as_tensor(returns, device=device)
        x_train, x_val = x_all[train_index.to(device)], x_all[val_index.to(device)]
        model = build_feasibility_model(histories.shape[-1], config).to(device)
        model.fit_normalizers(x_train, y_all[train_index.to(device)])
        y_norm = (y_all - model.return_mean) / model.return_std
        y_train, y_val = y_norm[train_index.to(device)], y_norm[val_index.to(device)]
        optimizer = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        best, best_state, best_epoch = math.inf, None, -1
        for epoch in range(config.epochs):
            model.train()
            permutation = torch.randperm(len(y_train), generator=generator).to(device)
            for start in range(0, len(y_train), config.batch_size):
                index = permutation[start:start + config.batch_size]
                loss = ((model.forward_normalized(x_train[index]) - y_train[index]) ** 2).mean()
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                if config.grad_clip > 0:
                    nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
                optimizer.step()
            if config.keep_best:
                monitored = _mse(model, x_val, y_val, config.batch_size) if n_val else \
                    _mse(model, x_train, y_train, config.batch_size)
                if monitored < best:
                    best, best_epoch = monitored, epoch
                    best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if best_state is not None:
            model.load_state_dict(best_state)
        else:
            best_epoch = config.epochs - 1
        model.eval()
        metrics = {"train_mse": _mse(model, x_train, y_train, config.batch_size), "best_epoch": best_epoch,
                   "n_train": len(y_train), "n_val": n_val}
        if n_val:
            val_mse = _mse(model, x_val, y_val, config.batch_size)
            metrics.update(val_mse=val_mse, val_rmse=math.sqrt(val_mse) * float(model.return_std),
                           val_r2=r_squared(val_mse, float(y_val.var(unbiased=False))))
        else:
            metrics.update(val_mse=float("nan"), val_rmse=float("nan"), val_r2=float("nan"))
        if successes is not None:
            labels = np.asarray(successes, dtype=bool).reshape(-1)
            if labels.shape != returns.shape:
                raise ValueError(f"successes {labels.shape} and returns {returns.shape} differ in shape")
            for split, index, x in (("train", train_index, x_train), ("val", val_index, x_val)):
                with torch.no_grad():
                    predicted = model.forward_normalized(x).cpu().numpy() if len(index) else np.zeros(0)
                metrics[f"{split}_auc"] = roc_auc(predicted, labels[index.numpy()])
    return model, metrics


def feasibility_targets(returns, successes, label: str) -> np.ndarray:
    """What F of ``label`` regresses: the returns, or the successes as 0.0 / 1.0."""
    if label not in LABELS:
        raise ValueError(f"label must be one of {LABELS}, got {label!r}")
    values = returns if label == "return" else np.asarray(successes, dtype=bool)
    return np.asarray(values, dtype=np.float64).reshape(-1)


def cross_validate(histories, targets, successes, config: FeasibilityConfig, folds: int = 5) -> dict:
    """Out-of-fold quality of F on hand-overs it was not fitted on: ``folds`` stratified folds (successes and
    failures dealt round-robin after a seeded shuffle), one F per fold fitted on the others (no validation
    split), every hand-over predicted once by the F that did not see it. Returns ``cv_auc`` (:func:`roc_auc` of
    the pooled out-of-fold predictions against ``successes``), ``cv_r2`` (of ``targets``), ``cv_folds`` and the
    count ``cv_n``. Deterministic for ``config.seed``."""
    histories = np.asarray(histories, dtype=np.float32)
    targets = np.asarray(targets, dtype=np.float64).reshape(-1)
    labels = np.asarray(successes, dtype=bool).reshape(-1)
    if not 2 <= folds <= len(targets) or labels.shape != targets.shape:
        raise ValueError(f"need 2 <= folds <= N and N successes: folds {folds}, {targets.shape} targets, "
                         f"{labels.shape} successes")
    rng = np.random.default_rng(config.seed)
    fold_of = np.empty(len(targets), dtype=int)
    for outcome in (True, False):  # Stratified: each fold gets its share of successes and of failures.
        members = rng.permutation(np.flatnonzero(labels == outcome))
        fold_of[members] = (np.arange(len(members)) + (0 if outcome else int(labels.sum()))) % folds
    predictions = np.zeros(len(targets))
    fold_config = dataclasses.replace(config, val_fraction=0.0)
    for fold in range(folds):
        held = fold_of == fold
        model, _ = train_feasibility(histories[~held], targets[~held], fold_config)
        predictions[held] = model.predict(histories[held])
    variance = float(targets.var())
    return {"cv_auc": roc_auc(predictions, labels), "cv_folds": folds, "cv_n": len(targets),
            "cv_r2": r_squared(float(((predictions - targets) ** 2).mean()), variance)}


def feasibility_threshold(returns, successes, quantile: float = 0.1) -> float:
    """h: the ``quantile`` of the returns of *successful* executions of the next policy (paper: "a threshold
    defined based on the reward of successful task executions").

    With the default 0.1, c = F / h > 1 means F predicts a return at least that of the bottom decile of
    successful executions, i.e. a state from which the next policy typically succeeds (``quantile=0`` is the
    least successful return, a laxer switch). Raises ValueError when there is no success or h <= 0 (c = F / h
    only orders states correctly for a positive h; shift the task's returns if successful ones can be <= 0).
    """
    returns = np.asarray(returns, dtype=np.float64).reshape(-1)
    successes = np.asarray(successes, dtype=bool).reshape(-1)
    if returns.shape != successes.shape:
        raise ValueError(f"returns {returns.shape} and successes {successes.shape} differ in shape")
    if not 0.0 <= quantile <= 1.0:
        raise ValueError(f"quantile must be in [0, 1], got {quantile}")
    if not successes.any():
        raise ValueError("no successful execution among the returns: the threshold h is undefined")
    threshold = float(np.quantile(returns[successes], quantile))
    if threshold <= 0:
        raise ValueError(f"the threshold h = {threshold:g} (the {quantile:g} quantile of successful returns) is not "
                         f"positive, so c = F / h would rank states backwards")
    return threshold


def score(model: _FeasibilityModel, history, h: float):
    """The switching score c = F(history) / h (switch to that policy when c > 1); ``history`` is (T, obs_dim)
    (returns a float) or (B, T, obs_dim) (returns a (B,) array)."""
    if not h > 0:
        raise ValueError(f"the threshold h must be positive, got {h}")
    return model.predict(history) / h


def walk_back(scores: np.ndarray) -> int:
    """The paper's stage estimate: the last stage i >= 1 with c^i > 1 (NaN never is), else 0 (restart).

    Shared by the deployed switcher (``controller/switcher.py``) and the pipeline's evaluation rollouts
    (``chaining/rollouts.py``), so both pick stages the same way."""
    for stage in range(len(scores) - 1, 0, -1):
        if scores[stage] > 1.0:
            return stage
    return 0


# The file format (save_feasibility, load_feasibility, FeasibilityFile) lives in ``feasibility_io``, which builds
# on the classes above; import it from there (re-exporting it here would make the two modules import each other).
__all__ = ["LABELS", "SUCCESS_THRESHOLD", "FeasibilityConfig", "MlpFeasibility", "TemporalFeasibility",
           "build_feasibility_model", "cross_validate", "feasibility_targets", "feasibility_threshold",
           "pad_history", "score", "train_feasibility", "walk_back"]
