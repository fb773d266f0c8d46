"""The chain's Drake systems: policy hosting (vs. a direct torch call, EMA), the feasibility switcher's rule on
hand-built F's (forward, bypass, recovery, restart, switch cap, sequential fallback), checkpoint discovery, and
the chain controller closed around a real station."""

import dataclasses
import types

import numpy as np
import pytest
import torch
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from seqdex_drake import (
    ChainParams,
    ConnectChainController,
    LoadChainCheckpoints,
    LoadScenario,
    MakeChainController,
    MakeControllerPlant,
    MakeStation,
    SetChainTarget,
)
from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model, score
from seqdex_drake.chaining.feasibility_io import save_feasibility
from seqdex_drake.controller.policy import PolicyParams, PolicySystem
from seqdex_drake.controller.switcher import FeasibilitySwitcher, SwitcherParams, feasibility_score, walk_back
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.networks import ActorCritic
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.robots.allegro import p_PalmHc_Palm, scale_action_to_limits, unscale_limits_to_action
from seqdex_drake.robots.arm_ik import PalmIK
from seqdex_drake.scene.objects import SceneObjects
from seqdex_drake.scene.piles import BOX_CENTER
from seqdex_drake.tasks.blocks_common import resting_pose
from seqdex_drake.tasks.run_config import observation_spec

PERIOD = 1.0 / 60.0


def tiny_model(obs_dim: int, seed: int = 0) -> ActorCritic:
    """A small actor with a fitted normalizer and an output layer large enough that some actions clip."""
    torch.manual_seed(seed)
    model = ActorCritic(obs_dim, 19, (32, 32), (8,))
    model.update_normalizer(torch.randn(64, obs_dim) * 3 + 1)
    with torch.no_grad():
        model.actor[-1].weight.mul_(300.0)
    return model


def tick(simulator: Simulator, ticks: int = 1) -> None:
    """Advances ``ticks`` control periods (the update at t = k * PERIOD runs when passing it)."""
    context = simulator.get_context()
    k = int(round(context.get_time() / PERIOD + 0.5))
    simulator.AdvanceTo((k + ticks - 0.5) * PERIOD)


# --------------------------------------------------------------------------------------------- policy
@pytest.mark.parametrize("inference, atol", [("torch", 1e-6), ("numpy", 1e-5)])
def test_policy_equals_direct_torch_call_with_ema(inference, atol):
    # The numpy path (default) runs float32 in another summation order than torch; this model's x300 output
    # layer amplifies that to ~1.5e-6 on unclipped actions, within the documented ~1e-5.
    model = tiny_model(159)
    params = PolicyParams(control_period=PERIOD, ema=0.3, wrist_step=0.005, inference=inference)
    policy = PolicySystem(model, 159, params)
    context = policy.CreateDefaultContext()
    rng = np.random.default_rng(0)
    observations = [rng.normal(size=159) for _ in range(3)]
    observations[0][7:23] = scale_action_to_limits(rng.uniform(-1, 1, 16))
    policy.GetInputPort("observation").FixValue(context, observations[0])
    simulator = Simulator(policy, context)
    simulator.Initialize()
    previous = np.r_[unscale_limits_to_action(observations[0][7:23]), np.zeros(3)]  # hold the measured hand
    np.testing.assert_allclose(policy.GetOutputPort("action").Eval(context), previous, atol=1e-12)
    for k, obs in enumerate(observations):
        policy.GetInputPort("observation").FixValue(context, obs)
        tick(simulator)
        with torch.no_grad():
            raw = np.clip(model.action_mean(torch.as_tensor(obs, dtype=torch.float32)[None])[0].numpy(), -1, 1)
        if k == 0:
            assert np.any(np.abs(raw) == 1.0), "the test model should saturate some actions"
        expected = np.r_[0.3 * raw[:16] + 0.7 * previous[:16], raw[16:]]
        np.testing.assert_allclose(policy.GetOutputPort("raw_action").Eval(context), raw, atol=atol)
        np.testing.assert_allclose(policy.GetOutputPort("action").Eval(context), expected, atol=atol)
        np.testing.assert_allclose(policy.GetOutputPort("hand_target").Eval(context),
                                   scale_action_to_limits(expected[:16]), atol=atol)
        np.testing.assert_allclose(policy.GetOutputPort("wrist_translation").Eval(context), 0.005 * raw[16:],
                                   atol=1e-8)
        previous = expected
    # Inactive: no inference, the state copies the applied action given on the feedback inputs.
    applied = rng.uniform(-1, 1, 19)
    policy.GetInputPort("active").FixValue(context, [0.0])
    policy.GetInputPort("previous_filtered_action").FixValue(context, applied)
    policy.GetInputPort("previous_action").FixValue(context, -applied)
    tick(simulator)
    np.testing.assert_allclose(policy.GetOutputPort("action").Eval(context), applied)
    np.testing.assert_allclose(policy.GetOutputPort("raw_action").Eval(context), -applied)


