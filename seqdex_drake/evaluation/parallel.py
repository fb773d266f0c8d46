"""``seqdex evaluate``'s episodes in worker processes (``EvalConfig.workers`` > 1).

:class:`WorkerPool` starts ``min(workers, seeds)`` processes with the "spawn" method, once per evaluation, and
splits each experiment setting's pending episodes over them by seed (seed ``seeds[i]`` to worker
``i % processes``). For every setting each worker builds its own Drake diagram, a :class:`ChainRunner` with the
same :class:`RunConfig` as the single-process path, and runs its episodes in the single-process order. Workers
send each finished episode (its record and its feasibility scatter points) through a queue; the parent, the only
writer of ``episodes.jsonl``, records it as it arrives, so the progress bar advances and ``--resume`` finds every
episode finished before an interruption. Every episode is seeded by (seed, object, episode) and starts its
runner's clock at 0, so the records do not depend on how the seeds were split.

A worker that raises stops the pool: a :class:`ChainRunError` is raised again in the parent with its message,
any other failure (or a worker that died) as :class:`EvaluationWorkerError` with the worker's traceback.
"""

import multiprocessing as mp
import queue
import signal
import traceback
from collections.abc import Callable

from seqdex_drake.evaluation.episodes import run_config, run_episode
from seqdex_drake.evaluation.runner import ChainRunError, ChainRunner

#: Seconds between the parent's checks that the workers are alive while it waits for their episodes.
POLL_SECONDS = 0.5
#: Seconds a worker gets to exit (after "stop", or after terminate) before it is killed.
JOIN_SECONDS = 5.0


class EvaluationWorkerError(RuntimeError):
    """An evaluation worker process failed (its traceback in the message) or died."""


def split_by_seed(jobs: list[dict], seeds, workers: int) -> dict[int, list[dict]]:
    """{worker: its jobs}: the jobs (episode tags with a ``seed``) of seed ``seeds[i]`` go to worker
    ``i % min(workers, len(seeds))``, in their order; workers without a job are left out."""
    seeds = list(seeds)
    count = max(1, min(workers, len(seeds)))
    lanes: dict[int, list[dict]] = {}
    for job in jobs:
        lanes.setdefault(seeds.index(job["seed"]) % count, []).append(job)
    return lanes


def _worker(index: int, config, tasks, messages) -> None:
    """Runs the tasks ``(overrides, jobs, scatter)`` it is sent until ``None``: per task, one runner built with
    ``overrides`` and ``jobs`` run in order, sending ``(kind, index, payload)`` messages ``built`` (the untrained
    stages), ``episode`` ((record, rpy, scores)) per job and ``finished``; on a failure ``chain_error`` (the
    message) or ``error`` (the traceback), and exits."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the parent stops the workers.
    parent = mp.parent_process()
    try:
        while (task := _next_task(tasks, parent)) is not None:
            overrides, jobs, scatter = task
            runner = ChainRunner(run_config(config, **overrides))
            messages.put(("built", index, list(runner.untrained)))
            for job in jobs:
                if parent is not None and not parent.is_alive():
                    return  # The parent was killed (no cleanup ran): nobody is left to report to.
                result, rpy, scores = run_episode(runner, config, job["object"], job["seed"], job["episode"],
                                                  scatter)
                messages.put(("episode", index, ({**job, **result}, [[float(a) for a in v] for v in rpy],
                                                 [float(c) for c in scores])))
            messages.put(("finished", index, None))
            del runner
    except ChainRunError as error:
        messages.put(("chain_error", index, str(error)))
    except BaseException:  # noqa: BLE001 - every failure goes to the parent, with its traceback.
        messages.put(("error", index, traceback.format_exc()))


def _next_task(tasks, parent):
    """The next task from the parent, or None (stop) once the parent has died without saying so."""
    while True:
        try:
            return tasks.get(timeout=POLL_SECONDS)
        except queue.Empty:
            if parent is not None and not parent.is_alive():
                return None


class WorkerPool:
    """``min(config.workers, len(config.seeds))`` worker processes running an evaluation's episodes; see the
    module docstring. :meth:`close` when done (a failed :meth:`run` closes the pool itself)."""

    def __init__(self, config):
        self.config = config
        self.count = max(1, min(config.workers, len(config.seeds)))
        context = mp.get_context("spawn")
        self.messages = context.Queue()
        self.tasks = [context.Queue() for _ in range(self.count)]
        self.processes = [context.Process(target=_worker, args=(i, config, self.tasks[i], self.messages),
                                          name=f"seqdex-evaluate-{i}", daemon=True) for i in range(self.count)]
        try:
            for process in self.processes:
                process.start()
        except BaseException:
            self.close(stop=False)
            raise

    def run(self, jobs: list[dict], overrides: dict, scatter: bool,
            on_episode: Callable[[dict, list, list], None]) -> list[str] | None:
        """Runs the episodes ``jobs`` (tags ``experiment, setting, seed, object, episode``) on runners built with
        ``overrides`` of :func:`~seqdex_drake.evaluation.episodes.run_config`, calling
        ``on_episode(record, rpy, scores)`` here as each finishes. Returns the runners' untrained stages (None if
        no job).

        Raises:
            ChainRunError: a worker's runner could not start (the worker's message).
            EvaluationWorkerError: a worker raised anything else, or died.
        """
        lanes = split_by_seed(jobs, self.config.seeds, self.count)
        untrained, waiting, exited = None, set(lanes), set()
        try:
            for i, lane in lanes.items():
                self.tasks[i].put((overrides, lane, scatter))
            while waiting:
                try:
                    kind, index, payload = self.messages.get(timeout=POLL_SECONDS)
                except queue.Empty:
                    # A worker flushes its messages before it exits: one that had exited before this empty wait
                    # died without a word (workers only exit on their own after reporting a failure).
                    if exited:
                        i = min(exited)
                        seeds = [s for k, s in enumerate(self.config.seeds) if k % self.count == i]
                        raise EvaluationWorkerError(f"evaluation worker {i} (seeds {seeds}) died: "
                                                    f"{_exit_description(self.processes[i].exitcode)}") from None
                    exited = {i for i, process in enumerate(self.processes) if not process.is_alive()}
                    continue
                if kind == "episode":
                    on_episode(*payload)
                elif kind == "built":
                    untrained = payload
                elif kind == "finished":
                    waiting.discard(index)
                elif kind == "chain_error":
                    raise ChainRunError(payload)
                else:
                    raise EvaluationWorkerError(f"evaluation worker {index} failed:\n{payload}")
        except BaseException:
            self.close(stop=False)
            raise
        return untrained

    def close(self, stop: bool = True) -> None:
        """Stops the workers: asks them to exit (``stop``) or terminates them; kills any that do not exit."""
        for i, process in enumerate(self.processes):
            if process.is_alive():
                if stop:
                    self.tasks[i].put(None)
                else:
                    process.terminate()
        for process in self.processes:
            if process.pid is not None:
                process.join(JOIN_SECONDS)
                if process.is_alive():
                    process.kill()
                    process.join()
        for channel in [self.messages, *self.tasks]:
            channel.close()
            channel.cancel_join_thread()
        self.processes = []


def _exit_description(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            return f"killed by signal {signal.Signals(-exitcode).name} (exit code {exitcode})"
        except ValueError:
            pass
    return f"exit code {exitcode}"
