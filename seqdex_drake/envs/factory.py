"""One entry point for vector envs, whichever backend runs the workers.

``make_vector_env(task, num_envs, seed, config, backend="process" | "ray", **kwargs)``: the process backend
(:class:`~seqdex_drake.envs.vector.ProcessVectorEnv`, forkserver processes on this machine, ``envs_per_worker``
envs each) or the Ray backend (:class:`~seqdex_drake.envs.ray_vector.RayVectorEnv`, one Ray actor per env, local
or on a cluster via ``address=``). Both have the same interface, seeding and autoreset, so the same seed gives
the same rollouts.

``pipeline_env_kit()``: the env classes a chaining :class:`~seqdex_drake.chaining.bidirectional.Pipeline` builds its
PPO envs from (``chaining/`` does not import ``envs/``; its caller hands them in).
"""

from seqdex_drake.tasks.base import TaskConfig

#: The backend names :func:`make_vector_env` accepts.
BACKENDS = ("process", "ray")


def make_vector_env(task: str, num_envs: int, seed: int = 0, config: TaskConfig | None = None,
                    backend: str = "process", **kwargs):
    """A vector env of ``num_envs`` copies of sub-task ``task`` (env ``i`` seeded ``seed + i``).

    Args:
        task: a registered sub-task name.
        num_envs: number of envs.
        seed: the base seed.
        config: the task config (default: the task's ``default_config()``).
        backend: ``"process"`` or ``"ray"``.
        kwargs: backend options: ``timeout``, ``max_restarts`` (both); ``start_method``, ``envs_per_worker``
            (process); ``address``, ``num_cpus``, ``cpus_per_worker`` (ray).
    """
    if backend == "process":
        from seqdex_drake.envs.vector import ProcessVectorEnv

        return ProcessVectorEnv(task, num_envs, seed=seed, config=config, **kwargs)
    if backend == "ray":
        from seqdex_drake.envs.ray_vector import RayVectorEnv

        return RayVectorEnv(task, num_envs, seed=seed, config=config, **kwargs)
    raise ValueError(f"unknown vector env backend {backend!r}; choose one of {', '.join(BACKENDS)}")


def pipeline_env_kit():
    """This package's :class:`~seqdex_drake.chaining.stage_envs.EnvKit`: worker-process vector envs
    (:class:`~seqdex_drake.envs.vector.ProcessVectorEnv`), in-process ones
    (:class:`~seqdex_drake.envs.serial.SerialVectorEnv`) and the whole-chain env
    (:class:`~seqdex_drake.envs.chain_env.ChainEnv`), for ``Pipeline(..., env_kit=pipeline_env_kit())``."""
    from seqdex_drake.chaining.stage_envs import EnvKit
    from seqdex_drake.envs.chain_env import ChainEnv
    from seqdex_drake.envs.serial import SerialVectorEnv
    from seqdex_drake.envs.vector import ProcessVectorEnv

    return EnvKit(process_vector_env=ProcessVectorEnv, serial_vector_env=SerialVectorEnv, chain_env=ChainEnv)