def test_policy_from_checkpoint_checks_observation_size(tmp_path):
    config = PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(8,), num_envs=1)
    ppo = PPO(config, obs_dim=159, action_dim=19)
    path = ppo.save(tmp_path / "best.pt")
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    policy = PolicySystem.from_checkpoint(path, 159)
    np.testing.assert_array_equal(np.random.get_state()[1], before)  # loading leaves the caller's RNG alone
    assert policy.trained and policy.source == str(path)
    obs = np.linspace(-1, 1, 159)
    with torch.no_grad():
        direct = ppo.model.action_mean(torch.as_tensor(obs, dtype=torch.float32)[None])[0].numpy()
    np.testing.assert_allclose(policy.raw_action(obs), np.clip(direct, -1, 1), atol=1e-6)
    with pytest.raises(ValueError, match=r"best\.pt.*expected 173, found 159"):
        PolicySystem.from_checkpoint(path, 173)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        PolicySystem.from_checkpoint(tmp_path / "missing.pt", 159)
    untrained = PolicySystem.untrained(159, seed=4, hidden_sizes=(16,))
    assert not untrained.trained
    np.testing.assert_allclose(untrained.raw_action(obs), PolicySystem.untrained(159, 4, hidden_sizes=(16,))
                               .raw_action(obs))


# ------------------------------------------------------------------------------------------- switcher
class ReadScore(torch.nn.Module):
    """A hand-written F: the last observation's first entry (so c = entry / h)."""

    obs_dim = 2

    def predict(self, history):
        return float(np.asarray(history)[-1, 0])


def hand_built_f(history: int = 3):
    return types.SimpleNamespace(model=ReadScore(), threshold=1.0,
                                 config=types.SimpleNamespace(input_length=history))


class SwitcherRig:
    """A 4-stage switcher whose F^i reads observation.<i-1>[0]; ``set(c1, c2, c3)`` fixes the scores."""

    def __init__(self, max_switches=3, missing=(), budgets=(5, 5, 5, 5), every_tick=False, trigger="next",
                 free_object=None):
        fs = [None] + [None if i in missing else hand_built_f() for i in (1, 2, 3)]
        self.switcher = FeasibilitySwitcher(fs, [2] * 4, budgets, PERIOD, SwitcherParams(
            max_switches, evaluate_every_tick=every_tick, trigger=trigger, free_object_stages=free_object))
        self.context = self.switcher.CreateDefaultContext()
        self.missing = missing
        self.set(0, 0, 0)
        self.simulator = Simulator(self.switcher, self.context)
        self.simulator.Initialize()

    def set(self, *scores):
        for i, c in enumerate(scores, start=1):
            if i not in self.missing:
                self.switcher.GetInputPort(f"observation.{i - 1}").FixValue(self.context, [c, 0.0])

    def run(self, ticks=1):
        tick(self.simulator, ticks)
        stage = int(self.switcher.GetOutputPort("active_stage").Eval(self.context)[0])
        return stage, int(self.switcher.GetOutputPort("switches_used").Eval(self.context)[0])

    def scores(self):
        return self.switcher.GetOutputPort("feasibility_scores").Eval(self.context)


