"""What the process and Ray vector envs share: the worker-side env loop and the vector-env semantics.

Seeding: env ``i`` is seeded ``seed + i`` at the first :meth:`VectorEnvBase.reset` (or ``reset(seed=s)`` gives
``s + i``); later resets, including automatic ones, continue each env's own random stream, exactly as a serial
env reset without a seed would.

Autoreset (SB3 ``SubprocVecEnv`` semantics): when a step ends an episode (``terminated`` or ``truncated``), the
worker resets its env at once and that step returns the *new* episode's first observation. The returned reward,
flags and info keys (``reward/<term>``, ``success``, ...) are those of the step just taken; the info also holds

- ``final_observation``: the last observation of the finished episode,
- ``final_info``: a copy of that step's info,
- ``reset_info``: the info returned by the automatic reset,
- ``episode``: ``{"return": float, "length": int}`` of the finished episode.

Failures: a worker that raised, died or did not answer within ``timeout`` seconds raises :class:`WorkerError`
naming it, and the vector env is closed. With ``max_restarts > 0`` the first ``max_restarts`` such failures (over
the env's life, all workers together) are answered instead by killing the worker, starting a new one that
rebuilds its env, and resetting it with the seed ``seed + i + num_envs * k`` (the ``k``-th restart of env ``i``;
deterministic, and distinct from every other env's seed). In :meth:`~VectorEnvBase.step` the lost episode is
reported as a *truncation* of that env with reward 0, the fresh episode's first observation, and an info with
``worker_restarted: True``, ``worker_error`` (what happened), ``final_observation`` (the last observation the
caller saw for that env, so a learner can bootstrap), ``final_info`` and ``reset_info``; it has no ``success``
key, so success rates skip it (episode-return statistics do count its partial return). The counters
``restarts`` (per env) and ``lost_episodes`` keep count. A failure during :meth:`~VectorEnvBase.reset` /
:meth:`~VectorEnvBase.reset_at` restarts the worker and performs the requested reset;
:meth:`~VectorEnvBase.get_states` never restarts (a fresh env has not got the lost state). The default
(``max_restarts=0``) raises on the first failure, as before: restarting hides bugs, so it is opt-in.
"""

import os
from collections.abc import Sequence

import numpy as np
from gymnasium.vector.utils import batch_space

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import default_config


class WorkerError(RuntimeError):
    """A worker process (or Ray actor) raised, died or stopped answering.

    Attributes:
        index: the worker's index (its env is env ``index`` of the vector env).
        detail: the remote traceback, the exit code description or the timeout description.
    """

    def __init__(self, index: int, detail: str):
        super().__init__(f"vector env worker {index} failed: {detail}")
        self.index = index
        self.detail = detail


class EnvWorker:
    """The worker side of a vector env: one sub-task env with autoreset and episode bookkeeping.

    Answers the commands ``spaces``, ``reset`` (``(seed, options)``), ``step`` (an action) and ``get_state``
    through :meth:`handle`; both the process workers and the Ray actors run this.
    """

    def __init__(self, task_name: str, config: TaskConfig | None):
        self.env = make_env(task_name, config)
        self.episode_return, self.episode_length = 0.0, 0

    def handle(self, command: str, data):
        if command == "step":
            return self.step(data)
        if command == "reset":
            seed, options = data
            self.episode_return, self.episode_length = 0.0, 0
            return self.env.reset(seed=seed, options=options)
        if command == "get_state":
            return self.env.get_state()
        if command == "spaces":
            return self.env.observation_space, self.env.action_space, os.getpid()
        raise ValueError(f"unknown command {command!r}")

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.episode_return += reward
        self.episode_length += 1
        if terminated or truncated:
            info = dict(info, final_info=dict(info), final_observation=observation,
                        episode={"return": self.episode_return, "length": self.episode_length})
            observation, info["reset_info"] = self.env.reset()
            self.episode_return, self.episode_length = 0.0, 0
        return observation, reward, terminated, truncated, info


