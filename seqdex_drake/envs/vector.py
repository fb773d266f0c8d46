"""A process-based vector environment: one sub-task environment per worker process.

Each worker builds its own :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` from plain data (the task name and a
picklable :class:`~seqdex_drake.tasks.base.TaskConfig`), because Drake diagrams, contexts and simulators do not
pickle; only numpy arrays, floats, dicts and :class:`~seqdex_drake.envs.subtask_env.EnvState` cross the pipes.
Workers start with ``forkserver`` by default (``spawn`` also works): a plain ``fork`` after the parent used torch
can hang (see SB3's ``SubprocVecEnv``). No visualizer is ever attached in a worker. The vector-env semantics
(seeding, autoreset, failures, restarts) live in :class:`~seqdex_drake.envs.vector_base.VectorEnvBase` and are
shared with the Ray backend (:mod:`seqdex_drake.envs.ray_vector`); this module is the process transport.

Failures are never waited on forever: every answer is awaited on the worker's pipe together with its process
sentinel and a timeout. A worker that raised (its traceback), died (its exit code or signal) or did not answer in
``timeout`` seconds raises :class:`WorkerError` naming the worker and the vector env is closed, unless
``max_restarts`` allows restarting it (see the base class).
"""

import multiprocessing as mp
import multiprocessing.connection
import signal
import sys
import time
import traceback

from seqdex_drake.envs.vector_base import EnvWorker, VectorEnvBase, WorkerError
from seqdex_drake.tasks.base import TaskConfig

__all__ = ["FORKSERVER_PRELOAD", "ProcessVectorEnv", "WorkerError"]

#: Modules the forkserver imports once, so that each worker forks with Drake and the env code loaded (about
#: 0.4 s instead of 1.5 s per worker start). Only takes effect if the forkserver is not yet running.
FORKSERVER_PRELOAD = ["__main__", "seqdex_drake.envs.subtask_env", "seqdex_drake.tasks.registry"]


def _exit_description(exitcode: int | None) -> str:
    """'exit code 3' or 'killed by signal SIGKILL (exit code -9)'."""
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return f"killed by signal {name} (exit code {exitcode})"
    return f"exit code {exitcode}"


def _worker(index: int, remote, parent_remote, task_name: str, config: TaskConfig | None) -> None:
    """The worker loop: builds the env, then answers ``(command, data)`` messages until ``close``.

    Every answer is ``("ok", payload)`` or ``("error", traceback text)``; after an error the worker exits.
    """
    parent_remote.close()
    if "torch" in sys.modules:  # Forked from a process that imported torch: keep it single-threaded.
        sys.modules["torch"].set_num_threads(1)
    try:
        worker = EnvWorker(task_name, config)  # No meshcat: visualizers change timing.
        remote.send(("ok", worker.handle("spaces", None)))
        while True:
            command, data = remote.recv()
            if command == "close":
                remote.send(("ok", None))
                break
            remote.send(("ok", worker.handle(command, data)))
    except (KeyboardInterrupt, EOFError, BrokenPipeError):
        pass  # The parent went away or interrupted us: nothing to report to.
    except Exception:  # noqa: BLE001 - every failure is reported to the parent with its traceback.
        try:
            remote.send(("error", f"worker {index} ({task_name}):\n{traceback.format_exc()}"))
        except (BrokenPipeError, OSError):
            pass
    finally:
        remote.close()