def test_walk_back_picks_the_last_feasible_stage():
    assert walk_back(np.array([np.nan, 2.0, 0.5, 1.5])) == 3
    assert walk_back(np.array([np.nan, 2.0, 1.5, 0.2])) == 2
    assert walk_back(np.array([np.nan, 0.5, np.nan, 1.0])) == 0  # c must exceed 1; NaN never does


def test_fast_score_equals_chaining_score():
    config = FeasibilityConfig(history=4, d_model=16, heads=2, layers=1, feedforward=16)
    model = build_feasibility_model(20, config).eval()
    f = types.SimpleNamespace(model=model, threshold=2.5, config=config)
    rng = np.random.default_rng(1)
    for steps in (1, 3, 4, 6):  # shorter histories are left-padded, longer ones cut
        history = rng.normal(size=(steps, 20))
        assert feasibility_score(f, history) == pytest.approx(score(model, history, 2.5), rel=1e-6, abs=1e-7)


def test_switcher_forward_bypass_recovery_restart():
    rig = SwitcherRig()
    assert rig.run() == (0, 0)
    np.testing.assert_allclose(rig.scores(), [np.nan, 0, np.nan, np.nan])  # Between decisions: c^{i+1} only.
    rig.set(2.0, 0.0, 0.0)
    assert rig.run() == (1, 1)  # forward: c^1 > 1
    rig.set(0.5, 3.0, 0.0)
    assert rig.run() == (2, 2)
    rig.set(2.0, 0.5, 0.5)  # stage 2 no longer feasible, stage 1 is: recovery at the end of stage 2's budget
    assert rig.run(4) == (2, 2)
    assert rig.run() == (1, 3)
    rig = SwitcherRig()
    rig.set(1.5, 2.0, 0.9)  # from stage 0 the walk bypasses stage 1 (already achieved): stage 2
    assert rig.run() == (2, 1)
    rig.set(0.0, 0.0, 0.0)  # nothing feasible at the end of the budget: restart from stage 0
    assert rig.run(4) == (2, 1)
    assert rig.run() == (0, 2)


def test_switcher_cap_zero_is_sequential_and_history_is_kept():
    rig = SwitcherRig(max_switches=0, budgets=(3, 2, 2, 2))
    rig.set(5.0, 5.0, 5.0)  # feasibility ignored: advance on the step budget only
    assert [rig.run()[0] for _ in range(8)] == [0, 0, 1, 1, 2, 2, 3, 3]
    assert rig.run(5) == (3, 0)  # the last stage keeps running
    history = rig.switcher.history(rig.context, 0)
    assert history.shape == (3, 2) and np.all(history[:, 0] == 5.0)
    # stage_success ends a stage early.
    rig = SwitcherRig(max_switches=0, budgets=(50, 50, 50, 50))
    rig.switcher.GetInputPort("stage_success").FixValue(rig.context, [1.0])
    assert [rig.run()[0] for _ in range(3)] == [1, 2, 3]


def test_switcher_is_done_only_when_the_last_stage_runs_past_its_budget_with_no_switch_left():
    rig = SwitcherRig(max_switches=0, budgets=(3, 2, 2, 2))
    done = []
    for _ in range(12):
        rig.run()
        done.append(rig.switcher.done_for(rig.context))
    assert done == [0] * 9 + [1, 2, 3]  # Stage 3 entered after 7 ticks, its budget of 2 used after 9.
    rig = SwitcherRig(budgets=(2, 2, 2, 2))  # Nothing feasible: each budget's end restarts from stage 0 ...
    ticks = 0
    while rig.switcher.done_for(rig.context) == 0 and ticks < 100:
        stage, switches = rig.run()
        ticks += 1
    assert (stage, switches) == (3, 3)  # ... until the switches are spent; then the sequential rule runs to the end.


