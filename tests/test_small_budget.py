"""The small-budget training levers: scripted phases, demonstrations (collection, success filter, file checks),
behaviour cloning, the DAPG term and the budget preset of ``seqdex train``."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.demonstrations import Demonstrations, behaviour_clone, collect_demonstrations
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv
from seqdex_drake.tasks.handover_common import hand_center
from seqdex_drake.tasks.phases import ScriptedPhases, apply_phases, release_tool_grasp_phases
from seqdex_drake.tasks.registry import budget_config, default_config

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------------ scripted phases
def test_apply_phases_follows_the_release_schedule():
    phases = release_tool_grasp_phases()
    action, previous = [0.3] * 16 + [0.5, -0.5, -1.0], [0.1] * 16 + [0.0, 0.0, 0.0]
    assert apply_phases(phases, 59, action, previous) == (action, False)  # The policy's own.
    lifted, frozen = apply_phases(phases, 60, action, previous)
    assert lifted[16:] == [0.0, 0.0, 1.0] and lifted[:16] == action[:16] and not frozen
    still, frozen = apply_phases(phases, 90, action, previous)
    assert still[16:] == [0.0, 0.0, 0.0] and still[:16] == previous[:16] and frozen
    assert apply_phases(None, 70, action, previous) == (action, False)
    assert apply_phases(ScriptedPhases(), 70, action, previous) == (action, False)


def test_phases_reject_a_lift_that_ends_before_it_starts():
    with pytest.raises(ValueError, match="lift_end"):
        ScriptedPhases(lift_start=60, lift_end=50)
    with pytest.raises(ValueError, match="lift_action"):
        ScriptedPhases(lift_start=60, lift_end=70, lift_action=2.0)


def test_tool_grasp_budget_env_lifts_by_script_and_freezes_the_hand():
    """Whatever the policy sends (here: wrist down, hand changing every step), the arm rises over steps 60-90
    and the hand's targets stay put from step 90 on."""
    config = budget_config("tool_grasp")
    assert config.phases == release_tool_grasp_phases() and config.reward.lift > 0
    env = make_env("tool_grasp", dataclasses.replace(config, episode_length=95, residual="", hand_actions=True))
    observation, _ = env.reset(seed=0)
    assert env.observation_space.shape == (160,) and observation[159] == 0.0  # The progress entry.
    rng = np.random.default_rng(0)
    heights, hand_targets = {}, {}
    for step in range(95):
        action = np.r_[rng.uniform(-1, 1, 16), 0.0, 0.0, -1.0]
        observation, _, _, _, info = env.step(action)
        assert observation[159] == np.float32((step + 1) / 95)
        heights[step] = env.ik.palm_point(env._arm_target)[2]
        hand_targets[step] = list(env._hand_target)
        assert "reward/lift" in info
    assert heights[59] < heights[0]  # The policy's wrist action (down) applied before step 60.
    assert heights[89] - heights[59] == pytest.approx(30 * config.wrist_step, abs=0.01)  # The scripted lift.
    assert all(heights[k + 1] > heights[k] for k in range(59, 89))
    assert heights[94] == pytest.approx(heights[89], abs=1e-4)
    assert hand_targets[89] == hand_targets[90] == hand_targets[94] != hand_targets[88]


def test_paper_config_has_no_phases():
    assert default_config("tool_grasp").phases is None and default_config("tool_grasp").reward.lift == 0
    assert budget_config("lower") == default_config("lower")  # No budget variant: its default.


# ------------------------------------------------------------------------------------------ demonstrations
class _DownController:
    """Lower's best policy (straight down at full speed): succeeds from 12.5 cm above the block, not above."""

    def reset(self, env):
        self.start_height = float(hand_center(env)[2] - env.object_position()[2])

    def action(self, env, step):
        return np.r_[np.zeros(16), 0.0, 0.0, -1.0]


@pytest.fixture(scope="module")
def lower_demos():
    env = make_env("lower")
    demos = collect_demonstrations(env, _DownController(), "lower", episodes=3, seed=0, max_attempts=12)
    return env, demos