class ProcessVectorEnv(VectorEnvBase):
    """``num_envs`` copies of one sub-task environment, each in its own process.

    Args:
        task_name: a registered sub-task (``seqdex_drake.tasks.registry.task_names()``).
        num_envs: number of worker processes (one env each).
        seed: env ``i`` is seeded ``seed + i`` at the first reset.
        config: the task config for every worker (default: the task's ``default_config()``).
        start_method: ``"forkserver"`` (default) or ``"spawn"``; ``"fork"`` is accepted but unsafe after torch use.
        timeout: seconds to wait for the workers' answers to one call (worker start included) before raising
            :class:`WorkerError`.
        max_restarts: how many worker failures (over the env's life) are answered by restarting the worker
            instead of raising :class:`WorkerError`; 0 (default) raises on the first failure.
    """

    backend = "process"

    def __init__(self, task_name: str, num_envs: int, seed: int = 0, config: TaskConfig | None = None,
                 start_method: str = "forkserver", timeout: float = 300.0, max_restarts: int = 0):
        self._remotes, self._processes = [None] * num_envs, [None] * num_envs
        self._context = mp.get_context(start_method)
        if start_method == "forkserver":
            self._context.set_forkserver_preload(FORKSERVER_PRELOAD)
        super().__init__(task_name, num_envs, seed, config, timeout, max_restarts)
        self._start()

    # ------------------------------------------------------------------------------------ transport
    @property
    def pids(self) -> list[int]:
        """Process ids of the workers, in env order."""
        return [process.pid for process in self._processes]

    def _start_worker(self, index: int) -> None:
        remote, worker_remote = self._context.Pipe()
        process = self._context.Process(target=_worker, name=f"{self.task_name}-worker-{index}", daemon=True,
                                        args=(index, worker_remote, remote, self.task_name, self.config))
        process.start()
        worker_remote.close()
        self._remotes[index], self._processes[index] = remote, process

    def _request(self, index: int, command: str, data) -> None:
        try:
            self._remotes[index].send((command, data))
        except (BrokenPipeError, OSError) as error:
            process = self._processes[index]
            process.join(timeout=1.0)  # A broken pipe usually means the worker died: say how.
            status = _exit_description(process.exitcode) if process.exitcode is not None else "still running"
            raise WorkerError(index, f"could not send '{command}' ({error}); the worker process: {status}") from None

    def _receive(self, index: int, deadline: float):
        """The payload of worker ``index``'s next answer, or a :class:`WorkerError` (error, death or timeout)."""
        remote, process = self._remotes[index], self._processes[index]
        while True:
            ready = mp.connection.wait([remote, process.sentinel], timeout=max(0.0, deadline - time.monotonic()))
            if remote in ready or remote.poll():  # An answer (possibly an error report) beats the exit.
                try:
                    status, payload = remote.recv()
                except (EOFError, OSError):
                    process.join(timeout=1.0)
                    return WorkerError(index, f"the worker's pipe closed; {_exit_description(process.exitcode)}")
                return WorkerError(index, payload) if status == "error" else payload
            if process.sentinel in ready:
                process.join(timeout=1.0)
                return WorkerError(index, f"the worker process died: {_exit_description(process.exitcode)}")
            if time.monotonic() >= deadline:
                return WorkerError(index, f"no answer within {self.timeout:g} s (process alive: {process.is_alive()})")

    def _answers(self, indices) -> dict:
        deadline = time.monotonic() + self.timeout
        return {index: self._receive(index, deadline) for index in indices}

    def _kill_worker(self, index: int) -> None:
        process = self._processes[index]
        if process is None:
            return
        if process.is_alive():  # A stalled worker would not answer 'close' either; SIGKILL also ends SIGSTOP.
            process.kill()
        process.join(timeout=5.0)
        self._remotes[index].close()

    def _close_workers(self, timeout: float) -> None:
        started = [(r, p) for r, p in zip(self._remotes, self._processes, strict=True) if p is not None]
        for remote, process in started:
            if process.is_alive():
                try:
                    remote.send(("close", None))
                except (BrokenPipeError, OSError):
                    pass
        deadline = time.monotonic() + timeout
        for _, process in started:
            process.join(timeout=max(0.0, deadline - time.monotonic()))
        for _, process in started:
            if process.is_alive():
                process.kill()  # SIGKILL also ends a stopped (SIGSTOP) or hung worker.
                process.join(timeout=timeout)
        for remote, _ in started:
            remote.close()

    # ---------------------------------------------------------------------- compatibility (private)
    def _send(self, index: int, command: str, data=None) -> None:
        """Sends one raw worker message; on failure closes the env and raises :class:`WorkerError`.

        Kept for callers that predate :meth:`reset_at`; prefer the public methods.
        """
        try:
            self._request(index, command, data)
        except WorkerError:
            self.close()
            raise

    def _gather(self, indices) -> list:
        """Answers of the workers in ``indices`` (raises :class:`WorkerError` and closes on any failure)."""
        answers = self._answers(list(indices))
        self._raise_failures(answers)
        return [answers[index] for index in indices]