class ReadProgress(ReadScore):
    """A hand-written F of a time-aware stage: its input rows end with the stage's progress, which it returns."""

    obs_dim = 3

    def predict(self, history):
        return float(np.asarray(history)[-1, -1])


def test_switcher_appends_a_time_aware_stages_progress_as_its_env_does():
    f = types.SimpleNamespace(model=ReadProgress(), threshold=1.0, config=types.SimpleNamespace(input_length=3))
    # Stage 0 observes its progress over a 10-step episode: F^1 reads 2 observation entries plus the progress.
    switcher = FeasibilitySwitcher([None, f], [2, 2], (10, 10), PERIOD, SwitcherParams(max_switches=0,
                                                                                       time_steps=(10, 0)))
    context = switcher.CreateDefaultContext()
    switcher.GetInputPort("observation.0").FixValue(context, [0.5, 0.0])
    simulator = Simulator(switcher, context)
    simulator.Initialize()
    tick(simulator, 4)
    # Ticks 1-4 saw 0-3 steps taken in stage 0, as the env's observations after 0-3 steps: progress 0.0-0.3.
    np.testing.assert_allclose(switcher.history(context, 0), [[0.5, 0.0, 0.1], [0.5, 0.0, 0.2], [0.5, 0.0, 0.3]])
    assert switcher.GetOutputPort("feasibility_scores").Eval(context)[1] == pytest.approx(0.3)
    tick(simulator, 9)  # Stage 1 executes from the 11th tick on: stage 0's rows then say it is over (1).
    assert int(switcher.GetOutputPort("active_stage").Eval(context)[0]) == 1
    np.testing.assert_allclose(switcher.history(context, 0)[:, -1], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"reads 3-dim histories, but stage 0's observation has 2; use the F"):
        FeasibilitySwitcher([None, f], [2, 2], (10, 10), PERIOD)
    with pytest.raises(ValueError, match="time_steps needs one entry"):
        FeasibilitySwitcher([None, f], [2, 2], (10, 10), PERIOD, SwitcherParams(time_steps=(10,)))


def test_switcher_cap_and_missing_f_fall_back_to_sequential():
    rig = SwitcherRig(max_switches=1, budgets=(4, 4, 4, 4), trigger="any_later")
    rig.set(0.0, 0.0, 3.0)
    assert rig.run() == (3, 1)  # one feasibility switch (straight to the last stage) ...
    rig.set(0.0, 0.0, 0.0)
    assert rig.run(6) == (3, 1)  # ... then the cap holds: no restart although nothing is feasible
    rig = SwitcherRig(missing=(2,), budgets=(4, 3, 3, 3))
    rig.set(2.0, 0.0, 0.0)
    assert rig.run() == (1, 1)
    assert [rig.run()[0] for _ in range(3)] == [1, 1, 2]  # no F for stage 2: advance on the budget
    assert np.isnan(rig.scores()[2]) and np.isnan(rig.scores()[0])
    # While the approach controller moves the hand the stage clock stops and nothing is decided.
    rig = SwitcherRig(budgets=(2, 2, 2, 2))
    rig.switcher.GetInputPort("approach_active").FixValue(rig.context, [1.0])
    rig.set(3.0, 0.0, 0.0)
    assert rig.run(5) == (0, 0)
    assert rig.scores()[1] == 3.0


def test_switcher_trigger_next_waits_for_the_budget_when_only_a_later_stage_is_feasible():
    """The paper's switch timing scores only c^{i+1} each tick; the full walk back happens at a decision."""
    rig = SwitcherRig(budgets=(4, 4, 4, 4))
    rig.set(0.0, 0.0, 3.0)
    assert rig.run(3) == (0, 0)  # c^1 <= 1: no decision, c^3 not even computed
    assert np.isnan(rig.scores()[3])
    assert rig.run() == (3, 1)  # budget used up: the walk back finds the last stage
    assert rig.scores()[3] == 3.0
    rig = SwitcherRig(budgets=(4, 4, 4, 4), trigger="any_later")
    rig.set(0.0, 0.0, 3.0)
    assert rig.run() == (3, 1)
    with pytest.raises(ValueError, match="trigger"):
        SwitcherRig(trigger="sometimes")


