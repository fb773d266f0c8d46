"""A Ray vector environment: one sub-task environment per Ray actor, on this machine or on a Ray cluster.

Same interface and semantics as :class:`~seqdex_drake.envs.vector.ProcessVectorEnv` (seeding, SB3-style
autoreset, ``reset_at``, ``get_states``, :class:`~seqdex_drake.envs.vector_base.WorkerError` on a failed actor,
opt-in restarts; see :mod:`seqdex_drake.envs.vector_base`), so the same seeds give the same observations and
rewards. Each actor builds its own env from plain data (the task name and a picklable
:class:`~seqdex_drake.tasks.base.TaskConfig`): Drake diagrams, contexts and simulators do not pickle.

Ray itself: if Ray is not initialized, the env starts a local Ray instance (:func:`init_ray`: every listener on
127.0.0.1, no dashboard, no usage statistics; offline-safe) and shuts it down on :meth:`RayVectorEnv.close`; pass
``address=`` to join an existing cluster instead (``"auto"``, ``"host:6379"`` or ``"ray://host:10001"``), whose
nodes must have this package installed. If Ray is already initialized (by you, or a test fixture), the env uses
that instance and leaves it running. Ray is an optional dependency: ``pip install "seqdex_drake[distributed]"``.
"""

import math
import os
import time

from seqdex_drake.envs.vector_base import EnvWorker, VectorEnvBase, WorkerError
from seqdex_drake.tasks.base import TaskConfig

__all__ = ["RayVectorEnv", "WorkerError", "import_ray", "init_ray"]


def import_ray():
    """The ``ray`` module, or an ImportError saying how to install it."""
    try:
        import ray  # Optional: the distributed extra; the error says how to install it.
    except ImportError as error:
        raise ImportError("the Ray vector env backend needs ray, which is not installed: install the distributed "
                          "extra (pip install \"seqdex_drake[distributed]\") or use backend='process'") from error
    return ray


def init_ray(num_cpus: int | None = None, address: str | None = None, **init_kwargs) -> bool:
    """Initializes Ray unless it already is; returns True if this call started it.

    Without ``address`` a local instance is started with every listener and connection on 127.0.0.1
    (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` and ``_node_ip_address="127.0.0.1"``; otherwise Ray binds to the
    machine's external interface), no dashboard and no usage statistics. With ``address`` the driver joins that
    cluster. ``init_kwargs`` go to ``ray.init`` (they override these defaults).
    """
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address is None:
        # Ray reads this when it is first imported (and its node processes inherit it): set it before.
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    ray = import_ray()
    if ray.is_initialized():
        return False
    if address is None:
        constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
        if os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] == "0" and getattr(constants, "ENABLE_RAY_CLUSTER", 0):
            constants.ENABLE_RAY_CLUSTER = False  # Ray was imported before the variable was set.
        kwargs = dict(num_cpus=num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                      log_to_driver=False)
    else:
        kwargs = dict(address=address, log_to_driver=False)
    kwargs.update(init_kwargs)
    ray.init(**kwargs)
    return True


class _EnvActor:
    """A Ray actor holding one :class:`~seqdex_drake.envs.vector_base.EnvWorker` (wrapped by ``ray.remote``)."""

    def __init__(self, task_name: str, config: TaskConfig | None):
        import torch  # Keep the actor single-threaded, as the process workers are.

        torch.set_num_threads(1)
        self.worker = EnvWorker(task_name, config)

    def call(self, command: str, data):
        return self.worker.handle(command, data)


