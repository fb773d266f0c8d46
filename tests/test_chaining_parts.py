"""Chain specs, the serial vector env, the chaining wrappers and the switcher rule of chain rollouts, on small
hand-made envs (the Drake-backed pieces are covered in test_chain_pipeline.py)."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from seqdex_drake.chaining.chain import ChainError, ChainNames, LoadChain
from seqdex_drake.chaining.rollouts import collect_transitions, run_chain, run_prefix
from seqdex_drake.chaining.wrappers import InitialStateVectorEnv, TransitionBonusVectorEnv
from seqdex_drake.env_state import SceneHandoffError
from seqdex_drake.envs.serial import SerialVectorEnv
from seqdex_drake.tasks.registry import task_names


class CounterEnv(gym.Env):
    """Observation [position, steps]; the action adds to the position; episodes last ``length`` steps; reward =
    position; success when the position ends above ``goal``. Its state is (position, steps)."""

    def __init__(self, length=3, goal=1.0):
        self.config = dataclasses.make_dataclass("Config", [("episode_length", int)])(length)
        self.goal = goal
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.position, self.steps = 0.0, 0

    def _obs(self):
        return np.array([self.position, self.steps], np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        state = (options or {}).get("initial_state")
        self.position = float(self.np_random.uniform(-0.1, 0.1)) if state is None else state[0]
        self.steps = 0
        return self._obs(), {"success": False}

    def step(self, action):
        self.position += float(np.asarray(action).reshape(-1)[0])
        self.steps += 1
        return (self._obs(), self.position, False, self.steps >= self.config.episode_length,
                {"success": self.position > self.goal})

    def get_state(self):
        return (self.position, self.steps)


def test_shipped_chains_load_and_name_registered_tasks():
    assert {"building_blocks", "tool_positioning", "handover"} <= set(ChainNames())
    chain = LoadChain("building_blocks", valid_tasks=task_names())
    assert chain.stages == ["search", "retrieve", "orient", "grasp", "insert"]
    assert LoadChain("building_blocks_policies", valid_tasks=task_names()).stages == [
        "search", "orient", "grasp", "insert"]
    assert chain.next_task("grasp") == "insert" and chain.previous_task("search") is None


def test_chain_file_errors(tmp_path):
    with pytest.raises(ChainError, match="unknown chain 'nope'.*handover"):
        LoadChain("nope")
    path = tmp_path / "chains.yaml"
    path.write_text("short: {stages: [reach]}\ntypo: {stages: [reach, lowr]}\n")
    with pytest.raises(ChainError, match="at least two"):
        LoadChain("short", path)
    with pytest.raises(ChainError, match="unknown stage.*lowr.*valid sub-tasks"):
        LoadChain("typo", path, valid_tasks=task_names())
    path.write_text("bad: {stagez: [reach, lower]}\n")
    with pytest.raises(ChainError, match="stagez"):  # Unknown keys anywhere in the file are rejected.
        LoadChain("bad", path)


def test_serial_vector_env_autoresets_like_a_serial_env():
    vec = SerialVectorEnv([lambda: CounterEnv(length=2)] * 2, seed=5)
    reference = CounterEnv(length=2)
    observations, _ = vec.reset()
    first, _ = reference.reset(seed=6)
    np.testing.assert_array_equal(observations[1], first)
    vec.step(np.ones((2, 1)))
    observations, rewards, terminated, truncated, infos = vec.step(np.ones((2, 1)))
    assert truncated.all() and not terminated.any()
    np.testing.assert_allclose(infos[1]["final_observation"], [first[0] + 2, 2])
    assert infos[1]["episode"]["length"] == 2 and infos[1]["final_info"]["success"]
    assert observations[1][1] == 0  # The new episode's first observation.


def test_transition_bonus_is_paid_at_the_terminal_step_on_the_last_h_observations():
    seen = []

    def bonus(history):
        seen.append(history.copy())
        return 10.0

    env = TransitionBonusVectorEnv(SerialVectorEnv([lambda: CounterEnv(length=3)], seed=0), bonus, lambda1=0.5,
                                   lambda2=2.0, history=2)
    env.reset()
    rewards = [env.step(np.ones((1, 1)))[1][0] for _ in range(3)]
    start = seen[0][0, 0] - 2  # The history ends with the final observation: positions start + 2, start + 3.
    np.testing.assert_allclose(rewards[:2], [0.5 * (start + 1), 0.5 * (start + 2)])
    np.testing.assert_allclose(rewards[2], 0.5 * (start + 3) + 2.0 * 10.0)
    assert len(seen) == 1 and seen[0].shape == (2, 2)
    np.testing.assert_allclose(seen[0][:, 1], [2, 3])  # steps 2 and 3: the terminal window.


def test_initial_state_wrapper_restarts_every_episode_from_the_buffer():
    class Buffer:
        def sample(self, rng, state_type, successful_only=True):
            return dataclasses.make_dataclass("Entry", [("state", tuple)])((5.0, 0))

    env = InitialStateVectorEnv(SerialVectorEnv([lambda: CounterEnv(length=1)], seed=0), Buffer(), seed=0,
                                state_type=tuple)
    observations, _ = env.reset()
    assert observations[0][0] == 5.0
    observations, *_ = env.step(np.ones((1, 1)))
    assert observations[0][0] == 5.0  # Reset again from the buffer, not from the env's own distribution.


class ConstantF:
    """A feasibility stand-in: F = value(history), threshold 1."""

    def __init__(self, value):
        self.threshold = 1.0
        self.model = dataclasses.make_dataclass("M", [("obs_dim", int), ("predict", object)])(2, value)


def test_run_chain_sequential_and_switcher_rules():
    envs = [CounterEnv(length=3, goal=0.5), CounterEnv(length=3, goal=1.0), CounterEnv(length=3, goal=2.0)]
    forward = [lambda obs: np.ones(1)] * 3
    outcome = run_chain(envs, forward, seed=0)
    assert outcome.stages_run == [0, 1, 2] and outcome.switches == 0 and outcome.steps == 9 and outcome.success

    # F^2 says stage 1 is feasible once the position exceeds 1.5: the switcher hands over early (2 steps), and
    # F^3 never qualifies, so after stage 1 the walk-back finds F^2 > 1 again (recovery to stage 1) until the cap.
    feasibility = [ConstantF(lambda h: 2.0 if h[-1, 0] > 1.5 else 0.0), ConstantF(lambda h: 0.0)]
    outcome = run_chain(envs, forward, seed=0, feasibility=feasibility, max_switches=2)
    assert outcome.stages_run[:2] == [0, 1] and outcome.stages_run.count(1) == 3 and outcome.switches == 2
    assert outcome.stages_run[-1] == 2  # With the switches used up, plain sequential order resumes.

    # Bypass: F^3 > 1 right away sends stage 0 straight to the last stage (one switch).
    bypass = [ConstantF(lambda h: 0.0), ConstantF(lambda h: 5.0)]
    outcome = run_chain(envs, forward, seed=0, feasibility=bypass, max_switches=1)
    assert outcome.stages_run == [0, 2] and outcome.switches == 1

    # Restart: nothing is feasible, so each hand-over restarts stage 0 while switches last.
    outcome = run_chain(envs, forward, seed=0, feasibility=[ConstantF(lambda h: 0.0)] * 2, max_switches=2)
    assert outcome.stages_run == [0, 0, 0, 1, 2] and outcome.switches == 2

    # max_switches = 0 ignores F entirely.
    assert run_chain(envs, forward, seed=0, feasibility=bypass, max_switches=0).stages_run == [0, 1, 2]

    # A restart into a scene that cannot hold the state (Building Blocks: a single block back to the pile) ends the
    # episode as a failure instead of raising.
    class PileEnv(CounterEnv):
        def reset(self, *, seed=None, options=None):
            if (options or {}).get("initial_state") is not None:
                raise SceneHandoffError("the handed-over target object 'block_1' has no counterpart")
            return super().reset(seed=seed, options=options)

    outcome = run_chain([PileEnv(length=3, goal=0.5), *envs[1:]], forward, seed=0,
                        feasibility=[ConstantF(lambda h: 0.0)] * 2, max_switches=2)
    assert outcome.stages_run == [0, 0] and not outcome.success and outcome.switches == 1


def test_intermediate_transitions_hand_over_before_the_previous_stage_ends():
    envs = [CounterEnv(length=6, goal=3.0), CounterEnv(length=3, goal=4.0)]
    data = collect_transitions(envs, [lambda obs: np.ones(1)] * 2, 1, episodes=2, seed=0, history=4,
                               intermediate=5)
    steps = np.array([state[1] for state in data.states])  # Stage 0's steps at each hand-over.
    assert data.histories.shape == (7, 4, 2) and len(data.returns) == 7
    assert list(steps[:2]) == [6, 6]  # Terminal hand-overs: the whole budget.
    assert np.all((steps[2:] >= 1) & (steps[2:] <= 5))  # Early ones: after 1 .. budget - 1 steps.
    # The history ends at the hand-over, and stage 1 starts there: fewer steps of stage 0, a lower return.
    np.testing.assert_array_equal(data.histories[:, -1, 1], steps)
    assert np.all(data.returns[2:] < data.returns[0]) and data.successes[:2].all()
    # The same seed draws the same cut points.
    again = collect_transitions(envs, [lambda obs: np.ones(1)] * 2, 1, episodes=2, seed=0, history=4, intermediate=5)
    np.testing.assert_array_equal([state[1] for state in again.states], steps)


class DrawingEnv(CounterEnv):
    """A stage that draws on a hand-over, as Insert draws its plate and goal: the handed-over position moves by a
    draw from the env's generator."""

    def reset(self, *, seed=None, options=None):
        observation, info = super().reset(seed=seed, options=options)
        if (options or {}).get("initial_state") is not None:
            self.position += float(self.np_random.uniform(-1.0, 1.0))
        return self._obs(), info