def test_collected_demonstrations_are_exactly_the_successful_episodes(lower_demos):
    env, demos = lower_demos
    assert demos.task == "lower" and demos.source == "_DownController" and demos.num_episodes >= 1
    # Replaying every attempt's seed shows which succeeded: the kept episodes are those, in order.
    successes = []
    for attempt in range(demos.attempts):
        obs, _ = env.reset(seed=attempt)
        for _ in range(env.config.episode_length):
            obs, _, terminated, truncated, info = env.step(np.r_[np.zeros(16), 0.0, 0.0, -1.0])
            if terminated or truncated:
                break
        successes.append(bool(info["success"]))
    assert sum(successes) == demos.num_episodes and not all(successes)
    first = successes.index(True)
    obs, _ = env.reset(seed=first)
    np.testing.assert_array_equal(demos.observations[0], obs)
    assert len(demos) == demos.num_episodes * env.config.episode_length
    assert np.all(demos.actions[:, 18] == -1.0)


def test_demonstration_files_round_trip_and_refuse_other_tasks(lower_demos, tmp_path):
    _, demos = lower_demos
    path = demos.save(tmp_path / "lower.npz")
    loaded = Demonstrations.load(path, expected_task="lower", expected_obs_dim=demos.observations.shape[1])
    np.testing.assert_array_equal(loaded.actions, demos.actions)
    np.testing.assert_array_equal(loaded.episode_starts, demos.episode_starts)
    with pytest.raises(ValueError, match="demonstrations of lower, not tool_grasp"):
        Demonstrations.load(path, expected_task="tool_grasp")
    with pytest.raises(ValueError, match="another observation layout"):
        Demonstrations.load(path, expected_obs_dim=173)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match="truncated.npz is not a readable demonstration file"):
        Demonstrations.load(truncated)
    with pytest.raises(ValueError, match="does not exist"):
        Demonstrations.load(tmp_path / "missing.npz")


def test_concatenated_demonstrations_keep_their_episodes(lower_demos):
    _, demos = lower_demos
    both = Demonstrations.concatenate([demos, demos])
    assert both.num_episodes == 2 * demos.num_episodes and both.attempts == 2 * demos.attempts
    np.testing.assert_array_equal(both.episode_starts[demos.num_episodes:], demos.episode_starts + len(demos))
    np.testing.assert_array_equal(both.returns(0.9)[len(demos):], demos.returns(0.9))
    with pytest.raises(ValueError, match="one task"):
        Demonstrations.concatenate([demos, dataclasses.replace(demos, task="reach")])


def test_returns_are_discounted_within_each_episode():
    demos = Demonstrations("x", np.zeros((5, 2), np.float32), np.zeros((5, 1), np.float32),
                           np.array([1, 1, 1, 2, 2], np.float32), np.array([0, 3]))
    np.testing.assert_allclose(demos.returns(0.5), [1.75, 1.5, 1.0, 3.0, 2.0])


# ------------------------------------------------------------------------------------- BC and the DAPG term
def _linear_demos(n=512, seed=0) -> Demonstrations:
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, 3)).astype(np.float32) * 4 + 10
    obs[:, 2] = np.arange(n) % 16  # The step in the episode: what the returns depend on.
    actions = np.tanh((obs - 10) @ np.array([[0.3, -0.2], [0.1, 0.4], [-0.25, 0.05]])).astype(np.float32)
    return Demonstrations("toy", obs, actions, np.ones(n, np.float32), np.arange(0, n, 16))


def test_behaviour_cloning_fits_the_actions_and_the_returns():
    demos = _linear_demos()
    torch.manual_seed(0)
    model = ActorCritic(3, 2, (64, 64), (64, 64))
    with torch.no_grad():  # Squared error summed over the action dims, averaged over transitions (as BC's).
        errors = model.action_mean(torch.as_tensor(demos.observations)) - torch.as_tensor(demos.actions)
        before = float(errors.square().sum(-1).mean())
    metrics = behaviour_clone(model, demos, gamma=0.9, epochs=60, batch_size=64)
    assert metrics["bc/actor_mse"] < 0.1 * before
    assert metrics["bc/critic_mse"] < 0.1 * float(np.var(demos.returns(0.9)))
    assert float(model.obs_normalizer.count) == len(demos)


