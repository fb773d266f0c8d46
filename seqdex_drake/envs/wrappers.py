"""Gymnasium wrappers for the sub-task envs made by ``gym.make("seqdex/<Task>-v0")`` (see :mod:`.registration`).

* :class:`FreeActionsWrapper`: exposes only the action dims an agent actually chooses (``low < high``) and fills
  the fixed ones (``low == high``, e.g. the 16 hand dims of a wrist-only task) with their value. Use it for
  learners that do not skip fixed dims themselves (Stable-Baselines3, CleanRL, ...): exploring dims the env
  ignores only adds noise to their updates.
* :class:`EpisodeLengthSync`: applied by ``gym.make`` after its ``TimeLimit``; keeps the env's own episode length
  (``TaskConfig.episode_length``, where the env truncates itself) equal to the ``TimeLimit``'s.

Both import only gymnasium and numpy at module level (no Drake), so registering them is cheap.
"""

import gymnasium as gym
import numpy as np

from seqdex_drake.tasks.registry import default_config


class FreeActionsWrapper(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """The wrapped env's ``Box`` action space reduced to its free dims (those with ``low < high``).

    The wrapper's action space is ``Box(low[free], high[free])``. :meth:`action` maps a reduced action back to the
    full one: the free dims take the given values (in order), every fixed dim (``low == high``) its only value.
    :meth:`reverse_action` maps a full action to the reduced one. An env without fixed dims passes through
    unchanged (same shape). Example, a wrist-only task whose 19 dims include 16 fixed hand dims::

        env = FreeActionsWrapper(gym.make("seqdex/Reach-v0"))
        env.action_space.shape      # (3,): the wrist translation
        env.free_indices            # array([16, 17, 18])

    With Stable-Baselines3: ``make_vec_env("seqdex/Reach-v0", wrapper_class=FreeActionsWrapper)``.

    Args:
        env: an env with a one-dimensional, bounded ``gymnasium.spaces.Box`` action space.

    Raises:
        ValueError: the action space is not a 1-D Box, has infinite bounds, or has no free dim at all.
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.ActionWrapper.__init__(self, env)
        space = env.action_space
        if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"FreeActionsWrapper needs a one-dimensional Box action space, got {space}; wrap an "
                             f"env with a flat continuous action")
        low, high = np.asarray(space.low), np.asarray(space.high)
        if not (np.isfinite(low).all() and np.isfinite(high).all()):
            raise ValueError(f"FreeActionsWrapper needs finite action bounds, got {space}; a dim is fixed only "
                             f"where low == high")
        free = low < high
        if not free.any():
            raise ValueError(f"every dim of the action space {space} is fixed (low == high): there is nothing "
                             f"for an agent to choose")
        self.free_mask = free
        """[A] bool: the full action's dims the agent chooses."""
        self.free_indices = np.flatnonzero(free)
        """Indices of the free dims in the full action, in the order of the reduced action."""
        self._full_template = low.astype(space.dtype)  # The fixed dims' values (low == high there).
        self.action_space = gym.spaces.Box(low[free], high[free], dtype=space.dtype)

    def action(self, action) -> np.ndarray:
        """The full action for the reduced ``action`` (shape ``(number of free dims,)``)."""
        action = np.asarray(action, dtype=self._full_template.dtype)
        if action.shape != self.action_space.shape:
            raise ValueError(f"the reduced action must have shape {self.action_space.shape} (the free dims "
                             f"{self.free_indices.tolist()} of the full action), got {action.shape}")
        full = self._full_template.copy()
        full[self.free_mask] = action
        return full

    def reverse_action(self, action) -> np.ndarray:
        """The reduced action of a full ``action`` (its free dims)."""
        action = np.asarray(action, dtype=self._full_template.dtype)
        if action.shape != self._full_template.shape:
            raise ValueError(f"the full action must have shape {self._full_template.shape}, got {action.shape}")
        return action[self.free_mask]


def _find_time_limit(env: gym.Env) -> gym.wrappers.TimeLimit | None:
    """The outermost ``TimeLimit`` among ``env`` and the wrappers below it, or None."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            return env
        env = env.env
    return None


class EpisodeLengthSync(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Makes a sub-task env's own episode length agree with the ``TimeLimit`` that ``gym.make`` put around it.

    A :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv` truncates itself after ``config.episode_length`` steps;
    ``gym.make`` adds a ``TimeLimit`` of ``max_episode_steps`` (its argument, default the spec's, which is the
    task's default episode length). This wrapper, registered as the spec's additional wrapper, runs once at
    ``gym.make`` time:

    * no ``TimeLimit`` (``max_episode_steps=-1``): nothing to do; the env still ends episodes itself.
    * the config's episode length is the task's default (no ``config``, ``preset`` or ``episode_length`` keyword
      that changes it): the env adopts the ``TimeLimit``'s length, so ``gym.make(id, max_episode_steps=N)`` gives
      N-step episodes.
    * the config's episode length was changed: it must equal the ``TimeLimit``'s, else a ValueError says to pass
      ``max_episode_steps`` too.

    Args:
        env: the env ``gym.make`` built (a ``TimeLimit`` somewhere around a ``SubtaskEnv``).
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        time_limit = _find_time_limit(env)
        config = getattr(self.unwrapped, "config", None)
        if time_limit is None or config is None:
            return
        limit = int(time_limit._max_episode_steps)
        if config.episode_length == limit:
            return

        if config.episode_length != default_config(config.name).episode_length:
            raise ValueError(f"the task config's episode_length {config.episode_length} differs from the time "
                             f"limit {limit} (gym.make's max_episode_steps, default the spec's); pass "
                             f"max_episode_steps={config.episode_length} to gym.make as well")
        config.episode_length = limit  # The entry point made this config for this env alone (not the caller's).