def test_switcher_trigger_decision_never_cuts_a_stage_short():
    """With ``trigger = "decision"`` no score is computed between decisions, so a feasible next stage waits for the
    executing stage's end; there the walk back still retries, skips or recovers."""
    rig = SwitcherRig(budgets=(4, 4, 4, 4), trigger="decision")
    rig.set(3.0, 0.0, 0.0)  # c^1 > 1 from the first tick: "next" would switch at once
    assert rig.run(3) == (0, 0)
    assert np.isnan(rig.scores()).all()  # nothing computed yet
    assert rig.run() == (1, 1)  # stage 0's budget end: the walk back selects stage 1, a feasibility switch
    assert rig.scores()[1] == 3.0
    rig.set(0.0, 0.0, 0.0)  # nothing feasible at stage 1's end: restart from stage 0 (a recovery)
    assert rig.run(3) == (1, 1)
    assert rig.run() == (0, 2)
    rig.set(0.0, 2.0, 0.0)  # stage 2 feasible at stage 0's end: skip stage 1
    assert rig.run(4) == (2, 3)
    rig = SwitcherRig(budgets=(4, 4, 4, 4), trigger="next")
    rig.set(3.0, 0.0, 0.0)
    assert rig.run() == (1, 1)  # the paper's timing, for contrast


def test_switcher_selects_a_free_object_stage_only_while_the_object_is_not_held():
    """Tool Grasp starts from the tool on the table: with the tool in hand a walk back to it does not switch (the
    sequential rule applies); once the tool is down (dropped), F sending the chain back to it does."""
    rig = SwitcherRig(budgets=(3, 3, 3, 3), free_object=(True, False, False, False))
    held = rig.switcher.GetInputPort("object_held")
    held.FixValue(rig.context, [1.0])
    rig.set(0.0, 0.0, 0.0)  # Nothing feasible at stage 0's budget end: would restart stage 0, but it is held.
    assert [rig.run()[0] for _ in range(3)] == [0, 0, 1]  # the sequential advance, no switch used
    assert rig.run(2) == (1, 0)
    assert rig.run() == (2, 0)  # stage 1's budget end: the walk back would restart stage 0; held: advance
    held.FixValue(rig.context, [0.0])  # Dropped: the restart happens at the next decision.
    assert rig.run(2) == (2, 0)
    assert rig.run() == (0, 1)
    rig.set(2.0, 0.0, 0.0)  # A stage without the flag is selected whether held or not.
    held.FixValue(rig.context, [1.0])
    assert rig.run() == (1, 2)
    with pytest.raises(ValueError, match="free_object_stages needs one flag per stage"):
        SwitcherRig(free_object=(True,))


def test_switcher_does_not_restart_the_last_stage_that_selects_itself():
    """At the last stage's budget end, c^K > 1 means the walk back selects the last stage again: it keeps running
    (the chain is done) instead of restarting its clock; c^K <= 1 still sends the chain back."""
    rig = SwitcherRig(budgets=(2, 2, 2, 2))
    rig.set(0.0, 0.0, 3.0)
    assert rig.run(2) == (3, 1)  # stage 0's budget end: the walk back finds the last stage
    assert rig.run(5) == (3, 1)  # its budget ends with c^3 > 1: no restart, no switch used
    assert rig.switcher.done_for(rig.context) > 0
    rig.set(0.0, 2.0, 0.0)  # no longer feasible from here: back to stage 2
    assert rig.run() == (2, 2)


def test_switcher_every_tick_mode_counts_changes_only():
    rig = SwitcherRig(every_tick=True)
    rig.set(2.0, 0.0, 0.0)
    assert rig.run() == (1, 1)
    assert rig.run(3) == (1, 1)
    rig.set(0.0, 0.0, 0.0)
    assert rig.run() == (0, 2)


