"""A process-based vector environment: one sub-task environment per worker process.

Each worker builds its own :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` from plain data (the task name and a
picklable :class:`~seqdex_drake.tasks.base.TaskConfig`), because Drake diagrams, contexts and simulators do not
pickle; only numpy arrays, floats, dicts and :class:`~seqdex_drake.envs.subtask_env.EnvState` cross the pipes.
Workers start with ``forkserver`` by default (``spawn`` also works): a plain ``fork`` after the parent used torch
can hang (see SB3's ``SubprocVecEnv``). No visualizer is ever attached in a worker.

Seeding: env ``i`` is seeded ``seed + i`` at the first :meth:`ProcessVectorEnv.reset` (or ``reset(seed=s)`` gives
``s + i``); later resets, including automatic ones, continue each env's own random stream, exactly as a serial
env reset without a seed would.

Autoreset (SB3 ``SubprocVecEnv`` semantics): when a step ends an episode (``terminated`` or ``truncated``), the
worker resets its env at once and that step returns the *new* episode's first observation. The returned reward,
flags and info keys (``reward/<term>``, ``success``, ...) are those of the step just taken; the info also holds

- ``final_observation``: the last observation of the finished episode,
- ``final_info``: a copy of that step's info,
- ``reset_info``: the info returned by the automatic reset,
- ``episode``: ``{"return": float, "length": int}`` of the finished episode.

Failures are never waited on forever: every answer is awaited on the worker's pipe together with its process
sentinel and a timeout. A worker that raised (its traceback), died (its exit code or signal) or did not answer in
``timeout`` seconds raises :class:`WorkerError` naming the worker; the vector env is then closed.
"""

import multiprocessing as mp
import multiprocessing.connection
import signal
import sys
import time
import traceback
from collections.abc import Sequence

import numpy as np
from gymnasium.vector.utils import batch_space

from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import default_config

#: Modules the forkserver imports once, so that each worker forks with Drake and the env code loaded (about
#: 0.4 s instead of 1.5 s per worker start). Only takes effect if the forkserver is not yet running.
FORKSERVER_PRELOAD = ["__main__", "seqdex_drake.envs.subtask_env", "seqdex_drake.tasks.registry"]


class WorkerError(RuntimeError):
    """A worker process raised, died or stopped answering.

    Attributes:
        index: the worker's index (its env is env ``index`` of the vector env).
        detail: the remote traceback, the exit code description or the timeout description.
    """

    def __init__(self, index: int, detail: str):
        super().__init__(f"vector env worker {index} failed: {detail}")
        self.index = index
        self.detail = detail


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
    env = None
    try:
        from seqdex_drake.tasks.registry import make_env

        env = make_env(task_name, config)  # No meshcat: visualizers change timing.
        remote.send(("ok", (env.observation_space, env.action_space)))
        episode_return, episode_length = 0.0, 0
        while True:
            command, data = remote.recv()
            if command == "step":
                observation, reward, terminated, truncated, info = env.step(data)
                episode_return += reward
                episode_length += 1
                if terminated or truncated:
                    info = dict(info, final_info=dict(info), final_observation=observation,
                                episode={"return": episode_return, "length": episode_length})
                    observation, info["reset_info"] = env.reset()
                    episode_return, episode_length = 0.0, 0
                remote.send(("ok", (observation, reward, terminated, truncated, info)))
            elif command == "reset":
                seed, options = data
                episode_return, episode_length = 0.0, 0
                remote.send(("ok", env.reset(seed=seed, options=options)))
            elif command == "get_state":
                remote.send(("ok", env.get_state()))
            elif command == "close":
                remote.send(("ok", None))
                break
            else:
                raise ValueError(f"unknown command {command!r}")
    except (KeyboardInterrupt, EOFError, BrokenPipeError):
        pass  # The parent went away or interrupted us: nothing to report to.
    except Exception:  # noqa: BLE001 - every failure is reported to the parent with its traceback.
        try:
            remote.send(("error", f"worker {index} ({task_name}):\n{traceback.format_exc()}"))
        except (BrokenPipeError, OSError):
            pass
    finally:
        remote.close()


