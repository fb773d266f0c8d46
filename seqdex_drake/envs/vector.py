"""A process-based vector environment: sub-task environments in worker processes, one or more per process.

Each worker builds its envs (:class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`) from plain data (the task name
and a picklable :class:`~seqdex_drake.tasks.base.TaskConfig`), because Drake diagrams, contexts and simulators do
not pickle; only numpy arrays, floats, dicts and :class:`~seqdex_drake.envs.subtask_env.EnvState` cross the pipes.
Workers start with ``forkserver`` by default (``spawn`` also works): a plain ``fork`` after the parent used torch
can hang (see SB3's ``SubprocVecEnv``). No visualizer is ever attached in a worker. The vector-env semantics
(seeding, autoreset, failures, restarts) live in :class:`~seqdex_drake.envs.vector_base.VectorEnvBase` and are
shared with the Ray backend (:mod:`seqdex_drake.envs.ray_vector`); this module is the process transport.

``envs_per_worker`` (default 1) hosts that many consecutive envs in each process: a vector step sends one
message per process and the process steps its envs one after the other. Fewer processes than envs pay off when
envs outnumber cores: less inter-process traffic per env step, less memory (one Python and Drake per process),
and a process's step time is the sum over its envs, whose spread is smaller, so processes wait less for each
other at every synchronous step. Results do not depend on it: env ``i`` is seeded ``seed + i`` either way.

Failures are never waited on forever: every answer is awaited on the process's pipe together with its process
sentinel and a timeout. An env that raised (its traceback), or whose process died (its exit code or signal) or
did not answer in ``timeout`` seconds, raises :class:`WorkerError` naming the env, and the vector env is closed,
unless ``max_restarts`` allows a restart (see the base class). An env that raised is rebuilt in its process; a
process that died or hung is killed and started again, and each of its envs counts as one failure.
"""

import multiprocessing as mp
import multiprocessing.connection
import os
import signal
import sys
import time
import traceback

import numpy as np

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
    """The worker loop: answers batches ``[(env, command, data), ...]`` with ``{env: ("ok", payload) or
    ("error", traceback text)}`` until ``close``. ``add`` builds env ``env`` (its answer is the ``spaces`` one);
    an env that raised is dropped (the parent adds it again to restart it); the other envs go on."""
    parent_remote.close()
    if "torch" in sys.modules:  # Forked from a process that imported torch: keep it single-threaded.
        sys.modules["torch"].set_num_threads(1)
    workers: dict[int, EnvWorker] = {}  # No meshcat: visualizers change timing.
    try:
        while True:
            batch = remote.recv()
            if batch == "close":
                remote.send("closed")
                break
            answers = {}
            for env, command, data in batch:
                try:
                    if command == "add":
                        workers[env] = EnvWorker(task_name, config)
                        command = "spaces"
                    answers[env] = ("ok", workers[env].handle(command, data))
                except Exception:  # noqa: BLE001 - every failure is reported to the parent with its traceback.
                    workers.pop(env, None)
                    answers[env] = ("error", f"worker {env} ({task_name}, process {index}):\n{traceback.format_exc()}")
            remote.send(answers)
    except (KeyboardInterrupt, EOFError, BrokenPipeError):
        pass  # The parent went away or interrupted us: nothing to report to.
    finally:
        remote.close()