def test_hand_overs_draw_the_same_for_the_same_episode_seed_whatever_the_envs_did_before():
    def stages():
        return [CounterEnv(length=2), DrawingEnv(length=2), DrawingEnv(length=2)]

    forward = [lambda obs: np.ones(1)] * 3
    fresh = run_prefix(stages(), forward, 2, seed=5).state
    used = stages()  # Envs with a history: seeded otherwise and stepped before.
    for index, env in enumerate(used):
        env.reset(seed=1000 + index)
        env.step(np.ones(1))
    assert run_prefix(used, forward, 2, seed=5).state == fresh
    assert run_prefix(stages(), forward, 2, seed=6).state != fresh  # Another episode draws otherwise.
    # F's transitions (the next stage's returns from each hand-over) and the switcher's episodes alike.
    first = collect_transitions(stages(), forward, 2, episodes=2, seed=0, history=2, intermediate=2)
    np.testing.assert_array_equal(collect_transitions(used, forward, 2, episodes=2, seed=0, history=2,
                                                      intermediate=2).returns, first.returns)
    switcher = [ConstantF(lambda h: 0.0), ConstantF(lambda h: 0.0)]  # Restarts: stage 0 from a handed-over state.
    runs = [run_chain(envs, forward, seed=3, feasibility=switcher, max_switches=2) for envs in (stages(), used)]
    assert runs[0] == runs[1] and runs[0].switches == 2