def test_the_dapg_term_pulls_the_policy_toward_the_demonstrations_and_decays():
    """Two learners from one seed on the toy env (target 0.5); one has demonstrations of action -0.5 with a
    large weight: its mean action moves toward -0.5, and the logged weight decays by demo_decay per update."""
    config = PPOConfig(actor_hidden_sizes=(32,), critic_hidden_sizes=(32,), num_envs=4, horizon=16,
                       num_epochs=4, num_minibatches=2, adaptive_lr=False, learning_rate=3e-3, seed=3,
                       demo_coef=5.0, demo_decay=0.5)
    obs = np.random.default_rng(0).normal(size=(256, 3)).astype(np.float32)
    demos = Demonstrations("toy", obs, np.full((256, 1), -0.5, np.float32), np.zeros(256, np.float32),
                           np.array([0]))
    means, weights = [], []
    for with_demos in (False, True):
        ppo = PPO(config, 3, 1, [-1.0], [1.0])
        ppo.demos = demos if with_demos else None
        env = TargetVectorEnv(num_envs=4, seed=3)
        for _ in range(3):
            ppo.collect(env)
            weights.append(ppo.update()["losses/demo_weight"])
        with torch.no_grad():
            means.append(float(ppo.model.action_mean(torch.as_tensor(obs)).mean()))
    assert means[1] < means[0] - 0.1
    assert weights == [0.0, 0.0, 0.0, 5.0, 2.5, 1.25]


def test_reward_scale_scales_what_the_learner_stores():
    env = TargetVectorEnv(num_envs=2, seed=0)
    stored = []
    for scale in (1.0, 0.1):
        ppo = PPO(PPOConfig(actor_hidden_sizes=(8,), critic_hidden_sizes=(8,), num_envs=2, horizon=4,
                            reward_scale=scale, seed=0), 3, 1, [-1.0], [1.0])
        ppo.collect(TargetVectorEnv(num_envs=2, seed=0))
        stored.append(ppo.buffer.rewards.clone())
    torch.testing.assert_close(stored[1], stored[0] * 0.1)
    del env


