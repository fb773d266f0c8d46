"""Numpy snapshots of the feasibility models F (``chaining/feasibility.py``) for the switcher's 60 Hz scores.

- :class:`FeasibilitySnapshot`: one :class:`~seqdex_drake.chaining.feasibility.TemporalFeasibility` (input
  normalization and clip, per-step embedding, backward-indexed positional table, pre- or post-norm encoder
  layers with multi-head self-attention, final LayerNorm, last-token or mean pooling, head, return scale) or
  :class:`~seqdex_drake.chaining.feasibility.MlpFeasibility`, without a padding mask (histories are left-padded by
  :func:`~seqdex_drake.chaining.feasibility.pad_history`, as ``predict`` does).
- :class:`FeasibilityBank`: several F's evaluated together. F's of the same architecture (observation sizes may
  differ: inputs are zero-padded, with zero embedding rows) are concatenated along a leading model axis and run
  as one batched pass, so a tick with K F's costs about as many numpy calls as one F (per-call overhead, not
  arithmetic, dominated a single batch-1 F).

Savings on top of a plain transcription: LayerNorm affine parts are folded into the following Linear, the
attention scale into the query weights, LayerNorm means and variances are matrix products with a 1/n vector,
and with last-token pooling the last encoder layer computes only the last token's output.

Every array has a leading model axis (weights (M, in, out), biases (M, 1, out)), M = 1 for one snapshot.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np
from torch import nn

from seqdex_drake.chaining.feasibility import MlpFeasibility, TemporalFeasibility, pad_history
from seqdex_drake.controller.inference_blocks import _Dense, _Tensors, exp, matmul


def _standardize(x: np.ndarray, eps: float) -> np.ndarray:
    """LayerNorm without its affine part: ``(x - mean) / sqrt(var + eps)`` over the last axis (means by numpy's
    pairwise sums: machine-independent, see :mod:`~seqdex_drake.controller.inference_blocks`)."""
    width = x.shape[-1]
    centered = x - x.sum(-1, keepdims=True) / x.dtype.type(width)
    variance = (centered * centered).sum(-1, keepdims=True) / x.dtype.type(width)
    variance += eps
    centered /= np.sqrt(variance, out=variance)
    return centered


def _softmax(x: np.ndarray) -> np.ndarray:
    x = exp(x - x.max(-1, keepdims=True))
    x /= x.sum(-1, keepdims=True)
    return x


def _fold_norm(norm: nn.LayerNorm, weight: np.ndarray, bias: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The Linear ``(weight, bias)`` ((1, in, out), (1, 1, out)) with the affine part of the preceding ``norm``
    folded in: ``(z * w + b) @ W + c = z @ (w[:, None] * W) + (b @ W + c)``; saves two passes per LayerNorm."""
    dtype = weight.dtype
    w, b = (tensor.detach().cpu().double().numpy() for tensor in (norm.weight, norm.bias))
    W = weight.astype(np.float64)
    c = np.zeros((1, 1, W.shape[-1])) if bias is None else bias.astype(np.float64)
    return np.ascontiguousarray(w[:, None] * W, dtype=dtype), (matmul(b, W) + c).astype(dtype)


