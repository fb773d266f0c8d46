"""Where a pipeline's envs come from: the process's pool of in-process stage envs, and the env classes the
pipeline is handed by its caller.

The chaining code does not import ``envs/``: stage envs are built through the task registry
(:func:`~seqdex_drake.tasks.registry.make_env`), and the classes that need the env package itself (the worker-
process vector env, the in-process vector env, the whole-chain env of the single-policy baselines) come in as an
:class:`EnvKit`, which the caller builds (``seqdex pipeline`` passes
:func:`seqdex_drake.envs.factory.pipeline_env_kit`). Both :mod:`~seqdex_drake.chaining.bidirectional` and
:mod:`~seqdex_drake.chaining.single_policy` use this module, so neither imports the other in a circle.
"""

import dataclasses
from collections.abc import Callable
from typing import Any

from seqdex_drake.tasks.registry import make_env

#: In-process envs, built once per (task, config, slot) and reused by every phase and pipeline of this process
#: (building a station diagram costs seconds; a reset with a seed makes a reused env as good as new).
_ENV_POOL: dict[tuple, object] = {}


def pooled_env(task: str, config, slot: int):
    """The process's env number ``slot`` for ``task`` with ``config`` (built on first use)."""
    key = (task, repr(config), slot)
    if key not in _ENV_POOL:
        _ENV_POOL[key] = make_env(task, config)
    return _ENV_POOL[key]


@dataclasses.dataclass(frozen=True)
class EnvKit:
    """The env classes (or any callables with their signatures) a pipeline builds its PPO envs from."""

    process_vector_env: Callable[..., Any]
    """``(task, num_envs, seed=, config=, envs_per_worker=)`` -> a vector env stepped in worker processes
    (:class:`~seqdex_drake.envs.vector.ProcessVectorEnv`), for ``backend="process"``."""
    serial_vector_env: Callable[..., Any]
    """``(env_fns, seed=)`` -> a vector env stepped in this process
    (:class:`~seqdex_drake.envs.serial.SerialVectorEnv`), for ``backend="serial"`` and the single-policy
    baselines."""
    chain_env: Callable[..., Any]
    """``(stages, start_stage=, envs=)`` -> one env running the stages back to back
    (:class:`~seqdex_drake.envs.chain_env.ChainEnv`), for RL-scratch and Curriculum RL."""
