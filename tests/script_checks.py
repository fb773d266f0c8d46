"""Checks every scripted residual base (``scene/block_*_script.py``) must pass, shared by their test files: the
script is Markov in (observation, step), and a budget env given zero corrections applies exactly its action."""

import numpy as np


def assert_markov(make_script, observation: np.ndarray, steps, without_progress: int):
    """Two scripts from ``make_script`` give the same in-range 19-dim action for ``observation`` at each of
    ``steps``, whether called again, on a copy, or on the observation without its progress entry (its first
    ``without_progress`` entries). Returns the first script."""
    first, second = make_script(), make_script()
    for step in steps:
        action = first.act(observation, step)
        assert action.shape == (19,) and np.all(np.abs(action) <= 1.0)
        np.testing.assert_array_equal(action, first.act(observation.copy(), step))  # No state kept between calls.
        np.testing.assert_array_equal(action, second.act(observation, step))
        np.testing.assert_array_equal(action, first.act(observation[:without_progress], step))  # Progress or not.
    return first


def assert_zero_corrections_apply(env, script, seed: int, steps: int) -> None:
    """The budget ``env`` given zeros applies exactly ``script``'s action of its own observation, step by step."""
    observation, _ = env.reset(seed=seed)
    for step in range(steps):
        expected = script.act(observation, step)
        observation, *_ = env.step(np.zeros(19))
        np.testing.assert_allclose(observation[124:143], expected, atol=1e-6)  # The applied (previous) action.
