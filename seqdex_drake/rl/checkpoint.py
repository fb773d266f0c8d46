"""Full-state checkpoints (rl_games style), written atomically.

A checkpoint is one ``torch.save`` file holding a dict: the model ``state_dict`` (its observation normalizers
included), the optimizer state, the training counters, the config as plain data, every RNG state and the best
metric so far (see :meth:`seqdex_drake.rl.ppo.PPO.state_dict`). It holds only tensors and plain python data,
so it loads with ``torch.load(weights_only=True)``: loading never executes pickled code.

Writes go to a temporary file in the destination directory, which is flushed, fsynced and then renamed over the
destination with ``os.replace`` (atomic on POSIX and Windows): a crash leaves either the old file or the new one,
never a half-written one, and the temporary file is removed on failure.
"""

import os
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seqdex_drake.atomic import atomic_write

FORMAT = "seqdex_drake.rl.checkpoint"
VERSION = 1


class CheckpointError(RuntimeError):
    """A checkpoint file exists but cannot be used (corrupt, truncated, or not one of ours)."""


def capture_rng_state(generators: dict[str, torch.Generator | np.random.Generator] | None = None) -> dict:
    """The states of python's ``random``, numpy's global generator, torch's CPU (and CUDA) generators and of any
    named extra ``torch.Generator`` / ``numpy.random.Generator``, as plain data."""
    kind, keys, position, has_gauss, cached_gaussian = np.random.get_state()
    state = {
        "python": random.getstate(),
        "numpy": {"kind": kind, "keys": keys.tolist(), "position": int(position), "has_gauss": int(has_gauss),
                  "cached_gaussian": float(cached_gaussian)},
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "generators": {},
    }
    for name, generator in (generators or {}).items():
        if isinstance(generator, torch.Generator):
            state["generators"][name] = generator.get_state()
        else:
            state["generators"][name] = generator.bit_generator.state
    return state


def restore_rng_state(state: dict, generators: dict[str, torch.Generator | np.random.Generator] | None = None):
    """Inverse of :meth:`capture_rng_state`; ``generators`` are restored in place by name."""
    random.setstate(state["python"])
    numpy_state = state["numpy"]
    np.random.set_state((numpy_state["kind"], np.asarray(numpy_state["keys"], dtype=np.uint32),
                         numpy_state["position"], numpy_state["has_gauss"], numpy_state["cached_gaussian"]))
    torch.set_rng_state(state["torch"])
    if state["cuda"] and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    for name, generator in (generators or {}).items():
        if name not in state["generators"]:
            raise CheckpointError(f"the checkpoint has no state for the random generator {name!r}")
        if isinstance(generator, torch.Generator):
            generator.set_state(state["generators"][name])
        else:
            generator.bit_generator.state = state["generators"][name]




def save_checkpoint(path: str | os.PathLike, checkpoint: dict[str, Any]) -> Path:
    """Atomically writes ``checkpoint`` (plain data and tensors) to ``path``; returns the path.

    The dict gets ``format`` and ``version`` keys. The parent directory is created if needed.
    """
    path = Path(path)
    payload = {"format": FORMAT, "version": VERSION, **checkpoint}
    atomic_write(path, lambda file: torch.save(payload, file))
    return path


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu",
                    required_keys: tuple[str, ...] = ()) -> dict[str, Any]:
    """Reads a checkpoint written by :func:`save_checkpoint`.

    Raises:
        FileNotFoundError: ``path`` does not exist (the message names it and the run directory's contents).
        CheckpointError: the file is corrupt, truncated, not a checkpoint of this project, of another format
            version, or lacks one of ``required_keys``; the message names the path and what to do.
    """
    path = Path(path)
    if not path.is_file():
        siblings = sorted(p.name for p in path.parent.glob("*.pt")) if path.parent.is_dir() else []
        raise FileNotFoundError(f"checkpoint {path} does not exist (checkpoints in {path.parent}: "
                                f"{siblings or 'none'}); pass an existing last.pt / best.pt or start without "
                                f"resuming")
    advice = "delete it and resume from another checkpoint of the run (last.pt or best.pt), or start afresh"
    try:
        checkpoint = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises many types for damaged files; all mean "corrupt".
        raise CheckpointError(f"checkpoint {path} is corrupt or unreadable ({type(error).__name__}: "
                              f"{str(error).splitlines()[0] if str(error) else ''}); {advice}") from error
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a seqdex_drake training checkpoint (no '{FORMAT}' format tag); "
                              f"{advice}")
    if checkpoint.get("version") != VERSION:
        raise CheckpointError(f"checkpoint {path} has format version {checkpoint.get('version')}, this code "
                              f"reads version {VERSION}; use the matching code version or start afresh")
    missing = [key for key in required_keys if key not in checkpoint]
    if missing:
        raise CheckpointError(f"checkpoint {path} lacks {missing}; {advice}")
    return checkpoint