def test_switcher_stage_epoch_changes_on_switches_and_on_entering_approach_stages():
    """``stage_epoch`` tells the approach controller to bring the hand back to the hover point: on entering a stage
    flagged ``approach_on_entry`` (not the others), and at a feasibility switch back to the executing or an earlier
    stage; a switch forward into an unflagged stage starts it where the hand is."""
    switcher = FeasibilitySwitcher([None] * 4, [2] * 4, (2, 2, 2, 2), PERIOD, SwitcherParams(
        max_switches=0, approach_on_entry=(False, True, False, True)))
    context = switcher.CreateDefaultContext()
    simulator = Simulator(switcher, context)
    simulator.Initialize()
    seen = []
    for _ in range(8):
        tick(simulator, 1)
        seen.append((int(switcher.GetOutputPort("active_stage").Eval(context)[0]),
                     int(switcher.GetOutputPort("stage_epoch").Eval(context)[0])))
    assert seen == [(0, 0), (1, 1), (1, 1), (2, 1), (2, 1), (3, 2), (3, 2), (3, 2)]
    rig = SwitcherRig(budgets=(2, 2, 2, 2))  # No stage flagged: only switches back restart the approach.
    epoch = rig.switcher.GetOutputPort("stage_epoch")
    rig.set(2.0, 0.0, 0.0)
    assert rig.run() == (1, 1) and epoch.Eval(rig.context)[0] == 0  # forward: starts where the hand is
    rig.set(2.0, 0.0, 0.0)
    assert rig.run(2) == (1, 2) and epoch.Eval(rig.context)[0] == 1  # budget end, stage 1 selects itself: a retry
    rig.set(0.0, 0.0, 0.0)
    assert rig.run(2) == (0, 3) and epoch.Eval(rig.context)[0] == 2  # back to stage 0: a restart
    with pytest.raises(ValueError, match="approach_on_entry needs one flag per stage"):
        FeasibilitySwitcher([None] * 4, [2] * 4, (2,) * 4, PERIOD, SwitcherParams(approach_on_entry=(True,)))


# ------------------------------------------------------------------------------------- chain + station
def test_load_chain_checkpoints(tmp_path):
    (tmp_path / "stages" / "grasp").mkdir(parents=True)
    (tmp_path / "feasibility").mkdir()
    for name in ("best.pt", "last.pt"):
        (tmp_path / "stages" / "grasp" / name).write_bytes(b"x")
    (tmp_path / "feasibility" / "insert.pt").write_bytes(b"x")
    found = LoadChainCheckpoints(tmp_path, ["orient", "grasp", "insert"])
    assert found.policies == [None, tmp_path / "stages/grasp/best.pt", None]
    assert found.feasibility == [None, None, tmp_path / "feasibility/insert.pt"]
    assert len(found.missing) == 3 and "orient" in found.missing[0] and "feasibility" in found.missing[1]
    with pytest.raises(ValueError, match="unknown task 'grab'"):
        LoadChainCheckpoints(tmp_path, ["grab"])


