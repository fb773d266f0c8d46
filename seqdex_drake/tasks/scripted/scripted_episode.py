"""One episode of a scripted base controller (``scene/block_*_script.py``), for measuring it alone.

In an env whose task config names a residual base (a budget variant) the env applies the script itself and the
episode sends zero corrections; in any other env it sends the controller's own actions. Optional Gaussian noise on
the 3 wrist entries of what is sent stands for a residual policy's exploration.
"""

import numpy as np


def play_script(env, seed: int, controller, wrist_noise: float = 0.0, rng: np.random.Generator | None = None
                ) -> tuple[dict, np.ndarray, np.ndarray]:
    """Runs one episode from ``env.reset(seed=seed)`` until it terminates or truncates; ``controller.act(observation,
    step)`` gives the actions where the env has no residual base. Returns the last step's ``info`` (its
    ``success`` is the episode's), the observation at reset and the last observation."""
    rng = rng or np.random.default_rng(seed)
    observation, info = env.reset(seed=seed)
    first = observation
    for step in range(env.config.episode_length):
        action = np.zeros(19) if env.config.residual else np.asarray(controller.act(observation, step), dtype=float)
        if wrist_noise:
            action = action.copy()
            action[16:] += rng.normal(0.0, wrist_noise, 3)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    return info, first, observation
