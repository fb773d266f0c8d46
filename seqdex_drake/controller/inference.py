"""Fast batch-1 inference: numpy snapshots of the chain's torch networks.

At 60 Hz the chain evaluates one observation (or one H-step history) per network per tick. For inputs that small,
torch's per-operator dispatch costs more than the arithmetic: measured on the 2-core development machine, a
paper-size actor ([1024, 1024, 512]) took ~0.3 ms through torch and an attention F (H = 10, d_model 128, 2
layers) ~1 ms, most of it overhead. The snapshots below copy the weights once into contiguous numpy arrays
(transposed, so that every layer is one ``x @ W`` call) and evaluate the same arithmetic with a handful of numpy
calls.

- :class:`PolicySnapshot`: :meth:`ActorCritic.action_mean <seqdex_drake.rl.networks.ActorCritic.action_mean>`
  (the observation normalizer with its clip, then the actor MLP).
- :class:`~seqdex_drake.controller.inference_feasibility.FeasibilitySnapshot` and
  :class:`~seqdex_drake.controller.inference_feasibility.FeasibilityBank` (several F's in one batched pass): the
  attention and MLP feasibility models, in their own module and re-exported here (the numpy building blocks
  both use are in :mod:`~seqdex_drake.controller.inference_blocks`).
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
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.controller.inference_blocks import _Dense, _Tensors
from seqdex_drake.controller.inference_feasibility import FeasibilityBank, FeasibilitySnapshot, snapshot_feasibility


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
        import threadpoolctl  # Optional: not a dependency; else OpenBLAS's own entry point.
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


__all__ = ["FeasibilityBank", "FeasibilitySnapshot", "PolicySnapshot", "limit_blas_threads", "snapshot_feasibility"]