class _EncoderLayer:
    """One ``nn.TransformerEncoderLayer`` (batch_first, no masks); pre-norm layers have their LayerNorm affine
    parts folded into the following Linear, and the attention scale is folded into the query projection."""

    def __init__(self, layer: nn.TransformerEncoderLayer, tensors: _Tensors):
        attention = layer.self_attn
        if not attention._qkv_same_embed_dim or attention.bias_k is not None or attention.add_zero_attn:
            raise TypeError("unsupported attention layout (separate q/k/v weights, bias_k or add_zero_attn)")
        if attention.in_proj_bias is None:
            raise TypeError("unsupported attention without input-projection bias")
        self.heads, self.width = int(attention.num_heads), int(attention.embed_dim)
        weight = tensors.array(attention.in_proj_weight, transpose=True)[None]
        bias = tensors.array(attention.in_proj_bias)[None, None]
        self.out = _Dense([attention.out_proj], tensors, stacked=True)
        self.feedforward = _Dense([layer.linear1, layer.activation, layer.linear2], tensors, stacked=True)
        self.norm_first = bool(layer.norm_first)
        self.eps = (float(layer.norm1.eps), float(layer.norm2.eps))
        norms = [(tensors.array(n.weight)[None, None], tensors.array(n.bias)[None, None])
                 for n in (layer.norm1, layer.norm2)]
        if self.norm_first:
            weight, bias = _fold_norm(layer.norm1, weight, bias)
            self.feedforward.layers[0] = _fold_norm(layer.norm2, *self.feedforward.layers[0])
            self.norms = None
        else:
            self.norms = norms
        scale = 1.0 / math.sqrt(self.width // self.heads)
        weight[..., :self.width] *= scale
        bias[..., :self.width] *= scale
        self.projection = (weight, bias)
        self.query = (np.ascontiguousarray(weight[..., :self.width]), bias[..., :self.width].copy())
        self.key_value = (np.ascontiguousarray(weight[..., self.width:]), bias[..., self.width:].copy())

    def attend(self, x: np.ndarray, last_only: bool) -> np.ndarray:
        """Multi-head self-attention of (M, T, width) tokens; with ``last_only`` only the last token's output
        (M, 1, width) is computed (every token still serves as key and value)."""
        batch, steps, _ = x.shape
        if last_only:
            query = matmul(x[:, -1:], self.query[0])
            query += self.query[1]
            key_value = matmul(x, self.key_value[0])
            key_value += self.key_value[1]
        else:
            key_value = matmul(x, self.projection[0])
            key_value += self.projection[1]
            query, key_value = key_value[..., :self.width], key_value[..., self.width:]
        rows = query.shape[1]
        query = query.reshape(batch, rows, self.heads, -1).transpose(0, 2, 1, 3)  # (M, heads, rows, head)
        key_value = key_value.reshape(batch, steps, 2, self.heads, -1).transpose(2, 0, 3, 1, 4)
        scores = _softmax(matmul(query, key_value[0].transpose(0, 1, 3, 2)))
        mixed = matmul(scores, key_value[1])  # (M, heads, rows, head)
        return self.out(mixed.transpose(0, 2, 1, 3).reshape(batch, rows, self.width))

    def __call__(self, x: np.ndarray, last_only: bool = False) -> np.ndarray:
        rows = x[:, -1:] if last_only else x
        if self.norm_first:
            x = rows + self.attend(_standardize(x, self.eps[0]), last_only)
            return x + self.feedforward(_standardize(x, self.eps[1]))
        (w1, b1), (w2, b2) = self.norms
        x = _standardize(rows + self.attend(x, last_only), self.eps[0]) * w1 + b1
        return _standardize(x + self.feedforward(x), self.eps[1]) * w2 + b2


class FeasibilitySnapshot:
    """A feasibility model's forward pass (F in return units) in numpy.

    Supports :class:`~seqdex_drake.chaining.feasibility.TemporalFeasibility` and
    :class:`~seqdex_drake.chaining.feasibility.MlpFeasibility` (use :func:`snapshot_feasibility` to get None for
    anything else). Call with a (T, obs_dim) history (returns a float) or (B, T, obs_dim) (returns (B,)); like
    ``predict``, histories are cut or left-padded to ``input_length`` with ``pad_history``.

    Args:
        model: the feasibility model; copied, not kept in sync (see :meth:`stale`).
        dtype: arithmetic precision, ``np.float32`` (torch's, default) or ``np.float64``.
    """

    def __init__(self, model, dtype=np.float32):
        tensors = self._tensors = _Tensors(dtype)
        self.dtype = tensors.dtype
        config = model.config
        self.obs_dim, self.input_length = int(model.obs_dim), int(config.input_length)
        self.clip = float(config.obs_clip)
        self.obs_mean = tensors.array(model.obs_mean)[None, None]
        self.obs_std = tensors.array(model.obs_std)[None, None]
        self.return_mean = tensors.array(model.return_mean).reshape(1)
        self.return_std = tensors.array(model.return_std).reshape(1)
        self.temporal = isinstance(model, TemporalFeasibility)
        if self.temporal:
            self.pooling = config.pooling
            self.embed = _Dense([model.embed], tensors, stacked=True)
            self.position = tensors.array(model.position)[None]
            if model.encoder.norm is not None:
                raise TypeError("unsupported encoder with its own final norm")
            self.layers = [_EncoderLayer(layer, tensors) for layer in model.encoder.layers]
            if not isinstance(model.head[0], nn.Linear):
                raise TypeError("unsupported head: it must start with a Linear layer")
            self.head = _Dense(model.head, tensors, stacked=True)
            self.norm_eps = float(model.norm.eps)
            tensors.array(model.norm.weight), tensors.array(model.norm.bias)  # Tracked for staleness.
            # Pooling (last token or mean) commutes with the affine part, so it folds into the head.
            self.head.layers[0] = _fold_norm(model.norm, *self.head.layers[0])
        elif isinstance(model, MlpFeasibility):
            self.head = _Dense(model.mlp, tensors, stacked=True)
        else:
            raise TypeError(f"no numpy version of {type(model).__name__}; use the torch inference path")

    def stale(self) -> bool:
        """True when a copied tensor was modified in place since the snapshot (rebuild it then)."""
        return self._tensors.stale()

    def __call__(self, history):
        x = np.asarray(history, dtype=self.dtype)
        single = x.ndim == 2
        x = pad_history(x[None] if single else x, self.input_length)
        if x.ndim != 3 or x.shape[-1] != self.obs_dim:
            raise ValueError(f"expected a history of shape (T, {self.obs_dim}) or (B, T, {self.obs_dim}), "
                             f"got {np.shape(history)}")
        values = self.forward(x)
        return float(values[0]) if single else values

    def forward(self, x: np.ndarray) -> np.ndarray:
        """F for raw (B, T, obs_dim) histories (no padding), shape (B,); B must be 1 or this snapshot's number
        of stacked models (each row then goes through its own model)."""
        x = (x - self.obs_mean) / self.obs_std
        np.clip(x, -self.clip, self.clip, out=x)
        if not self.temporal:
            pooled = x[:, -1:]
        else:
            steps = x.shape[1]
            if not 1 <= steps <= self.position.shape[1]:
                raise ValueError(f"history length must be in [1, {self.position.shape[1]}], got {steps}")
            tokens = self.embed(x)
            tokens += self.position[:, steps - 1::-1]  # Position 0 is the last step.
            last_only = self.pooling == "last"  # Then the last layer needs only the last token's output.
            for index, layer in enumerate(self.layers):
                tokens = layer(tokens, last_only and index == len(self.layers) - 1)
            encoded = _standardize(tokens, self.norm_eps)
            pooled = encoded[:, -1:] if last_only else encoded.mean(1, keepdims=True)
        return self.head(pooled)[:, 0, 0] * self.return_std + self.return_mean


class _Incompatible(Exception):
    """Two snapshots differ in architecture and cannot be stacked."""


def _stack(items: list):
    """Concatenates parallel snapshot structures along the leading model axis (arrays) or checks they agree."""
    first = items[0]
    if isinstance(first, np.ndarray):
        if any(item.shape[1:] != first.shape[1:] for item in items):
            raise _Incompatible
        return np.concatenate(items)
    if isinstance(first, list | tuple) and not isinstance(first[0] if first else None, type(_standardize)):
        if any(len(item) != len(first) for item in items):
            raise _Incompatible
        return type(first)(_stack(list(parts)) for parts in zip(*items, strict=True))
    if isinstance(first, _Dense | _EncoderLayer):
        stacked = copy.copy(first)
        stacked.__dict__ = {name: _stack([item.__dict__[name] for item in items]) for name in first.__dict__}
        return stacked
    if any(item != first for item in items):
        raise _Incompatible
    return first


def _padded(snapshot: FeasibilitySnapshot, obs_dim: int) -> FeasibilitySnapshot:
    """A shallow copy of ``snapshot`` reading ``obs_dim`` >= its own inputs (the extra ones are zeros): mean 0,
    std 1 and zero first-layer rows for them."""
    extra = obs_dim - snapshot.obs_dim
    if extra == 0:
        return snapshot
    padded = copy.copy(snapshot)
    padded.obs_dim = obs_dim
    padded.obs_mean = np.pad(snapshot.obs_mean, ((0, 0), (0, 0), (0, extra)))
    padded.obs_std = np.pad(snapshot.obs_std, ((0, 0), (0, 0), (0, extra)), constant_values=1.0)
    first = padded.embed if snapshot.temporal else padded.head
    first = copy.copy(first)
    weight, bias = first.layers[0]
    first.layers = [(np.pad(weight, ((0, 0), (0, extra), (0, 0))), bias), *first.layers[1:]]
    if snapshot.temporal:
        padded.embed = first
    else:
        padded.head = first
    return padded


class FeasibilityBank:
    """Evaluates several F's per call; those of one architecture run stacked as one batched pass.

    Args:
        models: the feasibility models (each must be supported by :class:`FeasibilitySnapshot`).
        dtype: arithmetic precision of the snapshots.

    Call with one (T_i, obs_dim_i) history per model (in the order given); returns the (M,) F values.
    """

    def __init__(self, models: Sequence, dtype=np.float32):
        self._models, self._dtype = list(models), dtype
        self.snapshots = [FeasibilitySnapshot(model, dtype) for model in self._models]
        self.groups: list[tuple[list[int], FeasibilitySnapshot]] = []
        for index in range(len(self.snapshots)):
            for position, (members, _) in enumerate(self.groups):
                stacked = self._try_stack([*members, index])
                if stacked is not None:
                    self.groups[position] = ([*members, index], stacked)
                    break
            else:
                self.groups.append(([index], self.snapshots[index]))

    def _try_stack(self, members: list[int]) -> FeasibilitySnapshot | None:
        snapshots = [self.snapshots[i] for i in members]
        width = max(s.obs_dim for s in snapshots)
        padded = [_padded(s, width) for s in snapshots]
        stacked = copy.copy(padded[0])
        try:
            stacked.__dict__ = {name: value if name == "_tensors" else _stack([p.__dict__[name] for p in padded])
                                for name, value in padded[0].__dict__.items()}
        except _Incompatible:
            return None
        return stacked

    def stale(self) -> bool:
        """True when any model's tensors changed in place since the snapshots (rebuild the bank then)."""
        return any(snapshot.stale() for snapshot in self.snapshots)

    def __call__(self, histories: Sequence[np.ndarray]) -> np.ndarray:
        if len(histories) != len(self.snapshots):
            raise ValueError(f"need one history per model ({len(self.snapshots)}), got {len(histories)}")
        values = np.empty(len(self.snapshots))
        for members, stacked in self.groups:
            batch = np.zeros((len(members), stacked.input_length, stacked.obs_dim), dtype=stacked.dtype)
            for row, index in enumerate(members):
                history = np.asarray(histories[index], dtype=stacked.dtype)
                if history.ndim != 2 or history.shape[1] != self.snapshots[index].obs_dim:
                    raise ValueError(f"history {index} must have shape (T, {self.snapshots[index].obs_dim}), got "
                                     f"{history.shape}")
                batch[row, :, :history.shape[1]] = pad_history(history, stacked.input_length)
            values[members] = stacked.forward(batch)
        return values


def snapshot_feasibility(model, dtype=np.float32) -> FeasibilitySnapshot | None:
    """A :class:`FeasibilitySnapshot` of ``model``, or None when ``model`` is not a supported torch F (e.g. a
    hand-written scorer with ``predict``) or is in training mode (dropout active)."""
    try:
        return FeasibilitySnapshot(model, dtype) if isinstance(model, nn.Module) and not model.training else None
    except (TypeError, AttributeError):
        return None