class RayVectorEnv(VectorEnvBase):
    """``num_envs`` copies of one sub-task environment, each in its own Ray actor.

    Args:
        task_name: a registered sub-task (``seqdex_drake.tasks.registry.task_names()``).
        num_envs: number of actors (one env each).
        seed: env ``i`` is seeded ``seed + i`` at the first reset.
        config: the task config for every actor (default: the task's ``default_config()``).
        timeout: seconds to wait for the actors' answers to one call (actor start and scheduling included)
            before raising :class:`WorkerError`.
        max_restarts: how many actor failures (over the env's life) are answered by starting a new actor
            instead of raising :class:`WorkerError`; 0 (default) raises on the first failure.
        address: join this Ray cluster (see :func:`init_ray`); ``None`` starts a local instance when Ray is
            not initialized yet.
        num_cpus: CPUs of a local Ray instance this env starts (default: the machine's count, at least enough
            for every actor).
        cpus_per_worker: CPUs each actor reserves (Ray scheduling; a fraction packs several per core).
    """

    backend = "ray"

    def __init__(self, task_name: str, num_envs: int, seed: int = 0, config: TaskConfig | None = None,
                 timeout: float = 300.0, max_restarts: int = 0, address: str | None = None,
                 num_cpus: int | None = None, cpus_per_worker: float = 1.0):
        if cpus_per_worker <= 0:
            raise ValueError(f"cpus_per_worker must be > 0, got {cpus_per_worker}")
        self._actors, self._pending, self._owns_ray = [None] * max(num_envs, 0), {}, False
        super().__init__(task_name, num_envs, seed, config, timeout, max_restarts)
        self._ray = ray = import_ray()
        needed = math.ceil(num_envs * cpus_per_worker)
        self._owns_ray = init_ray(num_cpus=num_cpus or max(os.cpu_count() or 1, needed), address=address)
        self._actor_class = ray.remote(_EnvActor).options(num_cpus=cpus_per_worker, max_restarts=0)
        self._start()

    # ------------------------------------------------------------------------------------ transport
    def _start_worker(self, index: int) -> None:
        self._actors[index] = self._actor_class.remote(self.task_name, self.config)
        self._pending[index] = self._actors[index].call.remote("spaces", None)

    def _request(self, index: int, command: str, data) -> None:
        self._pending[index] = self._actors[index].call.remote(command, data)

    def _answers(self, indices) -> dict:
        ray, exceptions = self._ray, self._ray.exceptions
        indices = list(indices)
        references = [self._pending.pop(index) for index in indices]
        if not references:
            return {}
        ready, _ = ray.wait(references, num_returns=len(references), timeout=self.timeout)
        ready = set(ready)
        answers = {}
        for index, reference in zip(indices, references, strict=True):
            if reference not in ready:
                answers[index] = WorkerError(index, f"no answer within {self.timeout:g} s (a stalled actor, or "
                                                    f"one the cluster could not schedule: {self._resources()})")
                continue
            try:
                answers[index] = ray.get(reference, timeout=self.timeout)
            except exceptions.RayActorError as error:
                answers[index] = WorkerError(index, f"the actor died: {error}")
            except exceptions.RayTaskError as error:
                answers[index] = WorkerError(index, f"actor {index} ({self.task_name}):\n{error}")
            except exceptions.RayError as error:
                answers[index] = WorkerError(index, f"{type(error).__name__}: {error}")
        return answers

    def _resources(self) -> str:
        try:
            return f"available {self._ray.available_resources()}"
        except Exception as error:  # noqa: BLE001 - only a diagnostic; Ray may be half shut down.
            return f"resources unknown ({error})"

    def _kill_worker(self, index: int) -> None:
        actor = self._actors[index]
        self._pending.pop(index, None)
        self._actors[index] = None
        if actor is not None and self._ray.is_initialized():  # Never auto-start Ray just to kill (at exit).
            self._ray.kill(actor, no_restart=True)

    def _close_workers(self, timeout: float) -> None:
        if not hasattr(self, "_ray"):
            return
        for index in range(len(self._actors)):
            self._kill_worker(index)
        if self._owns_ray and self._ray.is_initialized():
            deadline = time.monotonic() + timeout  # Let the actor processes go before Ray itself.
            while time.monotonic() < deadline and self._alive_pids():
                time.sleep(0.05)
            self._ray.shutdown()

    def _alive_pids(self) -> list[int]:
        alive = []
        for pid in self._pids:
            if pid is None:
                continue
            try:
                os.kill(pid, 0)
                alive.append(pid)
            except OSError:
                pass
        return alive
