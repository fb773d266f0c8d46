"""Fast batch-1 inference: numpy snapshots of the chain's torch networks.

At 60 Hz the chain evaluates one observation (or one H-step history) per network per tick. For inputs that small,
torch's per-operator dispatch costs more than the arithmetic: measured on the 2-core development machine, a
paper-size actor ([1024, 1024, 512]) took ~0.3 ms through torch and an attention F (H = 10, d_model 128, 2
layers) ~1 ms, most of it overhead. The snapshots below copy the weights once into contiguous numpy arrays
(transposed, so that every layer is one ``x @ W`` call) and evaluate the same arithmetic with a handful of numpy
calls.

- :class:`PolicySnapshot`: :meth:`ActorCritic.action_mean <seqdex_drake.rl.networks.ActorCritic.action_mean>`
  (the observation normalizer with its clip, then the actor MLP).
- :class:`~seqdex_drake.systems.inference_feasibility.FeasibilitySnapshot` and
  :class:`~seqdex_drake.systems.inference_feasibility.FeasibilityBank` (several F's in one batched pass): the
  attention and MLP feasibility models, in their own module and re-exported here.
- :func:`limit_blas_threads`: numpy's BLAS on one thread (batch-1 products are far slower multi-threaded on a
  busy machine).

Precision: ``dtype=np.float32`` (the default) runs the same float32 arithmetic as torch in another summation
order, so results agree to about 1e-6 relative (``tests/test_inference.py`` checks 1e-5); ``np.float64`` is
slower (twice the memory traffic) and closer to exact. Dropout is skipped (eval mode).

Staleness: a snapshot records torch's in-place version counter of every tensor it copied; :meth:`stale` is True
after any of them changed in place (an optimizer step, ``load_state_dict``, ``copy_``), and the hosting systems
re-snapshot then. Replacing a parameter object (``layer.weight = nn.Parameter(...)``) is not detected: build a
new snapshot (or a new system) after that.
"""

from __future__ import annotations

import ctypes
import operator
from pathlib import Path

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
            snapshots can be concatenated (:class:`~seqdex_drake.systems.inference_feasibility.FeasibilityBank`);
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


# ----------------------------------------------------------------------------------------------- snapshots
class PolicySnapshot:
    """``ActorCritic.action_mean`` in numpy: clip((obs - mean) / sqrt(var + eps)) through the actor MLP, then the
    model's fixed action dims (its ``action_fixed`` buffer, NaN = free, when it has one) set to their values.

    Args:
        model: the actor-critic (an :class:`~seqdex_drake.rl.networks.ActorCritic`); copied, not kept in sync
            (see :meth:`stale`).
        dtype: arithmetic precision, ``np.float32`` (torch's, default) or ``np.float64``.

    Call with one raw observation (obs_dim,) for an action (action_dim,), or (B, obs_dim) for (B, action_dim).
    """

    def __init__(self, model, dtype=np.float32):
        tensors = self._tensors = _Tensors(dtype)
        self.dtype = tensors.dtype
        self.obs_dim, self.action_dim = int(model.obs_dim), int(model.action_dim)
        self.normalize = bool(model.normalize_observations)
        normalizer = model.obs_normalizer
        self.clip = float(normalizer.clip)
        with torch.no_grad():  # torch normalizes in the observation's dtype: cast the statistics, then sqrt.
            torch_dtype = torch.float64 if self.dtype == np.float64 else torch.float32
            std = torch.sqrt(normalizer.var.to(torch_dtype) + normalizer.epsilon)
        self.mean = tensors.array(normalizer.mean)
        tensors.array(normalizer.var)  # Tracked for staleness; the copy used is ``std``.
        self.std = np.ascontiguousarray(std.numpy(), dtype=self.dtype)
        self.actor = _Dense(model.actor, tensors)
        fixed = getattr(model, "action_fixed", None)
        self.fixed = None if fixed is None else tensors.array(fixed)
        if self.fixed is not None and np.isnan(self.fixed).all():
            self.fixed = None  # Every dim free: the actor's output as it is.

    def stale(self) -> bool:
        """True when a copied tensor was modified in place since the snapshot (rebuild it then)."""
        return self._tensors.stale()

    def __call__(self, observation) -> np.ndarray:
        x = np.asarray(observation, dtype=self.dtype)
        if x.shape[-1] != self.obs_dim:
            raise ValueError(f"expected observations with {self.obs_dim} entries, got shape {x.shape}")
        if self.normalize:
            x = (x - self.mean) / self.std
            np.clip(x, -self.clip, self.clip, out=x)
        action = self.actor(x)
        if self.fixed is not None:
            action = np.where(np.isnan(self.fixed), action, self.fixed)
        return action


def limit_blas_threads(threads: int = 1) -> bool:
    """Sets the thread count of numpy's BLAS (process-wide, like ``torch.set_num_threads``); True if it was set.

    Batch-1 products are far faster on one thread: on the loaded 2-core development machine a 1 x 1024 by
    1024 x 1024 float32 product took 6.2 ms with OpenBLAS's default 2 threads and 0.09 ms with 1 (the workers
    wait for a core). Uses ``threadpoolctl`` when installed, else the ``*set_num_threads*`` entry point of the
    OpenBLAS bundled with numpy's wheel (the environment variable ``OPENBLAS_NUM_THREADS`` only counts before
    numpy is imported). Returns False when neither is found (another BLAS): nothing is changed then.
    """
    try:
        import threadpoolctl
    except ImportError:
        pass
    else:
        return bool(threadpoolctl.threadpool_limits(int(threads), user_api="blas")._original_info)
    names = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
             "openblas_set_num_threads")
    done = False
    for path in sorted((Path(np.__file__).resolve().parent.parent / "numpy.libs").glob("*openblas*.so*")):
        try:
            library = ctypes.CDLL(str(path))  # Already loaded by numpy: this returns the same library.
        except OSError:
            continue
        function = next((getattr(library, name) for name in names if hasattr(library, name)), None)
        if function is not None:
            function(ctypes.c_int(int(threads)))
            done = True
    return done


_FEASIBILITY_NAMES = ("FeasibilityBank", "FeasibilitySnapshot", "snapshot_feasibility")


def __getattr__(name: str):
    """Re-exports the feasibility snapshots from ``inference_feasibility`` (lazily: that module builds on the
    blocks above, so importing it here at load time would be circular)."""
    if name in _FEASIBILITY_NAMES:
        from seqdex_drake.systems import inference_feasibility

        return getattr(inference_feasibility, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["PolicySnapshot", "limit_blas_threads", *_FEASIBILITY_NAMES]
