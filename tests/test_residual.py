"""Residual policies on a scripted base (``tasks/residual.py``): the env and a deployed policy system apply the
same ``clip(base + action)``, the budget tool Grasp is one, and the trainer refuses what does not fit it."""

import dataclasses

import numpy as np
import pytest
import torch

from seqdex_drake.envs.subtask_env import make_env
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.tasks.base import TaskConfig
from seqdex_drake.tasks.registry import budget_config
from seqdex_drake.tasks.residual import apply_residual, make_base
from seqdex_drake.tasks.scripted.tool_grasp_script import ScriptedToolGrasp

STEPS = 40  # Through the approach and the start of the closing (the fingers move from step 42 - 1 - 6 on).


def test_apply_residual_adds_and_clips():
    class Constant:
        def act(self, observation, step):
            return np.full(19, 0.8 if step else -0.8)

    assert apply_residual(Constant(), None, 1, [0.1] * 19) == pytest.approx([0.9] * 19)
    assert apply_residual(Constant(), None, 1, [0.5] * 19) == [1.0] * 19
    assert apply_residual(Constant(), None, 0, [-0.5] * 19) == [-1.0] * 19
    assert apply_residual(None, None, 0, np.full(19, 0.3)) == pytest.approx([0.3] * 19)


def test_unknown_base_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown residual base 'nope'; valid bases: tool_grasp_script"):
        make_base("nope")
    with pytest.raises(ValueError, match="residual must be '' or one of tool_grasp_script"):
        TaskConfig(name="x", residual="nope")


def test_budget_tool_grasp_env_with_zero_corrections_is_the_script():
    """The residual env given zeros plays the scripted pickup exactly: the same applied actions and states as the
    script's own actions in the env without a base."""
    config = dataclasses.replace(budget_config("tool_grasp"), episode_length=STEPS)
    assert config.residual == "tool_grasp_script" and not config.hand_actions  # The policy corrects the wrist.
    residual_env = make_env("tool_grasp", config)
    plain_env = make_env("tool_grasp", dataclasses.replace(config, residual="", hand_actions=True))
    script = ScriptedToolGrasp()
    a, _ = residual_env.reset(seed=1)
    b, _ = plain_env.reset(seed=1)
    np.testing.assert_array_equal(a, b)
    for step in range(STEPS):
        a, reward_a, *_ = residual_env.step(np.zeros(19))
        b, reward_b, *_ = plain_env.step(script.act(plain_env.observation(), step))
        np.testing.assert_array_equal(a, b)
        assert reward_a == reward_b
    assert np.abs(a[124:143]).max() > 0.1  # The script did act (the previous-action entries).


def test_a_correction_changes_what_the_env_applies():
    config = dataclasses.replace(budget_config("tool_grasp"), episode_length=5)
    env = make_env("tool_grasp", config)
    observation, _ = env.reset(seed=1)
    expected = np.clip(ScriptedToolGrasp().act(observation, 0) + np.r_[np.zeros(16), 0.3, 0.0, 0.0], -1, 1)
    observation, *_ = env.step(np.r_[np.zeros(16), 0.3, 0.0, 0.0])
    np.testing.assert_allclose(observation[124:143], expected, atol=1e-6)


