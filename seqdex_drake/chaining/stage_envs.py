"""Where a pipeline's envs come from: the process's pool of in-process stage envs, and the env classes the
pipeline is handed by its caller.

Stage envs are built with :func:`~seqdex_drake.envs.subtask_env.make_env`; the vector envs of the PPO phases
and the whole-chain env of the single-policy baselines come from an :class:`EnvKit` (:func:`default_env_kit`:
this package's env classes; a caller may hand in others with the same signatures). Both
:mod:`~seqdex_drake.chaining.bidirectional` and
:mod:`~seqdex_drake.chaining.single_policy` use this module, so neither imports the other in a circle.
"""

import dataclasses
from collections.abc import Callable
from typing import Any

from seqdex_drake.envs.chain_env import ChainEnv
from seqdex_drake.envs.serial import SerialVectorEnv
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.envs.vector import ProcessVectorEnv

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


def default_env_kit() -> EnvKit:
    """This package's :class:`EnvKit`: worker-process vector envs
    (:class:`~seqdex_drake.envs.vector.ProcessVectorEnv`), in-process ones
    (:class:`~seqdex_drake.envs.serial.SerialVectorEnv`) and the whole-chain env
    (:class:`~seqdex_drake.envs.chain_env.ChainEnv`)."""
    return EnvKit(process_vector_env=ProcessVectorEnv, serial_vector_env=SerialVectorEnv, chain_env=ChainEnv)
