"""An in-process vector env over any gymnasium envs, with the process vector env's semantics.

:class:`SerialVectorEnv` steps its envs one after the other in the calling process: no worker start-up, any
env (also ones that are not registered sub-tasks, such as :class:`~seqdex_drake.envs.chain_env.ChainEnv`).
Seeding, SB3-style autoreset and the info keys (``final_observation``, ``final_info``, ``reset_info``,
``episode``) are those of :class:`~seqdex_drake.envs.vector.ProcessVectorEnv`, so PPO and the chaining wrappers
run unchanged on either.
"""

from collections.abc import Callable, Sequence

import numpy as np
from gymnasium.vector.utils import batch_space


class SerialVectorEnv:
    """``len(env_fns)`` envs stepped in this process.

    Args:
        env_fns: callables that each build one env.
        seed: env ``i`` is seeded ``seed + i`` at the first reset.
    """

    backend = "serial"

    def __init__(self, env_fns: Sequence[Callable], seed: int = 0):
        if not env_fns:
            raise ValueError("SerialVectorEnv needs at least one env factory")
        self.envs = [fn() for fn in env_fns]
        self.seed, self.num_envs = seed, len(self.envs)
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._reset_once = False
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, dtype=int)

    def __len__(self) -> int:
        return self.num_envs

    def reset_at(self, index: int, seed: int | None = None, options: dict | None = None):
        """Resets env ``index`` alone; returns its ``(observation, info)``."""
        self._returns[index], self._lengths[index] = 0.0, 0
        return self.envs[index].reset(seed=seed, options=options)

    def reset(self, seed: int | None = None, options: dict | Sequence[dict | None] | None = None):
        """Resets every env (env ``i`` gets ``seed + i``; see ProcessVectorEnv.reset)."""
        if seed is None and not self._reset_once:
            seed = self.seed
        if options is None or isinstance(options, dict):
            options = [options] * self.num_envs
        if len(options) != self.num_envs:
            raise ValueError(f"options must be a dict or {self.num_envs} dicts, got {len(options)}")
        results = [self.reset_at(i, None if seed is None else seed + i, options[i]) for i in range(self.num_envs)]
        self._reset_once = True
        return np.stack([observation for observation, _ in results]), [info for _, info in results]

    def step(self, actions):
        """Steps every env with its row of ``actions``; ended episodes reset at once (SB3 semantics)."""
        if not self._reset_once:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions (one row per env), got {len(actions)}")
        observations, rewards, terminated, truncated, infos = [], [], [], [], []
        for index, env in enumerate(self.envs):
            observation, reward, term, trunc, info = env.step(actions[index])
            self._returns[index] += reward
            self._lengths[index] += 1
            if term or trunc:
                info = dict(info, final_observation=observation, final_info=dict(info),
                            episode={"return": float(self._returns[index]), "length": int(self._lengths[index])})
                observation, info["reset_info"] = self.reset_at(index)
            observations.append(observation)
            rewards.append(reward)
            terminated.append(term)
            truncated.append(trunc)
            infos.append(info)
        return (np.stack(observations).astype(np.float32), np.array(rewards, dtype=np.float64),
                np.array(terminated, dtype=bool), np.array(truncated, dtype=bool), infos)

    def get_states(self) -> list:
        """Each env's restorable state (``env.get_state()``), in env order."""
        return [env.get_state() for env in self.envs]

    def close(self) -> None:
        """Closes the envs (a no-op for Drake sub-task envs, which hold no external resources)."""
        for env in self.envs:
            env.close()
