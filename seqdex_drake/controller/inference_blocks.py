"""The building blocks of the numpy inference snapshots: numpy versions of torch's activations, the collector of
copied tensors (with their in-place version counters, for staleness) and the dense-stack evaluator.

They sit in their own module, under both :mod:`seqdex_drake.controller.inference` (the policy snapshot, and the
public entry point that re-exports the feasibility snapshots) and
:mod:`seqdex_drake.controller.inference_feasibility` (the feasibility snapshots), so that each of those imports them
and neither imports the other in a circle. Not a public API.
"""

from __future__ import annotations

import operator

import numpy as np
import torch
from torch import nn
from torch.nn import functional

_VERSION = operator.attrgetter("_version")  # A tensor's in-place modification counter.
_SELU_ALPHA, _SELU_SCALE = 1.6732632423543772848170429916717, 1.0507009873554804934193349852946


# ------------------------------------------------------------------------------------------- activations
def _elu(x: np.ndarray, alpha: float = 1.0) -> np.ndarray:
    """ELU in place: ``max(x, 0) + alpha * expm1(min(x, 0))`` (no overflow for large x)."""
    negative = np.minimum(x, 0.0)
    np.expm1(negative, out=negative)
    if alpha != 1.0:
        negative *= alpha
    np.maximum(x, 0.0, out=x)
    x += negative
    return x


def _selu(x: np.ndarray) -> np.ndarray:
    _elu(x, _SELU_ALPHA)
    x *= _SELU_SCALE
    return x


def _gelu(x: np.ndarray, approximate: str = "none") -> np.ndarray:
    """GELU through torch's own kernel on a zero-copy view (one call; numpy has no vectorized erf, and scipy's
    took twice as long as torch's for the encoder's 10 x 256 activations)."""
    return functional.gelu(torch.from_numpy(x), approximate=approximate).numpy()


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


def _tanh(x: np.ndarray) -> np.ndarray:
    return np.tanh(x, out=x)


def _activation(module) -> tuple | None:
    """``(numpy function, extra arguments)`` for a torch activation module or function (a tuple, so that two
    snapshots' layers compare equal when stacking); None for no-ops (Dropout, Identity)."""
    if isinstance(module, nn.Dropout | nn.Identity):
        return None
    if isinstance(module, nn.ELU):
        return _elu, (float(module.alpha),)
    if isinstance(module, nn.GELU):
        return _gelu, (str(module.approximate),)
    simple = {nn.ReLU: _relu, nn.Tanh: _tanh, nn.SELU: _selu, functional.relu: _relu, functional.gelu: _gelu}
    for key, function in simple.items():
        if module is key or (isinstance(key, type) and isinstance(module, key)):
            return function, ()
    raise TypeError(f"no numpy version of the activation {module!r}; use the torch inference path")


# ------------------------------------------------------------------------------------------- building blocks
class _Tensors:
    """Collects the torch tensors a snapshot copies, with their in-place version counters."""

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self._tensors: list[torch.Tensor] = []
        self._versions: list[int] | None = []

    def array(self, tensor: torch.Tensor, transpose: bool = False) -> np.ndarray:
        """A contiguous numpy copy of ``tensor`` (transposed if asked) in the snapshot's dtype."""
        if self._versions is not None:
            try:
                self._versions.append(tensor._version)
                self._tensors.append(tensor)
            except RuntimeError:  # Inference tensors have no version counter: no staleness tracking.
                self._versions = None
        value = tensor.detach().to("cpu", torch.float64 if self.dtype == np.float64 else torch.float32).numpy()
        # Always a copy: ``numpy()`` shares the parameter's memory, and snapshots fold constants in place.
        return np.array(value.T if transpose else value, dtype=self.dtype, order="C", copy=True)

    def stale(self) -> bool:
        if self._versions is None:
            return False
        return list(map(_VERSION, self._tensors)) != self._versions


class _Dense:
    """Linear layers, each optionally followed by an activation (Dropout and Identity skipped), row-wise.

    Args:
        modules: an ``nn.Sequential`` or any sequence of ``nn.Linear`` and activation modules or functions.
        tensors: the snapshot's tensor collector.
        stacked: store weights (1, in, out) and biases (1, 1, out), with a leading model axis along which several
            snapshots can be concatenated (:class:`~seqdex_drake.controller.inference_feasibility.FeasibilityBank`);
            else (in, out) and (out,).
    """

    def __init__(self, modules, tensors: _Tensors, stacked: bool = False):
        sequential = list(modules)
        self.layers: list[tuple[np.ndarray, np.ndarray | None]] = []
        self.activations: list[tuple | None] = []
        for module in sequential:
            if isinstance(module, nn.Linear):
                weight = tensors.array(module.weight, transpose=True)
                bias = None if module.bias is None else tensors.array(module.bias)
                if stacked:
                    weight, bias = weight[None], None if bias is None else bias[None, None]
                self.layers.append((weight, bias))
                self.activations.append(None)
            else:
                function = _activation(module)
                if function is not None:
                    if not self.layers or self.activations[-1] is not None:
                        raise TypeError(f"unsupported layer order in {sequential}: an activation must follow a Linear")
                    self.activations[-1] = function
        if not self.layers:
            raise TypeError(f"{sequential} has no Linear layer")

    def __call__(self, x: np.ndarray) -> np.ndarray:
        for (weight, bias), activation in zip(self.layers, self.activations, strict=True):
            x = x @ weight
            if bias is not None:
                x += bias
            if activation is not None:
                x = activation[0](x, *activation[1])
        return x