def test_chain_controller_runs_with_a_station(tmp_path):
    config = FeasibilityConfig(history=3, d_model=16, heads=2, layers=1, feedforward=16)
    # h far above any untrained output: c^insert ~ 0, so the chain restarts when Grasp's budget ends.
    f_path = save_feasibility(tmp_path / "insert.pt", build_feasibility_model(159, config), config, 1e6,
                              observation_spec("grasp", 159), source_task="grasp", target_task="insert")
    scenario = LoadScenario("building_blocks/grasp")
    params = ChainParams(untrained_hidden_sizes=(32, 32), switcher=SwitcherParams(stage_steps=(10, 10, 10)))
    stages = [("orient", None), ("grasp", None), ("insert", None)]
    with pytest.raises(ValueError, match="Search stage needs a camera"):
        MakeChainController(scenario, [("search", None)], params=params)
    with pytest.raises(ValueError, match=r"insert\.pt.*orient"):
        MakeChainController(scenario, stages, [None, f_path, None], params=params)  # F^insert scores grasp histories
    for bad in (dict(approach_stages=("grasps",)), dict(carry_stages=(("lift", 0.03),)), dict(carry_stages=(
            ("grasp", 0.03),))):  # A misspelt stage, one not in the chain, one without a goal to carry to.
        with pytest.raises(ValueError, match="not stages of this chain|finite only for stages with a goal"):
            MakeChainController(scenario, stages, params=dataclasses.replace(params, **bad))
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario))
    controller = builder.AddNamedSystem("chain", MakeChainController(scenario, stages, [None, None, f_path], params))
    ConnectChainController(builder, station, controller)
    simulator = Simulator(builder.Build())
    context = simulator.get_mutable_context()
    objects = SceneObjects(station, scenario)
    objects.park(context)
    objects.set_pose(context, "block_2", resting_pose(2, 0.0, 0.0, 0.3, BOX_CENTER[:2]))
    plant = station.GetSubsystemByName("plant")
    plant_context = plant.GetMyMutableContextFromRoot(context)
    body = plant.GetBodyByName("block", plant.GetModelInstanceByName("block_2"))
    p_WBcm = plant.EvalBodyPoseInWorld(plant_context, body) @ body.default_com()
    # Start at the hover pose (hand centre 5 cm above the block, palm down), as the sub-task resets do.
    ik = PalmIK(MakeControllerPlant(scenario), p_PalmC_Palm=p_PalmHc_Palm)
    home = np.asarray(scenario.robot.arm_home)
    q_hover, error = ik.solve(home, p_WBcm + [0, 0, 0.05], ik.palm_pose(home).rotation())
    assert error < 1e-3
    plant.SetPositions(plant_context, plant.GetModelInstanceByName("franka"), q_hover)
    with pytest.raises(ValueError, match="pass goal="):
        SetChainTarget(controller, context, int(body.index()))
    SetChainTarget(controller, context, int(body.index()), goal=[0.5, 0.1, 0.6, 1, 0, 0, 0])
    simulator.Initialize()
    # Ticks 0..21: approach done at tick 0, orient 10 ticks, grasp 10, restart at tick 20, which re-arms the
    # approach (the switch changes the OSC's stage_epoch; the hand has left the hover point).
    simulator.AdvanceTo(0.36)
    chain_context = controller.GetMyContextFromRoot(context)

    def out(name):
        return controller.GetOutputPort(name).Eval(chain_context)

    sizes = {"franka.desired_state": 14, "allegro.desired_state": 32, "active_stage": 1, "feasibility_scores": 3,
             "approach_active": 1, "action": 19, "executing_stage": 1, "switches_used": 1, "approach_target": 3}
    assert {name: out(name).shape for name in sizes} == {name: (size,) for name, size in sizes.items()}
    assert np.isnan(out("feasibility_scores")[:2]).all() and abs(out("feasibility_scores")[2]) < 1e-2
    assert out("approach_active")[0] == 1.0
    assert (out("active_stage")[0], out("executing_stage")[0], out("switches_used")[0]) == (0, 0, 1)
    policy = controller.GetSubsystemByName("policy.0")
    policy_context = policy.GetMyContextFromRoot(context)
    np.testing.assert_allclose(out("allegro.desired_state")[:16], policy.GetOutputPort("hand_target").Eval(
        policy_context))
    np.testing.assert_allclose(out("action"), policy.GetOutputPort("action").Eval(policy_context))
    assembler = controller.GetSubsystemByName("observation.base")  # its previous action is the applied raw one
    np.testing.assert_allclose(assembler.GetOutputPort("observation").Eval(assembler.GetMyContextFromRoot(
        context))[124:143], policy.GetOutputPort("raw_action").Eval(policy_context))
    arm = out("franka.desired_state")
    assert np.all(np.isfinite(arm)) and np.linalg.norm(arm[:7] - q_hover) < 0.05  # untrained: small wrist moves
    np.testing.assert_allclose(out("approach_target"), plant.EvalBodyPoseInWorld(
        plant_context, body) @ body.default_com(), atol=1e-9)
