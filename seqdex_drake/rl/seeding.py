"""One place that seeds every random number generator of a training process (SB3's ``set_random_seed``)."""

import random

import numpy as np
import torch


def seed_everything(seed: int, rank: int = 0, deterministic: bool = True) -> int:
    """Seeds python's ``random``, numpy's global generator and torch (CPU and, if present, CUDA).

    Args:
        seed: the run's seed.
        rank: index of this process among cooperating processes (learner 0, workers 1, ...); the effective seed
            is ``seed + rank`` so that processes draw different streams. Env ``i`` of a vector env is seeded
            ``seed + i`` by the vector env itself.
        deterministic: also select deterministic cuDNN kernels (cheap; CPU kernels are deterministic already
            for a fixed thread count).

    Returns:
        The effective seed ``seed + rank``.
    """
    effective = int(seed) + int(rank)
    random.seed(effective)
    np.random.seed(effective % 2**32)
    torch.manual_seed(effective)  # Also seeds every CUDA device.
    if deterministic:
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False
    return effective