def default_envs_per_worker(num_envs: int) -> int:
    """ceil(num_envs / cores available to this process): as many worker processes as cores, the envs spread
    over them (the CLI's default layout; measured: 8 envs per worker gave a better 2-worker speedup than 1)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, -(-max(num_envs, 1) // max(cores, 1)))


class ProcessVectorEnv(VectorEnvBase):
    """``num_envs`` copies of one sub-task environment in worker processes, ``envs_per_worker`` per process.

    Args:
        task_name: a registered sub-task (``seqdex_drake.tasks.registry.task_names()``).
        num_envs: number of envs.
        seed: env ``i`` is seeded ``seed + i`` at the first reset.
        config: the task config for every env (default: the task's ``default_config()``).
        start_method: ``"forkserver"`` (default) or ``"spawn"``; ``"fork"`` is accepted but unsafe after torch use.
        timeout: seconds to wait for the workers' answers to one call (env builds included) before raising
            :class:`WorkerError`.
        max_restarts: how many env failures (over the env's life) are answered by restarting instead of raising
            :class:`WorkerError`; 0 (default) raises on the first failure.
        envs_per_worker: envs hosted by each process (consecutive envs; the last process may host fewer); None:
            :func:`default_envs_per_worker`, one process per core.
    """

    backend = "process"

    def __init__(self, task_name: str, num_envs: int, seed: int = 0, config: TaskConfig | None = None,
                 start_method: str = "forkserver", timeout: float = 300.0, max_restarts: int = 0,
                 envs_per_worker: int | None = 1):
        if envs_per_worker is None:
            envs_per_worker = default_envs_per_worker(num_envs)
        if not isinstance(envs_per_worker, int) or envs_per_worker < 1:
            raise ValueError(f"envs_per_worker must be an integer >= 1, got {envs_per_worker!r}")
        self.envs_per_worker = envs_per_worker
        self.num_workers = -(-max(num_envs, 1) // envs_per_worker)
        """Worker processes: ceil(num_envs / envs_per_worker)."""
        self._remotes, self._processes = [None] * self.num_workers, [None] * self.num_workers
        self._pending: list[list] = [[] for _ in range(self.num_workers)]  # Requests not yet sent, per process.
        self._broken = [False] * self.num_workers  # Died, hung or lost its pipe: killed at the next restart.
        self._in_flight: dict[int, tuple[list, dict]] = {}  # Step group -> (batch sent, failures): step_async.
        self._context = mp.get_context(start_method)
        if start_method == "forkserver":
            self._context.set_forkserver_preload(FORKSERVER_PRELOAD)
        super().__init__(task_name, num_envs, seed, config, timeout, max_restarts)
        self._start()

    # ------------------------------------------------------------------------------------ transport
    @property
    def pids(self) -> list[int]:
        """Process ids of the envs' workers, in env order (envs of one process share its id)."""
        return [self._processes[self._worker_of(index)].pid for index in range(self.num_envs)]

    def _worker_of(self, index: int) -> int:
        return index // self.envs_per_worker

    def _start_worker(self, index: int) -> None:
        """Starts env ``index``'s process if it is not running, and asks it to build env ``index``."""
        worker = self._worker_of(index)
        if self._processes[worker] is None or self._broken[worker]:  # Never started, or killed after a failure.
            remote, worker_remote = self._context.Pipe()
            process = self._context.Process(target=_worker, name=f"{self.task_name}-worker-{worker}", daemon=True,
                                            args=(worker, worker_remote, remote, self.task_name, self.config))
            process.start()
            worker_remote.close()
            self._remotes[worker], self._processes[worker], self._broken[worker] = remote, process, False
        self._pending[worker].append((index, "add", None))

    def _request(self, index: int, command: str, data) -> None:
        worker = self._worker_of(index)
        if worker in self._in_flight:
            raise RuntimeError(f"env {index}'s step group {worker} is still stepping (step_async); collect it with "
                               "step_wait() before calling reset, step or get_states")
        if self._processes[worker] is None or self._broken[worker]:
            raise WorkerError(index, f"its worker process {worker} failed earlier and was not restarted")
        self._pending[worker].append((index, command, data))

    def _answers(self, indices) -> dict:
        """Sends each process its pending requests as one message, then awaits every process's answer."""
        deadline = time.monotonic() + self.timeout
        sent, answers = {}, {}
        for worker, batch in enumerate(self._pending):
            if batch:
                sent[worker], failures = self._send(worker)
                answers.update(failures)
        for worker, batch in sent.items():
            if batch:
                answers.update(self._reply_answers(batch, self._receive(worker, deadline)))
        return {index: answers[index] for index in indices}

    def _send(self, worker: int) -> tuple[list, dict]:
        """Sends process ``worker`` its pending requests as one message: (the batch sent, or [] if the send
        failed, and the WorkerErrors of a failed send)."""
        batch, self._pending[worker] = self._pending[worker], []
        try:
            self._remotes[worker].send(batch)
            return batch, {}
        except (BrokenPipeError, OSError) as error:
            process = self._processes[worker]
            process.join(timeout=1.0)  # A broken pipe usually means the worker died: say how.
            status = _exit_description(process.exitcode) if process.exitcode is not None else "still running"
            self._broken[worker] = True
            return [], {index: WorkerError(index, f"could not send '{command}' ({error}); the worker process: "
                                                  f"{status}") for index, command, _ in batch}

    @staticmethod
    def _reply_answers(batch: list, reply) -> dict:
        """The answers to ``batch`` in a process's ``reply`` (a dict, or a string saying why none came)."""
        answers = {}
        for index, _, _ in batch:
            if isinstance(reply, str):  # The process failed: every env it hosts did.
                answers[index] = WorkerError(index, reply)
            else:
                status, payload = reply[index]
                answers[index] = WorkerError(index, payload) if status == "error" else payload
        return answers

    # ---------------------------------------------------------------------------- asynchronous groups
    @property
    def step_groups(self) -> list[list[int]]:
        """The envs of each worker process, in env order: what :meth:`step_async` steps together."""
        k = self.envs_per_worker
        return [list(range(w * k, min((w + 1) * k, self.num_envs))) for w in range(self.num_workers)]

    def step_async(self, group: int, actions) -> None:
        """Starts a step of the envs of ``step_groups[group]`` (one worker process) with ``actions``, one row
        per env of the group, and returns at once; :meth:`step_wait` returns its results. Other groups can step
        meanwhile: a learner can act on one worker's observations and send it its next step while the other
        workers are still stepping, instead of waiting for the slowest at every step."""
        self._check_open()
        if not self._reset_once:
            raise RuntimeError("call reset() before step_async()")
        if not 0 <= group < self.num_workers:
            raise IndexError(f"step group {group} out of range for {self.num_workers} groups")
        if group in self._in_flight:
            raise RuntimeError(f"step group {group} is already stepping; collect it with step_wait() first")
        indices, actions = self.step_groups[group], np.asarray(actions)
        if len(actions) != len(indices):
            raise ValueError(f"expected {len(indices)} actions for step group {group}, got {len(actions)}")
        failures = {}
        for index, action in zip(indices, actions, strict=True):
            try:
                self._request(index, "step", action)
            except WorkerError as error:
                failures[index] = error
        batch = []
        if self._pending[group]:
            batch, send_failures = self._send(group)
            failures.update(send_failures)
        self._in_flight[group] = (batch, failures)

    def step_wait(self):
        """Waits for the first step group (of those started with :meth:`step_async`) whose results are in.

        Returns:
            ``(group, (observations, rewards, terminated, truncated, infos))``, the results as
            :meth:`~seqdex_drake.envs.vector_base.VectorEnvBase.step` gives them for the group's envs, in the
            order of ``step_groups[group]`` (autoreset, failures and restarts alike).
        """
        self._check_open()
        if not self._in_flight:
            raise RuntimeError("no step group is stepping; start one with step_async()")
        deadline = time.monotonic() + self.timeout
        ready = [group for group, (batch, _) in self._in_flight.items() if not batch]  # Nothing to wait for.
        if not ready:
            waiting = {self._remotes[group]: group for group in self._in_flight}
            waiting.update({self._processes[group].sentinel: group for group in self._in_flight})
            found = mp.connection.wait(list(waiting), timeout=max(0.0, deadline - time.monotonic()))
            ready = sorted({waiting[handle] for handle in found}) or [min(self._in_flight)]  # Timeout: report it.
        group = ready[0]
        batch, answers = self._in_flight.pop(group)
        if batch:
            answers.update(self._reply_answers(batch, self._receive(group, deadline)))
        indices = self.step_groups[group]
        return group, self._finish_step(indices, answers)

    def _receive(self, worker: int, deadline: float):
        """Process ``worker``'s next answer (a dict), or a description of why none came (death or timeout)."""
        remote, process = self._remotes[worker], self._processes[worker]
        while True:
            ready = mp.connection.wait([remote, process.sentinel], timeout=max(0.0, deadline - time.monotonic()))
            if remote in ready or remote.poll():  # An answer beats the exit.
                try:
                    return remote.recv()
                except (EOFError, OSError):
                    process.join(timeout=1.0)
                    self._broken[worker] = True
                    return f"the worker's pipe closed; {_exit_description(process.exitcode)}"
            if process.sentinel in ready:
                process.join(timeout=1.0)
                self._broken[worker] = True
                return f"the worker process died: {_exit_description(process.exitcode)}"
            if time.monotonic() >= deadline:
                self._broken[worker] = True
                return f"no answer within {self.timeout:g} s (process alive: {process.is_alive()})"

    def _kill_worker(self, index: int) -> None:
        """Env ``index`` failed: a broken process is killed (the next env start in it starts a new one); a
        healthy one already dropped the env that raised."""
        worker = self._worker_of(index)
        process = self._processes[worker]
        if process is None or not self._broken[worker]:
            return
        if process.is_alive():  # A stalled worker would not answer 'close' either; SIGKILL also ends SIGSTOP.
            process.kill()
        process.join(timeout=5.0)
        self._remotes[worker].close()

    def _close_workers(self, timeout: float) -> None:
        started = [(r, p) for r, p in zip(self._remotes, self._processes, strict=True) if p is not None]
        # (A process killed after a failure is not alive: it is only joined again, and its pipe closed again.)
        for remote, process in started:
            if process.is_alive():
                try:
                    remote.send("close")
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
