"""Forward initialization with real successes: Reach's terminal states, some successful and some not, collected
as the pipeline collects them (``run_prefix``, a terminal buffer saved and loaded), start Lower's episodes; every
start is one of Reach's *successful* hand-overs, while without the filter failed ones are drawn too."""

import numpy as np

from seqdex_drake.chaining.feasibility import pad_history
from seqdex_drake.chaining.rollouts import run_prefix
from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
from seqdex_drake.chaining.wrappers import InitialStateVectorEnv
from seqdex_drake.envs.serial import SerialVectorEnv
from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.tasks.handover_common import hand_center
from seqdex_drake.tasks.run_config import observation_spec

EPISODES = 8


def _offset(env) -> np.ndarray:
    """The hand centre relative to the block: what decides both Reach's success and Lower's start."""
    return hand_center(env) - env.object_position()


def _collect(tmp_path):
    reach = make_env("reach")
    step = reach.config.wrist_step

    def hover(observation):  # Over the block: Reach succeeds.
        return np.r_[np.zeros(16), np.clip(-_offset(reach)[:2] / step, -1.0, 1.0), 0.0]

    def away(observation):  # Sideways at full speed: Reach fails.
        return np.r_[np.zeros(16), 1.0, 1.0, 0.0]

    buffer = TerminalBuffer("reach", "lower", reach.config.scenario,
                            observation_spec("reach", reach.observation_space.shape[0]), 10)
    offsets = []
    for episode in range(EPISODES):
        result = run_prefix([reach], [hover if episode % 2 == 0 else away], 0, seed=300 + episode)
        assert result.success == reach.task.is_success(reach)
        buffer.append(result.state, pad_history(result.observations, buffer.history), result.episode_return,
                      result.success)
        offsets.append(_offset(reach))
    path = buffer.save(tmp_path / "reach_to_lower.npz")
    return TerminalBuffer.load(path, expected_task="lower"), np.array(offsets)


def _starts(buffer, offsets: np.ndarray, successful_only: bool, resets: int) -> list[int]:
    """The buffer entry each of ``resets`` Lower starts came from (matched by the hand's offset)."""
    lower = make_env("lower")
    env = InitialStateVectorEnv(SerialVectorEnv([lambda: lower], seed=0), buffer, seed=0,
                                successful_only=successful_only)
    drawn = []
    for _ in range(resets):
        env.reset()
        distances = np.linalg.norm(offsets - _offset(lower), axis=1)
        assert distances.min() < 1e-6, "a start that is no hand-over of the buffer"
        drawn.append(int(np.argmin(distances)))
    return drawn


def test_lower_starts_only_from_reachs_successful_hand_overs(tmp_path):
    buffer, offsets = _collect(tmp_path)
    successes = buffer.successes.astype(bool)
    assert successes.tolist() == [episode % 2 == 0 for episode in range(EPISODES)]  # Real successes, real failures.
    assert np.all(np.linalg.norm(offsets[successes, :2], axis=1) < 0.02)
    filtered = _starts(buffer, offsets, successful_only=True, resets=12)
    assert all(successes[index] for index in filtered)
    assert len(set(filtered)) > 1  # Drawn among the successes, not one state.
    unfiltered = _starts(buffer, offsets, successful_only=False, resets=12)
    assert not all(successes[index] for index in unfiltered)  # The filter is what keeps failures out.