def test_knocked_out_transitions_knock_the_object_out_late_in_the_previous_stage():
    """A knock-out (here: the position reset to 0) applied once, in the second half of stage 0's budget; stage 0
    still runs to its end, and stage 1 starts from the knocked-out state (so it fails: F learns a drop)."""
    envs = [CounterEnv(length=6, goal=3.0), CounterEnv(length=3, goal=7.0)]  # Stage 1 needs stage 0's all.
    knocks = []

    def knock_out(env, rng):
        knocks.append(env.steps)
        env.position = 0.0

    data = collect_transitions(envs, [lambda obs: np.ones(1)] * 2, 1, episodes=2, seed=0, history=4,
                               knocked_out=4, knock_out=knock_out)
    assert len(data.returns) == 6 and len(knocks) == 4 and all(3 <= step <= 5 for step in knocks)
    assert [state[1] for state in data.states] == [6] * 6  # Every source run used its whole budget.
    np.testing.assert_array_equal([state[0] for state in data.states[2:]], [6 - step for step in knocks])
    assert data.successes[:2].all() and not data.successes[2:].any()
    with pytest.raises(ValueError, match="need a knock_out function"):
        collect_transitions(envs, [lambda obs: np.ones(1)] * 2, 1, episodes=1, seed=0, knocked_out=1)


def test_the_pipeline_refuses_a_chain_with_a_scripted_stage_and_says_what_to_train(tmp_path):
    from seqdex_drake.chaining.bidirectional import Pipeline
    from seqdex_drake.chaining.pipeline import PipelineConfig, PipelineError

    config = PipelineConfig.tiny(chain="building_blocks", method="seqdex")
    with pytest.raises(PipelineError, match="scripted stage.s. retrieve .*learned stages only"):
        Pipeline(LoadChain("building_blocks"), config, tmp_path / "run")
    assert not (tmp_path / "run").exists()  # Refused before anything was written.
