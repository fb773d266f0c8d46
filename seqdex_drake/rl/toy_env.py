"""A tiny pure-numpy vector env with the API of ``seqdex_drake.envs.vector.ProcessVectorEnv``, for tests and
smoke runs of the learning stack without Drake (like SB3's identity envs).

Task: each step, output an action close to ``target`` (default 0.5). The reward has two named terms,
``alive`` (+1 per step) and ``distance`` (minus the mean absolute error), so a policy that ends episodes early
loses reward. An action farther than ``failure_distance`` from the target is a task failure (``terminated``);
the time limit ``episode_length`` is a truncation. ``success`` is ``distance < success_distance``.

Observation: ``[target, step / episode_length, obs_offset + noise]`` (the last entry is a distractor with a large
offset, which the observation normalizer must take care of).
"""

import gymnasium
import numpy as np


class TargetVectorEnv:
    """``num_envs`` independent copies of the target task, stepped in lockstep with SB3-style autoreset.

    Args:
        num_envs: number of envs.
        action_dim: size of the action vector (every entry should match the target).
        episode_length: steps per episode before truncation.
        target: the action to output.
        failure_distance: mean absolute error above which the episode terminates (task failure).
        success_distance: mean absolute error below which a step counts as a success.
        obs_offset: offset of the distractor observation entry.
        seed: env ``i`` is seeded ``seed + i`` at the first reset (as ProcessVectorEnv).
    """

    def __init__(self, num_envs: int = 4, action_dim: int = 1, episode_length: int = 8, target: float = 0.5,
                 failure_distance: float = 1.2, success_distance: float = 0.2, obs_offset: float = 10.0,
                 seed: int = 0):
        self.num_envs, self.episode_length, self.target = num_envs, episode_length, target
        self.failure_distance, self.success_distance, self.obs_offset = failure_distance, success_distance, obs_offset
        self.seed = seed
        self.single_observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (3,), np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
        self._rngs = [np.random.default_rng(seed + index) for index in range(num_envs)]
        self._steps = np.zeros(num_envs, dtype=np.int64)
        self._returns = np.zeros(num_envs)
        self._reset_once = False

    def __len__(self) -> int:
        return self.num_envs

    def _observation(self, index: int) -> np.ndarray:
        noise = self._rngs[index].normal()
        return np.array([self.target, self._steps[index] / self.episode_length, self.obs_offset + noise],
                        dtype=np.float32)

    def reset(self, seed: int | None = None, options=None):
        """Resets every env; returns ``(observations[num_envs, 3], infos)``."""
        if seed is None and not self._reset_once:
            seed = self.seed
        if seed is not None:
            self._rngs = [np.random.default_rng(seed + index) for index in range(self.num_envs)]
        self._reset_once = True
        self._steps[:] = 0
        self._returns[:] = 0.0
        observations = np.stack([self._observation(index) for index in range(self.num_envs)])
        return observations, [{"success": False} for _ in range(self.num_envs)]

    def step(self, actions):
        """Steps every env; ended episodes reset at once (``final_observation`` / ``final_info`` in the info)."""
        if not self._reset_once:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1)
        distance = np.abs(actions - self.target).mean(axis=1)
        rewards = 1.0 - distance
        terminated = distance > self.failure_distance
        self._steps += 1
        truncated = (self._steps >= self.episode_length) & ~terminated
        self._returns += rewards
        observations, infos = [], []
        for index in range(self.num_envs):
            info = {"reward/alive": 1.0, "reward/distance": -float(distance[index]),
                    "success": bool(distance[index] < self.success_distance)}
            observation = self._observation(index)
            if terminated[index] or truncated[index]:
                info = dict(info, final_info=dict(info), final_observation=observation,
                            episode={"return": float(self._returns[index]), "length": int(self._steps[index])})
                self._steps[index] = 0
                self._returns[index] = 0.0
                observation = self._observation(index)
            observations.append(observation)
            infos.append(info)
        return np.stack(observations), rewards, terminated, truncated, infos

    def state_dict(self) -> dict:
        """Everything that determines the next steps (random streams, step counts, returns) as plain data, so a
        checkpoint can resume the env exactly (see :meth:`seqdex_drake.rl.ppo.PPO.train`)."""
        return {"rngs": [rng.bit_generator.state for rng in self._rngs], "steps": self._steps.tolist(),
                "returns": self._returns.tolist(), "reset_once": self._reset_once}

    def load_state_dict(self, state: dict) -> None:
        """Restores :meth:`state_dict`'s output (same ``num_envs``)."""
        if len(state["rngs"]) != self.num_envs:
            raise ValueError(f"the state is of {len(state['rngs'])} envs, this env has {self.num_envs}")
        for rng, rng_state in zip(self._rngs, state["rngs"], strict=True):
            rng.bit_generator.state = rng_state
        self._steps[:] = state["steps"]
        self._returns[:] = state["returns"]
        self._reset_once = bool(state["reset_once"])

    def close(self) -> None:
        """Nothing to release (API parity with ProcessVectorEnv)."""