# ------------------------------------------------------------------------------------------------- the CLI
def _seqdex(*args, cwd):
    return subprocess.run([sys.executable, "-m", "seqdex_drake.cli.main", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def test_train_with_demonstrations_and_refusing_another_tasks(lower_demos, tmp_path):
    _, demos = lower_demos
    path = demos.save(tmp_path / "lower.npz")
    done = _seqdex("train", "--task", "lower", "--test", "--num-envs", "2", "--demos", str(path),
                   "--run-dir", str(tmp_path / "run"), cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "behaviour-cloned on" in done.stderr
    assert "steps 0 -> 16 (whole updates of 16 steps" in done.stderr  # --test: 2 envs x 8 steps, one update.
    refused = _seqdex("train", "--task", "reach", "--test", "--num-envs", "2", "--demos", str(path),
                      "--run-dir", str(tmp_path / "other"), cwd=ROOT)
    assert refused.returncode == 2
    assert "holds demonstrations of lower, not reach" in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "other").exists()


# ------------------------------------------------------------------------------------------ learning curves
def test_learning_curves_merge_resumed_runs_and_count_only_training_time(tmp_path):
    """Two sessions of one run (the second resumed after a pause): one curve, steps ascending, wall-clock
    without the pause."""
    import time

    from seqdex_drake.evaluation.learning_curves import read_curve, write_curve

    config = PPOConfig(actor_hidden_sizes=(8,), critic_hidden_sizes=(8,), num_envs=4, horizon=16, seed=0)
    ppo = PPO(config, 3, 1, [-1.0], [1.0])
    ppo.train(TargetVectorEnv(num_envs=4), tmp_path / "run", total_steps=128, progress=False)
    time.sleep(1.5)  # The pause between sessions.
    resumed = PPO.resume(tmp_path / "run" / "last.pt")
    resumed.train(TargetVectorEnv(num_envs=4), tmp_path / "run", total_steps=256, progress=False)
    curve = read_curve(tmp_path / "run")
    assert list(curve["env_steps"]) == list(range(64, 257, 64))
    assert np.all(np.diff(curve["wall_clock_s"]) > 0) and curve["wall_clock_s"][-1] < 1.5
    csv_path, png_path = write_curve(tmp_path / "run", tmp_path / "curve")
    assert csv_path.read_text().splitlines()[0].startswith("env_steps,wall_clock_s,success_rate")
    assert png_path.stat().st_size > 1000
    with pytest.raises(ValueError, match="holds no training events"):
        read_curve(tmp_path)


def test_a_curve_that_continues_another_runs_checkpoint_counts_only_its_own_updates(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    from seqdex_drake.evaluation.learning_curves import read_curve

    writer = SummaryWriter(str(tmp_path))  # A fine-tuning phase: its first update ends at step 10 064, 10 s apart.
    for i, step in enumerate((10_064, 10_128, 10_192)):
        writer.add_scalar("charts/SPS", 6.4, step, walltime=100.0 + 10.0 * i)
    writer.close()
    curve = read_curve(tmp_path)
    # The first update took one batch (64 steps) at 6.4 steps/s, not 10 064 steps' worth.
    np.testing.assert_allclose(curve["wall_clock_s"], [10.0, 20.0, 30.0])


def test_policy_system_applies_the_phases_on_its_active_ticks():
    """A deployed policy trained with scripted phases gets them too: its raw action follows the schedule on the
    ticks counted since it became active (here: always active, from tick 0)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from seqdex_drake.controller.policy import PolicyParams, PolicySystem

    torch.manual_seed(0)
    model = ActorCritic(159, 19, (), (8,))  # Linear: action = W obs + b (the normalizer is still the identity).
    with torch.no_grad():  # The wrist always down; the hand at observation entry 0.
        model.actor[-1].weight.zero_()
        model.actor[-1].weight[:16, 0] = 1.0
        model.actor[-1].bias.copy_(torch.tensor([0.0] * 16 + [0.0, 0.0, -1.0]))
    builder = DiagramBuilder()
    system = builder.AddSystem(PolicySystem(model, 159, PolicyParams(ema=1.0, phases=release_tool_grasp_phases())))
    source = builder.AddSystem(ConstantVectorSource(np.r_[0.5, np.zeros(158)]))
    builder.Connect(source.get_output_port(), system.GetInputPort("observation"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = system.GetMyContextFromRoot(simulator.get_mutable_context())
    raw = {}
    for tick in range(95):
        if tick == 92:  # From here on the policy asks for the hand at -0.5: too late, the hand is frozen.
            source.get_mutable_source_value(source.GetMyMutableContextFromRoot(simulator.get_mutable_context())) \
                .SetFromVector(np.r_[-0.5, np.zeros(158)])
        simulator.AdvanceTo((tick + 0.5) / 60.0)  # After the update of tick ``tick`` (at tick / 60 s).
        raw[tick] = system.GetOutputPort("raw_action").Eval(context).copy()
    np.testing.assert_allclose(raw[59], [0.5] * 16 + [0.0, 0.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(raw[60][16:], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(raw[89][16:], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(raw[90][16:], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(raw[94], raw[90])  # The hand holds the step-89 targets ...
    np.testing.assert_allclose(raw[94][:16], 0.5)  # ... whatever the policy asks for now.


def test_collect_demos_script_keeps_a_scripted_tool_grasp(tmp_path):
    """scripts/collect_demos.py on tool grasp, from a seed the scripted grasp succeeds on: one kept episode in the
    budget env (the scripted lift in its actions), in a file that seqdex train --demos reads."""
    out = tmp_path / "demos.npz"
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "collect_demos.py"), "--task", "tool_grasp",
                           "--episodes", "1", "--seed", "1", "--test", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    demos = Demonstrations.load(out, expected_task="tool_grasp", expected_obs_dim=160)
    assert demos.num_episodes == 1 and len(demos) == 150 and demos.attempts == 1
    np.testing.assert_array_equal(demos.actions[60:90, 16:], np.tile([0.0, 0.0, 1.0], (30, 1)))
    refused = subprocess.run([sys.executable, str(ROOT / "scripts" / "collect_demos.py"), "--task", "search",
                              "--episodes", "1", "--out", str(tmp_path / "x.npz")], capture_output=True, text=True)
    assert refused.returncode == 2 and "no scripted controller for 'search'" in refused.stderr


def test_policy_system_feeds_a_time_aware_policy_its_progress():
    """A policy trained with observe_time reads the stage observation plus ticks / episode length."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from seqdex_drake.controller.policy import PolicyParams, PolicySystem

    model = ActorCritic(160, 19, (), (8,))  # Linear: hand dim 0 = the progress entry.
    with torch.no_grad():
        model.actor[-1].weight.zero_()
        model.actor[-1].bias.zero_()
        model.actor[-1].weight[0, 159] = 1.0
    with pytest.raises(ValueError, match="reads 160-dim observations"):
        PolicySystem(model, 160, PolicyParams(time_steps=150))
    builder = DiagramBuilder()
    system = builder.AddSystem(PolicySystem(model, 159, PolicyParams(ema=1.0, time_steps=150)))
    source = builder.AddSystem(ConstantVectorSource(np.zeros(159)))
    builder.Connect(source.get_output_port(), system.GetInputPort("observation"))
    simulator = Simulator(builder.Build())
    context = system.GetMyContextFromRoot(simulator.get_mutable_context())
    for tick in (0, 30, 75):
        simulator.AdvanceTo((tick + 0.5) / 60.0)
        assert system.GetOutputPort("raw_action").Eval(context)[0] == pytest.approx(tick / 150, abs=1e-6)
