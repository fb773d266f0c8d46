"""A whole chain of sub-tasks as one gymnasium episode (the RL-scratch and Curriculum RL baselines).

Each stage keeps its own :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`; when a stage's time budget
(its ``episode_length``) runs out, its final state is restored into the next stage's env (forward
initialization's hand-off, a few state writes) and the episode continues there. The episode ends when the last
stage's budget runs out (truncated; ``success`` is the last stage's success test), when a stage fails
(terminated) or on a simulator error (truncated, flagged). The reward is the active stage's own reward.

Observation: the active stage's observation zero-padded to the largest stage's size, then a one-hot of the
stage index (a single policy must know which sub-task it is in). Action: the sub-tasks' shared 19-dim action.
Consecutive stages on different station scenes hand over the robot and the target object
(``envs/scene_handoff.py``); the constructor checks that every object has a counterpart in the next scene.
"""

from itertools import pairwise

import gymnasium as gym
import numpy as np

from seqdex_drake.env_state import check_handoff
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.base import TaskConfig


class ChainEnv(gym.Env):
    """Stages run back to back in one episode.

    Args:
        stages: registered sub-task names, first to last.
        configs: one TaskConfig per stage (default: each task's default config).
        start_stage: the stage episodes start in (reset from that stage's own distribution); Curriculum RL moves
            it from the last stage back to the first. Settable between episodes.
        envs: already built stage envs to use instead of building them (``configs`` is then ignored).
    """

    metadata = {"render_modes": []}

    def __init__(self, stages: list[str], configs: list[TaskConfig | None] | None = None, start_stage: int = 0,
                 envs: list | None = None):
        configs = configs or [None] * len(stages)
        if len(configs) != len(stages) or (envs is not None and len(envs) != len(stages)):
            raise ValueError(f"{len(stages)} stages need as many configs / envs")
        self.stages = list(stages)
        self.envs = list(envs) if envs is not None else [make_env(name, config)
                                                         for name, config in zip(stages, configs, strict=True)]
        for source, target in pairwise(self.envs):  # Hand-offs across scenes: envs/scene_handoff.py
            if source.plant.num_positions() != target.plant.num_positions():
                check_handoff(source.objects.names, target.objects.names)
        self.dims = [env.observation_space.shape[0] for env in self.envs]
        self.padded = max(self.dims)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (self.padded + len(stages),), np.float32)
        self.action_space = self.envs[0].action_space
        self.start_stage = start_stage
        self.stage = start_stage

    @property
    def env(self):
        """The active stage's env."""
        return self.envs[self.stage]

    def _observation(self, observation: np.ndarray) -> np.ndarray:
        out = np.zeros(self.observation_space.shape, np.float32)
        out[:len(observation)] = observation
        out[self.padded + self.stage] = 1.0
        return out

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = dict(options or {})
        start = int(options.pop("start_stage", self.start_stage))
        if not 0 <= start < len(self.stages):
            raise ValueError(f"start_stage must be in [0, {len(self.stages) - 1}], got {start}")
        if seed is not None:  # Seed every stage's random stream, so hand-offs are deterministic too.
            for index, env in enumerate(self.envs):
                if index != start:
                    env.reset(seed=seed + index)
        self.stage = start
        observation, info = self.env.reset(seed=seed, options=options or None)
        return self._observation(observation), dict(info, stage=self.stage, success=False)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        info = dict(info, stage=self.stage, stage_success=bool(info.get("success", False)))
        last = self.stage == len(self.stages) - 1
        if terminated or info.get("simulator_error") or info.get("nan_action") or (truncated and last):
            info["success"] = bool(last and not terminated and info["stage_success"])
            return self._observation(observation), reward, terminated, truncated or not terminated, info
        info["success"] = False
        if truncated:  # The stage's time budget ran out: hand its final state to the next stage.
            state = self.env.get_state()
            self.stage += 1
            observation, reset_info = self.env.reset(options={"initial_state": state})
            info["handover"] = True
        return self._observation(observation), reward, False, False, info

    def get_state(self):
        return self.env.get_state()

    def close(self) -> None:
        for env in self.envs:
            env.close()