def test_policy_system_adds_the_base_as_the_env_does():
    """A deployed residual policy whose corrections are zero sends the script's action, on its active ticks."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from seqdex_drake.controller.policy import PolicyParams, PolicySystem

    env = make_env("tool_grasp", dataclasses.replace(budget_config("tool_grasp"), episode_length=5))
    observation, _ = env.reset(seed=2)
    model = ActorCritic(160, 19, (), (8,))
    with torch.no_grad():
        model.actor[-1].weight.zero_()
        model.actor[-1].bias.zero_()
    builder = DiagramBuilder()
    system = builder.AddSystem(PolicySystem(model, 159, PolicyParams(ema=1.0, time_steps=150,
                                                                     residual="tool_grasp_script")))
    source = builder.AddSystem(ConstantVectorSource(observation[:159].astype(float)))
    builder.Connect(source.get_output_port(), system.GetInputPort("observation"))
    simulator = Simulator(builder.Build())
    context = system.GetMyContextFromRoot(simulator.get_mutable_context())
    script = ScriptedToolGrasp()
    for tick in (0, 3):
        simulator.AdvanceTo((tick + 0.5) / 60.0)
        expected = script.act(np.r_[observation[:159], tick / 150], tick)
        np.testing.assert_allclose(system.GetOutputPort("raw_action").Eval(context), expected, atol=1e-6)


def test_runs_with_demonstrations_train_whole_actions(tmp_path):
    """DAPG's demonstrations hold whole actions: a run with --demos (and what reads its checkpoints) uses the
    variant without the residual base; every other budget run has it."""
    import json

    from seqdex_drake.tasks.run_config import run_residual, task_config

    assert task_config("tool_grasp", False, "budget").residual == "tool_grasp_script"
    assert task_config("tool_grasp", False, "budget", residual=False).residual == ""
    assert task_config("tool_grasp", False, "budget", residual=False).hand_actions  # Demonstrations: whole actions.
    assert task_config("tool_grasp", False, "paper").residual == ""
    (tmp_path / "config.json").write_text(json.dumps({"demos": "demos/tool_grasp.npz"}))
    assert not run_residual(tmp_path / "last.pt")
    (tmp_path / "config.json").write_text(json.dumps({"demos": None}))
    assert run_residual(tmp_path / "last.pt")


def test_rollout_of_the_zero_action_plays_the_residual_base(tmp_path, capsys):
    """``seqdex rollout --zero-action`` measures a residual variant's script alone (no checkpoint)."""
    import json

    from seqdex_drake.cli.main import main

    out = tmp_path / "script.json"
    assert main(["rollout", "--task", "tool_grasp", "--zero-action", "--test", "--episodes", "1",
                 "--out", str(out)]) == 0
    assert "the zero action (the tool_grasp_script base alone), budget task variant" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["preset"] == "budget" and result["episodes"] == 1
    assert main(["rollout", "--task", "tool_grasp", "--zero-action", "--checkpoint", "x.pt"]) == 2
    assert "--zero-action rolls out no policy" in capsys.readouterr().err


def test_a_budget_residual_run_takes_small_kl_bounded_steps(tmp_path):
    """seqdex train on a residual variant starts from the residual hyperparameters (std 0.05, KL-adaptive rate,
    whole-episode rollouts); with --demos it trains whole actions with the DAPG settings instead."""
    import argparse
    import math

    from seqdex_drake.cli.train import DEMO_INIT_STD, _new_run
    from seqdex_drake.rl.config import RESIDUAL_HYPERPARAMETERS
    from seqdex_drake.tasks.run_config import task_config

    args = argparse.Namespace(seed=3, num_envs=None, test=False, demos=None, demo_coef=0.1, steps=None,
                              checkpoint_seconds=None, preset="budget", task="tool_grasp", initial_states=None)
    ppo_config, record = _new_run(args, tmp_path, task_config("tool_grasp", False, "budget"))
    for key, value in RESIDUAL_HYPERPARAMETERS.items():
        assert getattr(ppo_config, key) == value, key
    assert ppo_config.init_log_std == math.log(0.1) and ppo_config.adaptive_lr and ppo_config.seed == 3
    assert record["task_config"]["residual"] == "tool_grasp_script"
    args.demos = "demos/tool_grasp.npz"
    ppo_config, record = _new_run(args, tmp_path, task_config("tool_grasp", False, "budget", residual=False))
    assert ppo_config.init_log_std == math.log(DEMO_INIT_STD) and not ppo_config.adaptive_lr
    assert record["task_config"]["residual"] == ""