class VectorEnvBase:
    """``num_envs`` copies of one sub-task env in workers; subclasses provide the transport.

    A subclass implements ``_start_worker(i)`` (start worker ``i``; its first answer is the ``spaces`` one),
    ``_request(i, command, data)`` (send, or raise :class:`WorkerError`), ``_answers(indices)`` (a dict index ->
    payload or :class:`WorkerError`, all awaited against one ``timeout`` deadline), ``_kill_worker(i)`` and
    ``_close_workers(timeout)``, and calls :meth:`_start` at the end of its constructor.
    """

    backend = ""

    def __init__(self, task_name: str, num_envs: int, seed: int, config: TaskConfig | None, timeout: float,
                 max_restarts: int):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if max_restarts < 0:
            raise ValueError(f"max_restarts must be >= 0 (0: raise WorkerError on a failure), got {max_restarts}")
        default_config(task_name)  # Unknown names fail here, listing the valid ones.
        self.task_name, self.num_envs, self.seed, self.config = task_name, num_envs, seed, config
        self.timeout, self.max_restarts = timeout, max_restarts
        self.restarts = [0] * num_envs
        """Restarts of each env's worker so far."""
        self.lost_episodes = 0
        """Episodes cut short by a worker failure (each reported as a truncation with ``worker_restarted``)."""
        self.closed = False
        self._reset_once = False
        self._pids: list[int | None] = [None] * num_envs
        self._last_observations: np.ndarray | None = None

    def _start(self) -> None:
        try:
            for index in range(self.num_envs):
                self._start_worker(index)
            answers = self._answers(range(self.num_envs))
            self._raise_failures(answers)
        except BaseException:
            self.close()
            raise
        self.single_observation_space, self.single_action_space, _ = answers[0]
        self._pids = [answers[index][2] for index in range(self.num_envs)]
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    # ------------------------------------------------------------------------------------ failures
    def _raise_failures(self, answers: dict) -> None:
        """Closes the env and raises the first :class:`WorkerError` in ``answers`` (in env order), if any."""
        failed = sorted(index for index, answer in answers.items() if isinstance(answer, WorkerError))
        if failed:
            for index in failed:
                self._kill_worker(index)  # A stalled worker would not answer a polite close.
            self.close()
            raise answers[failed[0]]

    def _call(self, indices, command: str, data_of) -> dict:
        """Sends ``command`` with ``data_of(i)`` to each worker in ``indices``; their answers or WorkerErrors."""
        failures = {}
        for index in indices:
            try:
                self._request(index, command, data_of(index))
            except WorkerError as error:
                failures[index] = error
        answers = self._answers([index for index in indices if index not in failures])
        answers.update(failures)
        return answers

    def _recover(self, answers: dict, reset_args) -> dict:
        """Restarts the failed workers in ``answers`` and resets them with ``reset_args(i)``; returns
        ``{i: ((observation, info), error)}``. Raises (closing the env) when restarts are off or used up."""
        failed = {index: error for index, error in answers.items() if isinstance(error, WorkerError)}
        if not failed:
            return {}
        if sum(self.restarts) + len(failed) > self.max_restarts:
            if self.max_restarts:
                first = failed[min(failed)]
                first.args = (f"{first.args[0]} (restart budget of {self.max_restarts} used up)",)
            self._raise_failures(failed)
        recovered = {}
        for index, error in sorted(failed.items()):
            self._kill_worker(index)
            self.restarts[index] += 1
            self._start_worker(index)
            started = self._answers([index])
            self._raise_failures(started)
            self._pids[index] = started[index][2]
            reset = self._call([index], "reset", reset_args)
            self._raise_failures(reset)
            recovered[index] = (reset[index], error)
        return recovered

    def _restart_seed(self, index: int) -> int:
        return self.seed + index + self.num_envs * self.restarts[index]

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"this {type(self).__name__} is closed")

    # ------------------------------------------------------------------------------------ vector API
    @property
    def pids(self) -> list[int]:
        """Process ids of the workers, in env order."""
        return list(self._pids)

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
        env_seeds = [None if seed is None else seed + index for index in range(self.num_envs)]
        answers = self._call(range(self.num_envs), "reset", lambda index: (env_seeds[index], options[index]))
        recovered = self._recover(answers, lambda index: (
            self._restart_seed(index) if env_seeds[index] is None else env_seeds[index], options[index]))
        answers.update({index: result for index, (result, _) in recovered.items()})
        self._reset_once = True
        observations = np.stack([answers[index][0] for index in range(self.num_envs)])
        self._last_observations = observations.copy()
        return observations, [answers[index][1] for index in range(self.num_envs)]

    def reset_at(self, index: int, seed: int | None = None, options: dict | None = None):
        """Resets env ``index`` only; returns its ``(observation, info)``.

        Args:
            index: the env, ``0 <= index < num_envs``.
            seed: the env's new seed, used as given (not offset by ``index``); ``None`` continues its stream.
            options: the env's reset options, e.g. ``{"initial_state": EnvState}``.
        """
        self._check_open()
        if not self._reset_once:
            raise RuntimeError("call reset() before reset_at() (it seeds every env)")
        if not 0 <= index < self.num_envs:
            raise IndexError(f"env index {index} out of range for {self.num_envs} envs")
        index = int(index)
        answers = self._call([index], "reset", lambda _: (seed, options))
        recovered = self._recover(answers, lambda _: (self._restart_seed(index) if seed is None else seed, options))
        observation, info = recovered[index][0] if recovered else answers[index]
        self._last_observations[index] = observation
        return observation, info

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
        answers = self._call(range(self.num_envs), "step", lambda index: actions[index])  # Envs check shapes.
        return self._finish_step(range(self.num_envs), answers)

    def _finish_step(self, indices, answers: dict):
        """The step results of envs ``indices`` (in that order) from their ``answers`` (payloads or
        WorkerErrors): failed workers are restarted (or the env closed and the error raised, see the module
        docstring) and their lost episodes reported as truncations."""
        recovered = self._recover(answers, lambda index: (self._restart_seed(index), None))
        for index, ((observation, reset_info), error) in recovered.items():
            self.lost_episodes += 1
            info = {"worker_restarted": True, "worker_error": error.detail}
            answers[index] = (observation, 0.0, False, True, dict(
                info, final_info=dict(info), final_observation=self._last_observations[index].copy(),
                reset_info=reset_info))
        observations, rewards, terminated, truncated, infos = zip(*(answers[i] for i in indices), strict=True)
        observations = np.stack(observations)
        self._last_observations[list(indices)] = observations
        return (observations, np.array(rewards, dtype=np.float64), np.array(terminated, dtype=bool),
                np.array(truncated, dtype=bool), list(infos))

    @property
    def step_groups(self) -> list[list[int]]:
        """The envs that step together, one group per worker message. Backends that can step one group while
        another is still running (``ProcessVectorEnv.step_async`` / ``step_wait``) have one group per worker
        process; here, a single group of every env."""
        return [list(range(self.num_envs))]

    def get_states(self) -> list:
        """Each env's restorable :class:`~seqdex_drake.envs.subtask_env.EnvState`, in env order."""
        self._check_open()
        answers = self._call(range(self.num_envs), "get_state", lambda index: None)
        self._raise_failures(answers)
        return [answers[index] for index in range(self.num_envs)]

    def close(self, timeout: float = 5.0) -> None:
        """Stops every worker (politely, then by force after ``timeout`` s); calling it again does nothing."""
        if self.closed:
            return
        self.closed = True
        self._close_workers(timeout)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def __del__(self):
        if not getattr(self, "closed", True):
            self.close()

    def __len__(self) -> int:
        return self.num_envs