class ProcessVectorEnv:
    """``num_envs`` copies of one sub-task environment, each in its own process.

    Args:
        task_name: a registered sub-task (``seqdex_drake.tasks.registry.task_names()``).
        num_envs: number of worker processes (one env each).
        seed: env ``i`` is seeded ``seed + i`` at the first reset.
        config: the task config for every worker (default: the task's ``default_config()``).
        start_method: ``"forkserver"`` (default) or ``"spawn"``; ``"fork"`` is accepted but unsafe after torch use.
        timeout: seconds to wait for the workers' answers to one call (worker start included) before raising
            :class:`WorkerError`.
    """

    def __init__(self, task_name: str, num_envs: int, seed: int = 0, config: TaskConfig | None = None,
                 start_method: str = "forkserver", timeout: float = 300.0):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        default_config(task_name)  # Unknown names fail here, listing the valid ones.
        self.task_name = task_name
        self.num_envs = num_envs
        self.seed = seed
        self.timeout = timeout
        self.closed = False
        self._reset_once = False
        self._remotes, self._processes = [], []
        context = mp.get_context(start_method)
        if start_method == "forkserver":
            context.set_forkserver_preload(FORKSERVER_PRELOAD)
        try:
            for index in range(num_envs):
                remote, worker_remote = context.Pipe()
                process = context.Process(target=_worker, name=f"{task_name}-worker-{index}", daemon=True,
                                          args=(index, worker_remote, remote, task_name, config))
                process.start()
                worker_remote.close()
                self._remotes.append(remote)
                self._processes.append(process)
            spaces = self._gather(range(num_envs))
        except BaseException:
            self.close()
            raise
        self.single_observation_space, self.single_action_space = spaces[0]
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)

    # ------------------------------------------------------------------------------------ messaging
    @property
    def pids(self) -> list[int]:
        """Process ids of the workers, in env order."""
        return [process.pid for process in self._processes]

    def _send(self, index: int, command: str, data=None) -> None:
        try:
            self._remotes[index].send((command, data))
        except (BrokenPipeError, OSError) as error:
            process = self._processes[index]
            process.join(timeout=1.0)  # A broken pipe usually means the worker died: say how.
            status = _exit_description(process.exitcode) if process.exitcode is not None else "still running"
            self._fail(index, f"could not send '{command}' ({error}); the worker process: {status}")

    def _receive(self, index: int, deadline: float):
        """The payload of worker ``index``'s next answer; raises WorkerError on error, death or timeout."""
        remote, process = self._remotes[index], self._processes[index]
        while True:
            ready = mp.connection.wait([remote, process.sentinel], timeout=max(0.0, deadline - time.monotonic()))
            if remote in ready or remote.poll():  # An answer (possibly an error report) beats the exit.
                try:
                    status, payload = remote.recv()
                except (EOFError, OSError):
                    process.join(timeout=1.0)
                    self._fail(index, f"the worker's pipe closed; {_exit_description(process.exitcode)}")
                if status == "error":
                    self._fail(index, payload)
                return payload
            if process.sentinel in ready:
                process.join(timeout=1.0)
                self._fail(index, f"the worker process died: {_exit_description(process.exitcode)}")
            if time.monotonic() >= deadline:
                self._fail(index, f"no answer within {self.timeout:g} s (process alive: {process.is_alive()})")

    def _gather(self, indices) -> list:
        """Answers of the workers in ``indices``, all awaited against one deadline."""
        deadline = time.monotonic() + self.timeout
        return [self._receive(index, deadline) for index in indices]

    def _fail(self, index: int, detail: str):
        if self._processes[index].is_alive():  # A stalled worker would not answer 'close' either.
            self._processes[index].kill()
        self.close()
        raise WorkerError(index, detail)

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError("this ProcessVectorEnv is closed")

    # ------------------------------------------------------------------------------------ vector API
    def reset(self, seed: int | None = None, options: dict | Sequence[dict | None] | None = None):
        """Resets every env; returns ``(observations[num_envs, d], infos)`` with one info dict per env.

        Args:
            seed: env ``i`` gets ``seed + i``; ``None`` gives ``self.seed + i`` at the first reset and continues
                each env's random stream afterwards.
            options: one dict for every env, or a sequence of ``num_envs`` dicts (or None), e.g. per-env
                ``{"initial_state": EnvState}`` for forward initialization.
        """
        self._check_open()
        if seed is None and not self._reset_once:
            seed = self.seed
        if options is None or isinstance(options, dict):
            options = [options] * self.num_envs
        if len(options) != self.num_envs:
            raise ValueError(f"options must be a dict or {self.num_envs} dicts, got {len(options)}")
        for index in range(self.num_envs):
            self._send(index, "reset", (None if seed is None else seed + index, options[index]))
        results = self._gather(range(self.num_envs))
        self._reset_once = True
        return np.stack([observation for observation, _ in results]), [info for _, info in results]

    def step(self, actions):
        """Steps every env with its row of ``actions`` [num_envs, 19] (ended episodes reset automatically).

        Returns:
            ``observations[num_envs, d]`` (float32), ``rewards[num_envs]`` (float64), ``terminated[num_envs]``,
            ``truncated[num_envs]`` (bool) and a list of ``num_envs`` info dicts (see the module docstring).
        """
        self._check_open()
        if not self._reset_once:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions (one row per env), got {len(actions)}")
        for index in range(self.num_envs):
            self._send(index, "step", actions[index])  # Each env checks its own action shape.
        results = self._gather(range(self.num_envs))
        observations, rewards, terminated, truncated, infos = zip(*results, strict=True)
        return (np.stack(observations), np.array(rewards, dtype=np.float64), np.array(terminated, dtype=bool),
                np.array(truncated, dtype=bool), list(infos))

    def get_states(self) -> list:
        """Each env's restorable :class:`~seqdex_drake.envs.subtask_env.EnvState`, in env order."""
        self._check_open()
        for index in range(self.num_envs):
            self._send(index, "get_state")
        return self._gather(range(self.num_envs))

    def close(self, timeout: float = 5.0) -> None:
        """Stops every worker (politely, then by force after ``timeout`` s); calling it again does nothing."""
        if self.closed:
            return
        self.closed = True
        for remote, process in zip(self._remotes, self._processes, strict=True):
            if process.is_alive():
                try:
                    remote.send(("close", None))
                except (BrokenPipeError, OSError):
                    pass
        deadline = time.monotonic() + timeout
        for process in self._processes:
            process.join(timeout=max(0.0, deadline - time.monotonic()))
        for process in self._processes:
            if process.is_alive():
                process.kill()  # SIGKILL also ends a stopped (SIGSTOP) or hung worker.
                process.join(timeout=timeout)
        for remote in self._remotes:
            remote.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def __del__(self):
        if not getattr(self, "closed", True):
            self.close()

    def __len__(self) -> int:
        return self.num_envs
