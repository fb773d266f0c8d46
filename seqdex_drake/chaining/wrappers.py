"""Vector-env wrappers that chain sub-tasks: forward initialization's start states and backward fine-tuning's
transition bonus. They work on any vector env with the SB3 autoreset semantics of
:class:`~seqdex_drake.envs.vector.ProcessVectorEnv` (also :class:`~seqdex_drake.envs.serial.SerialVectorEnv`) and
a public ``reset_at(index, seed=None, options=None)``.
"""

from collections.abc import Callable

import numpy as np

from seqdex_drake.chaining.feasibility import pad_history
from seqdex_drake.env_state import EnvState


class _Wrapper:
    def __init__(self, env):
        self.env = env
        self.single_observation_space = env.single_observation_space
        self.single_action_space = env.single_action_space

    def __len__(self) -> int:
        return len(self.env)

    def reset_at(self, index: int, seed: int | None = None, options: dict | None = None):
        return self.env.reset_at(index, seed=seed, options=options)

    def get_states(self) -> list:
        return self.env.get_states()

    def close(self) -> None:
        self.env.close()


class InitialStateVectorEnv(_Wrapper):
    """Every episode (first and automatic resets alike) starts from a state drawn from a terminal buffer
    (forward initialization: rho_i is pi_{i-1}'s successful terminal states).

    Args:
        env: the vector env of the buffer's target task.
        buffer: a :class:`~seqdex_drake.chaining.terminal_buffer.TerminalBuffer` with at least one success.
        seed: seed of the state draws (``np.random.default_rng``).
        state_type: the class the buffer's states are rebuilt as (default: the sub-task env's ``EnvState``).
        successful_only: draw only successful entries (default); False also draws failed ones (test runs).
    """

    def __init__(self, env, buffer, seed: int, state_type: type | None = None, successful_only: bool = True):
        super().__init__(env)
        if state_type is None:
            state_type = EnvState
        self.buffer, self.state_type, self.successful_only = buffer, state_type, successful_only
        self.rng = np.random.default_rng(seed)

    def _options(self) -> dict:
        entry = self.buffer.sample(self.rng, self.state_type, successful_only=self.successful_only)
        return {"initial_state": entry.state}

    def reset(self, seed: int | None = None, options=None):
        """Resets every env from a freshly drawn buffer state (``options`` is ignored)."""
        return self.env.reset(seed=seed, options=[self._options() for _ in range(len(self.env))])

    def step(self, actions):
        """Steps the wrapped env; envs whose episode ended restart from a buffer state (the observation returned
        for them is the new episode's first one)."""
        observations, rewards, terminated, truncated, infos = self.env.step(actions)
        for index in np.flatnonzero(terminated | truncated):
            observations[index], infos[index]["reset_info"] = self.env.reset_at(int(index), options=self._options())
        return observations, rewards, terminated, truncated, infos


class TransitionBonusVectorEnv(_Wrapper):
    """Backward fine-tuning's reward: ``lambda1 * R + lambda2 * bonus(history)`` where the bonus is paid at the
    last ``window`` steps of each episode (default 1: once, at the terminal step, as in the paper's Algorithm 1)
    on the window of the last ``history`` observations ending at that step.

    The bonus is the next stage's feasibility F^{i+1} (ours), its PPO critic (V-Chain) or a discriminator reward
    (T-STAR) — any callable mapping a (history, obs_dim) array to a float. A step whose episode ended in a
    simulator error gets no bonus. The bonus paid is reported in ``info["reward/transition"]``.

    Args:
        env: the vector env of the stage being fine-tuned; its episodes must have a fixed length ``episode_length``
            when ``window > 1`` (the window is counted back from it).
        bonus: history -> float.
        lambda1, lambda2: weights of the task reward and of the bonus.
        history: observations per bonus input (H).
        window: steps at the end of an episode that receive the bonus.
        episode_length: the stage's episode length (needed when ``window > 1``).
    """

    def __init__(self, env, bonus: Callable[[np.ndarray], float], lambda1: float = 1.0, lambda2: float = 1.0,
                 history: int = 10, window: int = 1, episode_length: int | None = None):
        super().__init__(env)
        if window > 1 and episode_length is None:
            raise ValueError("a bonus window longer than one step needs the stage's episode_length")
        self.bonus, self.lambda1, self.lambda2 = bonus, lambda1, lambda2
        self.history, self.window, self.episode_length = max(history, 1), window, episode_length
        self._recent: list[list[np.ndarray]] = []
        self._steps = np.zeros(len(env), dtype=int)

    def _start(self, index: int, observation: np.ndarray) -> None:
        self._recent[index] = [np.array(observation)]
        self._steps[index] = 0

    def reset(self, seed: int | None = None, options=None):
        observations, infos = self.env.reset(seed=seed, options=options)
        self._recent = [[np.array(o)] for o in observations]
        self._steps[:] = 0
        return observations, infos

    def reset_at(self, index: int, seed: int | None = None, options: dict | None = None):
        observation, info = self.env.reset_at(index, seed=seed, options=options)
        self._start(index, observation)
        return observation, info

    def step(self, actions):
        observations, rewards, terminated, truncated, infos = self.env.step(actions)
        rewards = self.lambda1 * np.asarray(rewards, dtype=np.float64)
        for index in range(len(self.env)):
            done = bool(terminated[index] or truncated[index])
            last = infos[index].get("final_observation", observations[index]) if done else observations[index]
            self._recent[index] = (self._recent[index] + [np.array(last)])[-self.history:]
            self._steps[index] += 1
            in_window = done or (self.window > 1 and self._steps[index] > self.episode_length - self.window)
            paid = 0.0
            if in_window and not infos[index].get("simulator_error", False):
                paid = self.lambda2 * float(self.bonus(pad_history(np.stack(self._recent[index]), self.history)))
            rewards[index] += paid
            infos[index]["reward/transition"] = paid
            if done:
                self._start(index, observations[index])
        return observations, rewards, terminated, truncated, infos
