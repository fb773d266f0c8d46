"""One entry point for vector envs, whichever backend runs the workers.

``make_vector_env(task, num_envs, seed, config, backend="process" | "ray", **kwargs)``: the process backend
(:class:`~seqdex_drake.envs.vector.ProcessVectorEnv`, forkserver processes on this machine, ``envs_per_worker``
envs each) or the Ray backend (:class:`~seqdex_drake.envs.ray_vector.RayVectorEnv`, one Ray actor per env, local
or on a cluster via ``address=``). Both have the same interface, seeding and autoreset, so the same seed gives
the same rollouts.
"""

from seqdex_drake.envs.ray_vector import RayVectorEnv
from seqdex_drake.envs.vector import ProcessVectorEnv
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
        return ProcessVectorEnv(task, num_envs, seed=seed, config=config, **kwargs)
    if backend == "ray":
        return RayVectorEnv(task, num_envs, seed=seed, config=config, **kwargs)
    raise ValueError(f"unknown vector env backend {backend!r}; choose one of {', '.join(BACKENDS)}")

