"""The building blocks of the numpy inference snapshots: numpy versions of torch's activations, the collector of
copied tensors (with their in-place version counters, for staleness) and the dense-stack evaluator.

Bits that do not depend on the machine. numpy picks its BLAS kernels (OpenBLAS's per-CPU GEMM) and its ufunc
loops (``exp``, ``tanh``: AVX2 or AVX-512 implementations) from the CPU it runs on, and each gives other last
bits: the same shipped policy gave four different outputs on one machine under four CPU-feature settings, so a
chain episode recorded on one machine played differently on another (the chain is chaotic: a last-bit change
in one action moves the whole episode). The snapshots therefore use only arithmetic whose bits are fixed by
IEEE 754 and numpy's code, whatever the CPU: :func:`matmul` (``np.einsum``'s own loops, never BLAS),
elementwise ``+ - * /`` and ``sqrt`` (correctly rounded everywhere), ``np.sum`` (numpy's pairwise summation),
and :func:`exp` and :func:`erf` evaluated here in float64 from those operations alone.

They sit in their own module, under both :mod:`seqdex_drake.controller.inference` (the policy snapshot, and the
public entry point that re-exports the feasibility snapshots) and
:mod:`seqdex_drake.controller.inference_feasibility` (the feasibility snapshots), so that each of those imports them
and neither imports the other in a circle. Not a public API.
"""

from __future__ import annotations

import math
import operator

import numpy as np
import torch
from torch import nn
from torch.nn import functional

_VERSION = operator.attrgetter("_version")  # A tensor's in-place modification counter.
_SELU_ALPHA, _SELU_SCALE = 1.6732632423543772848170429916717, 1.0507009873554804934193349852946


# ------------------------------------------------------------------------------ machine-independent arithmetic
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10  # Cody-Waite split of ln 2.
_EXP_TAYLOR = tuple(1.0 / math.factorial(k) for k in range(14))  # e^r to 1e-17 for |r| <= ln(2) / 2.
#: Abramowitz & Stegun 7.1.26: erf to 1.5e-7 (about a float32 ulp at 1), from +, *, / and exp alone.
_ERF_P, _ERF_A = 0.3275911, (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` (``b`` a matrix, or a stack broadcast against ``a``'s leading axes) through ``np.einsum``'s own
    loops, which numpy never hands to BLAS (without ``optimize``): the same bits on every CPU."""
    if b.ndim == 2:
        return np.einsum("...j,jk->...k", a, b)
    if a.ndim == 1:  # A vector times a stack of matrices, as numpy's matmul: the vector's axis is contracted.
        return np.einsum("j,...jk->...k", a, b)
    return np.einsum("...ij,...jk->...ik", a, b)


def exp(x: np.ndarray) -> np.ndarray:
    """e^x in ``x``'s dtype, computed in float64 by range reduction (x = k ln 2 + r) and a Taylor polynomial in
    r, from correctly rounded operations only (within 2 float64 ulps; float32 results are almost always
    torch's)."""
    x64 = np.clip(np.asarray(x, dtype=np.float64), -745.0, 709.0)
    k = np.rint(x64 * (1.0 / math.log(2.0)))
    r = (x64 - k * _LN2_HI) - k * _LN2_LO
    p = np.full_like(r, _EXP_TAYLOR[-1])
    for coefficient in _EXP_TAYLOR[-2::-1]:
        p *= r
        p += coefficient
    return np.ldexp(p, k.astype(np.int64)).astype(np.asarray(x).dtype, copy=False)


def erf(x: np.ndarray) -> np.ndarray:
    """erf(x) in ``x``'s dtype to 1.5e-7 (Abramowitz & Stegun 7.1.26, in float64 with :func:`exp`)."""
    x64 = np.asarray(x, dtype=np.float64)
    t = 1.0 / (1.0 + _ERF_P * np.abs(x64))
    poly = np.full_like(t, _ERF_A[-1])
    for coefficient in _ERF_A[-2::-1]:
        poly *= t
        poly += coefficient
    value = 1.0 - poly * t * exp(-(x64 * x64))
    return np.copysign(value, x64).astype(np.asarray(x).dtype, copy=False)


# ------------------------------------------------------------------------------------------- activations
def _elu(x: np.ndarray, alpha: float = 1.0) -> np.ndarray:
    """ELU in place: ``max(x, 0) + alpha * (exp(min(x, 0)) - 1)`` (:func:`exp`, in float64: no overflow for large
    x, and the subtraction's cancellation near 0 costs nothing at float32)."""
    negative = np.minimum(x, 0.0).astype(np.float64)
    negative = exp(negative) - 1.0
    if alpha != 1.0:
        negative *= alpha
    np.maximum(x, 0.0, out=x)
    x += negative.astype(x.dtype, copy=False)
    return x


def _selu(x: np.ndarray) -> np.ndarray:
    _elu(x, _SELU_ALPHA)
    x *= _SELU_SCALE
    return x


def _gelu(x: np.ndarray, approximate: str = "none") -> np.ndarray:
    """GELU: ``x / 2 (1 + erf(x / sqrt 2))``, or with ``approximate="tanh"`` torch's tanh form (:func:`erf`,
    :func:`_tanh`; torch's own kernel differs between CPUs)."""
    x64 = np.asarray(x, dtype=np.float64)
    if approximate == "tanh":
        inner = math.sqrt(2.0 / math.pi) * (x64 + 0.044715 * x64 * x64 * x64)
        value = 0.5 * x64 * (1.0 + _tanh(inner))
    else:
        value = 0.5 * x64 * (1.0 + erf(x64 * (1.0 / math.sqrt(2.0))))
    return value.astype(x.dtype, copy=False)


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


def _tanh(x: np.ndarray) -> np.ndarray:
    """tanh x = 1 - 2 / (e^(2x) + 1) (:func:`exp`, in float64)."""
    x64 = np.asarray(x, dtype=np.float64)
    return (1.0 - 2.0 / (exp(2.0 * x64) + 1.0)).astype(x.dtype, copy=False)


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
            x = matmul(x, weight)
            if bias is not None:
                x += bias
            if activation is not None:
                x = activation[0](x, *activation[1])
        return x
