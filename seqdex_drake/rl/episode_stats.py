"""Bookkeeping of what training logs: reward-term means per rollout, and windowed episode statistics.

Reads the info dicts of a vector env with the ``seqdex_drake.envs`` conventions: every step's info carries its
named reward terms as ``reward/<term>`` and a boolean ``success``; the success of an episode is the ``success``
of its last step.
"""

from collections import deque

import numpy as np


class EpisodeStats:
    """Per-env running returns, a window of finished episodes, and reward-term sums of the current rollout.

    Args:
        num_envs: number of environments of the vector env.
        window: number of most recent episodes averaged by :meth:`window_metrics`.
    """

    def __init__(self, num_envs: int, window: int = 100):
        self.window = window
        self.returns = deque(maxlen=window)
        self.lengths = deque(maxlen=window)
        self.successes = deque(maxlen=window)
        self.num_episodes = 0
        self.reset_envs(num_envs)
        self._term_sums: dict[str, float] = {}
        self._term_counts: dict[str, int] = {}
        self._rollout_returns: list[float] = []

    def reset_envs(self, num_envs: int) -> None:
        """Forgets the unfinished episodes (the vector env was reset or replaced)."""
        self.num_envs = num_envs
        self._running_return = np.zeros(num_envs)
        self._running_length = np.zeros(num_envs, dtype=np.int64)

    def record_step(self, rewards, terminated, truncated, infos: list[dict], indices=None) -> None:
        """Accounts one vector step (after autoreset: ``infos`` are those of the step just taken), of every env
        or, with ``indices``, of those envs only (the arrays and infos then follow ``indices``' order)."""
        envs = range(self.num_envs) if indices is None else indices
        self._running_return[list(envs)] += rewards
        self._running_length[list(envs)] += 1
        for info in infos:
            for key, value in info.items():
                if key.startswith("reward/"):
                    self._term_sums[key] = self._term_sums.get(key, 0.0) + float(value)
                    self._term_counts[key] = self._term_counts.get(key, 0) + 1
        for k in np.flatnonzero(np.logical_or(terminated, truncated)):
            index = envs[k]
            self.returns.append(float(self._running_return[index]))
            self.lengths.append(int(self._running_length[index]))
            self._rollout_returns.append(float(self._running_return[index]))
            if "success" in infos[k]:
                self.successes.append(float(bool(infos[k]["success"])))
            self.num_episodes += 1
            self._running_return[index] = 0.0
            self._running_length[index] = 0

    def rollout_metrics(self) -> dict[str, float]:
        """``reward/<term>`` means per env step and the episodes finished since the last call; then clears."""
        metrics = {key: self._term_sums[key] / self._term_counts[key] for key in sorted(self._term_sums)}
        metrics["charts/rollout_episodes"] = float(len(self._rollout_returns))
        if self._rollout_returns:
            metrics["charts/rollout_episode_return"] = float(np.mean(self._rollout_returns))
        self._term_sums, self._term_counts, self._rollout_returns = {}, {}, []
        return metrics

    def window_metrics(self) -> dict[str, float]:
        """Means over the last ``window`` episodes: ``charts/episode_return``, ``charts/episode_length``,
        ``charts/success_rate`` (only keys with data), and ``charts/episodes`` (total finished)."""
        metrics = {"charts/episodes": float(self.num_episodes)}
        if self.returns:
            metrics["charts/episode_return"] = float(np.mean(self.returns))
            metrics["charts/episode_length"] = float(np.mean(self.lengths))
        if self.successes:
            metrics["charts/success_rate"] = float(np.mean(self.successes))
        return metrics

    def summary(self) -> str:
        """The window in words: ``success rate 0.250 over the last 8 episodes`` (the mean return for episodes that
        report no ``success``), or ``no episodes yet``; a resumed run shows its saved window."""
        if not self.returns:
            return "no episodes yet"
        if self.successes:
            return f"success rate {np.mean(self.successes):.3f} over the last {len(self.successes)} episodes"
        return f"mean return {np.mean(self.returns):.3f} over the last {len(self.returns)} episodes"

    def selection_metric(self) -> tuple[str, float] | None:
        """What ``best.pt`` maximizes: the windowed success rate if episodes report ``success``, else the
        windowed mean return; ``None`` until ``min(window, num_envs)`` episodes have finished."""
        if len(self.returns) < min(self.window, self.num_envs):
            return None
        if self.successes:
            return "charts/success_rate", float(np.mean(self.successes))
        return "charts/episode_return", float(np.mean(self.returns))

    def state_dict(self) -> dict:
        """The finished-episode window and count as plain data (unfinished episodes are not saved)."""
        return {"returns": list(self.returns), "lengths": list(self.lengths), "successes": list(self.successes),
                "num_episodes": self.num_episodes}

    def load_state_dict(self, state: dict) -> None:
        self.returns = deque(state["returns"], maxlen=self.window)
        self.lengths = deque(state["lengths"], maxlen=self.window)
        self.successes = deque(state["successes"], maxlen=self.window)
        self.num_episodes = int(state["num_episodes"])
